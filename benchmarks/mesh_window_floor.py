"""What a mesh flow step would cost with windows shaped to their particles and free layouts.

    python benchmarks/mesh_window_floor.py [--relax 400] [--flow 800] [--room 1 2] [--repeats 2]
                                           [--corrections 2 1] [--output FILE]

A design study: it replaces ``MeshDomain.refit`` in its own process. A box window is the
dofs inside a box (margin 4 around the φ > 0.01 set, room and slack,
:class:`~femphase.domains.mesh.boxes.BoxPolicy`, ``numerics.mesh_windows = "boxes"``); here a
**shaped** window is the dofs within ``margin + room`` of the set (distances along the mesh's
edges, :func:`~femphase.domains.mesh.kernels.dilate`), made at a refit and kept while every
dof of the set lies within ``room`` of the set it was made for (so the margin holds). A
window that fails this is made anew at the next refit, alone (femphase's own shapes,
:mod:`femphase.domains.mesh.shapes`, make the windows near their room with it); any new
window makes a new layout, built as femphase builds one (:class:`~femphase.domains.layout.Layout`,
block matrices per layout), and costed as updated in place.

Each run is its own process, relaxed ``--relax`` time units in boxes and then run
``--flow`` time units of flow, timed on the process clock. Its flow CPU is split into:

* **refit**: the refits, the new layouts and the transfer of the fields to them; for the
  shaped windows, recorded apart within it, **checking** (a compiled pass over the positions
  for windows to remake, :func:`~femphase.domains.mesh.kernels.largest_made_distance`) and
  **shaping** (their making, :meth:`~femphase.domains.mesh.domain.MeshDomain.dilation`);
* **blocks**: what is built once per layout (block patterns and block-diagonal matrices,
  Jacobi diagonals: :meth:`~femphase.domains.base.Domain.per_layout`);
* **floor**: the rest, the work of the substeps themselves.

Kinds: ``grid`` (examples/random.toml, Poiseuille of rate U, as ``mesh_parity.py``), ``box``
(examples/straight_mesh.toml, Stokes flow of centre-line velocity U, box windows),
``shapes`` (the same on femphase's shaped windows) and ``shaped`` at each ``--room`` and
each ``--corrections`` K (the mesh advection's Jacobi corrections,
:data:`~femphase.domains.mesh.advection.MASS_CORRECTIONS`: 2, the default, or fewer
products per substep), alternated ``--repeats`` times; ratios are to the grid run of the
same repeat. Each mesh run also records every particle's centroid and area at the end, and
the shaped runs their largest differences from the box run of the same repeat and what a
layout built from pieces kept per window would cost, concatenated or updated in place
(:func:`layout_from_pieces_ms`).
Blocks are timed once each: a block matrix builds the block pattern on first use, inside
its own build, and the pattern's time is counted with it only (counted twice, the floor
reads short by the pattern's time at every layout: docs/decisions/0057-shaped-mesh-windows.md).
The design's cost, windows checked and made as here and layouts updated in place, is (floor +
checking + shaping + layouts × ``in_place_layout_ms``) over the grid's flow CPU, each shaped
run's ``design_to_grid_flow`` (docs/decisions/0054-shaped-mesh-windows-floor.md).
Writes ``results/mesh_window_floor.json`` (``--output``: another path), with the command and
the machine.

Processes a minute apart see different spells of the shared machine (the grid's flow moved
0.88–1.37 s between repeats). ``--interleaved N`` runs every kind in one process instead,
relaxed one after the other, then their flows in N chunks of ``--flow`` time units, the
kinds' order rotated each chunk; totals over the chunks after the first (compilation), with
each shaped run's design also against the boxes' flow (``design_to_box_flow``), and one
more kind, ``shapes``: femphase's own shaped windows (``numerics.mesh_windows = "shapes"``,
:mod:`femphase.domains.mesh.shapes`), timed as the others:

    python benchmarks/mesh_window_floor.py --room 2 --corrections 2 1 --flow 100 --interleaved 17 \\
        --output benchmarks/results/mesh_window_floor_interleaved.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import numpy as np
from mesh_parity import THREADS, scene_of

ROOT = Path(__file__).resolve().parents[1]
RESULT = Path(__file__).parent / "results" / "mesh_window_floor.json"


class ShapedWindows:
    """The refit of shaped windows (module docstring), replacing a mesh domain's, with CPU
    accounts. A shaped window is a :class:`Box` used as a tag (x0 = −serial), whose dofs are
    put into the domain's window cache; ``made[tag]`` holds each of its dofs' distance to the
    set it was made for."""

    def __init__(self, domain, policy, room: float) -> None:
        self.domain, self.room = domain, room
        self.threshold, self.margin = policy.threshold, policy.margin
        self.made: dict = {}
        self.serial = 0
        self.windows_made = 0
        #: CPU seconds spent making windows (``MeshDomain.dilation``, the sets' gathering included)
        self.shaping = 0.0
        #: CPU seconds spent finding the windows to remake
        self.checking = 0.0
        self._made_positions: tuple = (None, None)

    def made_positions(self, layout) -> np.ndarray:
        """Every position's distance to the set its window was made for (inf in windows not
        made here), in layout order; kept for the last layout."""
        if self._made_positions[0] is not layout:
            self._made_positions = (layout, np.concatenate([
                self.made.get(layout.windows[i], np.full(layout.sizes[slot], np.inf))
                for slot, i in enumerate(layout.order)]))
        return self._made_positions[1]

    def refit(self, layout, phi, policy, motion):
        from femphase.domains.mesh.boxes import Box

        domain = self.domain
        from femphase.domains.mesh.kernels import largest_made_distance

        started = time.process_time()
        slots = np.flatnonzero(largest_made_distance(phi, self.made_positions(layout), layout.offsets,
                                                     self.threshold) > self.room)
        self.checking += time.process_time() - started
        if not slots.size:
            return layout, phi
        boxes, fields = layout.windows, layout.scatter(phi)
        particles = layout.order[slots]
        started = time.process_time()
        made = domain.dilation([domain.window_dofs(boxes[i])[fields[i] > self.threshold] for i in particles],
                               self.margin + self.room)
        self.shaping += time.process_time() - started
        replaced = {}
        for i, (dofs, distance) in zip(particles, made):
            self.serial += 1
            tag = Box(-float(self.serial), 0.0, 0.0, 0.0)
            domain._dofs.put(tag, dofs)
            self.made[tag] = distance
            self.made.pop(boxes[i], None)
            replaced[i] = tag
        self.windows_made += len(particles)
        return domain._transferred(layout, phi, replaced)


def layout_from_pieces_ms(domain, layout, changed: int, matrices: int = 4, repeats: int = 50) -> dict:
    """Milliseconds to build ``layout``'s flat arrays from pieces kept per window: its dofs,
    its block pattern's rows and columns (shifted to each window's place) and the entries of
    ``matrices`` single-precision block matrices (best of ``repeats`` each).

    * ``concatenated``: every array concatenated from its windows' pieces, the least any
      layout built anew can cost;
    * ``in_place``: ``changed`` windows' slices rewritten in arrays that stay (every window a
      slot of its own), the least a layout updated in place can cost (slots of the same size:
      a changed window's capacity and its place in the products are left out)."""
    pattern = domain.window_blocks(layout)
    offsets = layout.offsets
    entries = pattern.indptr[offsets].astype(np.int64)
    windows = range(offsets.size - 1)
    nodes = [layout.node_index[offsets[w]:offsets[w + 1]] for w in windows]
    columns = [pattern.indices[entries[w]:entries[w + 1]] - offsets[w] for w in windows]
    rows = [pattern.indptr[offsets[w]:offsets[w + 1]] - entries[w] for w in windows]
    data = domain._operator_data["mass", np.float32][pattern.source]
    values = [[data[entries[w]:entries[w + 1]].copy() for w in windows] for _ in range(matrices)]
    sizes, counts = np.diff(offsets), np.diff(entries)

    def concatenate():
        index = np.concatenate(columns)
        index += np.repeat(offsets[:-1], counts).astype(index.dtype)
        starts = np.concatenate(rows)
        starts += np.repeat(entries[:-1], sizes).astype(starts.dtype)
        return np.concatenate(nodes), index, starts, [np.concatenate(pieces) for pieces in values]

    node_index, index, starts, arrays = concatenate()
    rewritten = np.linspace(0, len(windows) - 1, min(changed, len(windows))).round().astype(int)

    def rewrite():
        for w in rewritten:
            positions, stored = slice(offsets[w], offsets[w + 1]), slice(entries[w], entries[w + 1])
            node_index[positions] = nodes[w]
            np.add(columns[w], offsets[w], out=index[stored], casting="unsafe")
            np.add(rows[w], entries[w], out=starts[positions], casting="unsafe")
            for array, pieces in zip(arrays, values):
                array[stored] = pieces[w]

    def best(build) -> float:
        fastest = np.inf
        for _ in range(repeats):
            started = time.perf_counter()
            build()
            fastest = min(fastest, time.perf_counter() - started)
        return 1e3 * fastest

    return {"concatenated": best(concatenate), "in_place": best(rewrite), "windows_rewritten": int(rewritten.size)}


class FlowRun:
    """One kind (module docstring) relaxed in this process and ready for its flow, which
    :meth:`advance` steps on: the refits and the per-layout blocks timed apart, and for the
    shaped windows their check and their making."""

    #: the run whose per-layout blocks are being built (:meth:`advance`)
    current: "FlowRun | None" = None

    def __init__(self, kind: str, relax: float, flow: float, velocity: float, room: float, corrections: int) -> None:
        self.kind, self.room, self.corrections = kind, room, corrections
        # the box and shaped windows run mesh_parity.py's mesh scene on boxes, femphase's shapes
        # on its own, the grid its grid scene
        scene = scene_of({"grid": "grid", "shapes": "mesh"}.get(kind, "mesh_boxes"), relax, flow, velocity)
        self.flowing = scene.phases[1]
        FlowRun.current = None  # the relaxation's blocks are not the flow's
        self.state, self.stepper = common.relaxed_flow(scene)
        self.domain = self.stepper.domain
        self.spent = {"flow": 0.0, "refit": 0.0, "blocks": 0.0}
        self.layouts = 0
        self.shaped = ShapedWindows(self.domain, self.stepper.policy, room) if kind == "shaped" else None
        refit = self.shaped.refit if self.shaped else self.domain.refit

        def counted(layout, *args):
            started = time.process_time()
            try:
                out = refit(layout, *args)
            finally:
                self.spent["refit"] += time.process_time() - started
            self.layouts += out[0] is not layout
            return out

        object.__setattr__(self.domain, "refit", counted)  # the domain is a frozen dataclass
        _time_blocks()

    def advance(self) -> None:
        """One flow phase's worth of steps (``flow`` time units)."""
        from femphase.domains.mesh import advection

        advection.MASS_CORRECTIONS = self.corrections  # read when an advection is built
        FlowRun.current = self
        started = time.process_time()
        self.stepper.step(self.state, self.flowing.n_steps)
        self.spent["flow"] += time.process_time() - started

    def counters(self) -> dict:
        """CPU seconds so far: the flow, its refits, its blocks, and the shaped windows' check
        and making; and the layouts."""
        shaped = {"checking": self.shaped.checking, "shaping": self.shaped.shaping} if self.shaped else {}
        return {**self.spent, **shaped, "layouts": self.layouts}

    def record(self) -> dict:
        """The run's totals and end state (module docstring)."""
        layout, phi = self.state.flat()
        area, centroids, _ = self.domain.shape_moments(layout, phi)
        spent = self.spent
        record = {"kind": self.kind, "room": self.room if self.shaped else None, "corrections": self.corrections,
                  "flow_cpu_s": spent["flow"], "refit_cpu_s": spent["refit"], "blocks_cpu_s": spent["blocks"],
                  "floor_cpu_s": spent["flow"] - spent["refit"] - spent["blocks"], "positions": int(phi.size),
                  "layouts": self.layouts,
                  "cg_iterations": round(float(getattr(self.stepper, "krylov_iterations", 0)), 1),
                  "period": float(self.domain.period), "areas": area.tolist(), "centroids": centroids.tolist()}
        if self.shaped:
            pieces = layout_from_pieces_ms(self.domain, layout,
                                           changed=round(self.shaped.windows_made / max(self.layouts, 1)))
            record.update(windows_made=self.shaped.windows_made, shaping_cpu_s=self.shaped.shaping,
                          checking_cpu_s=self.shaped.checking, concatenated_layout_ms=pieces["concatenated"],
                          in_place_layout_ms=pieces["in_place"], windows_rewritten=pieces["windows_rewritten"])
        return record


def _time_blocks() -> None:
    """Time every per-layout build into the current run's blocks (once per process), each
    once: a build that asks for another (a block matrix for the block pattern, built on
    first use) holds the inner build's time already."""
    from femphase.domains.base import Domain

    if getattr(Domain.per_layout, "timed", False):
        return
    per_layout = Domain.per_layout
    depth = [0]

    def timed(self, layout, name, build, tag=None):
        def run():
            started = time.process_time()
            depth[0] += 1
            try:
                return build()
            finally:
                depth[0] -= 1
                if FlowRun.current is not None and depth[0] == 0:
                    FlowRun.current.spent["blocks"] += time.process_time() - started
        return per_layout(self, layout, name, run, tag)

    timed.timed = True
    Domain.per_layout = timed


def child(kind: str, relax: float, flow: float, velocity: float, room: float, corrections: int) -> dict:
    """Run one kind in this process (module docstring)."""
    run = FlowRun(kind, relax, flow, velocity, room, corrections)
    run.advance()
    return run.record()


def design_seconds(floor: float, checking: float, shaping: float, layouts: int, in_place_ms: float) -> float:
    """The shaped design's CPU seconds as costed in the module docstring: windows checked and
    made as here, each layout updated in place."""
    return floor + checking + shaping + layouts * in_place_ms / 1e3


def interleaved(relax: float, chunk: float, chunks: int, velocity: float, room: float,
                corrections: list[int]) -> dict:
    """The grid, the boxes, femphase's shapes and the shaped windows at each K in
    ``corrections``, all in this process: each relaxed, then their flows in ``chunks``
    chunks of ``chunk`` time units, the kinds' order rotated each chunk so that all see the
    machine's spells alike. Totals over the chunks after the first (compilation), and the
    ratios to the grid's flow and to the boxes' of the same chunks."""
    runs = [FlowRun(kind, relax, chunk, velocity, 0.0, 2) for kind in ("grid", "box", "shapes")]
    runs += [FlowRun("shaped", relax, chunk, velocity, room, k) for k in corrections]
    totals = []
    for index in range(chunks):
        if index == 1:
            totals = [run.counters() for run in runs]
        turn = index % len(runs)
        for run in runs[turn:] + runs[:turn]:
            run.advance()
    out = []
    for run, before in zip(runs, totals):
        record = run.record()
        after = run.counters()
        used = {key: after[key] - before[key] for key in after}
        record.update({f"{key}_cpu_s": value for key, value in used.items() if key != "layouts"},
                      layouts=used["layouts"])
        record["floor_cpu_s"] = used["flow"] - used["refit"] - used["blocks"]
        out.append(record)
    grid, box = out[0]["flow_cpu_s"], out[1]["flow_cpu_s"]
    for record in out[1:]:
        record["flow_to_grid_flow"] = record["flow_cpu_s"] / grid
        if record["kind"] == "shaped":
            design = design_seconds(record["floor_cpu_s"], record["checking_cpu_s"], record["shaping_cpu_s"],
                                    record["layouts"], record["in_place_layout_ms"])
            record.update(design_cpu_s=design, design_to_grid_flow=design / grid, design_to_box_flow=design / box)
    return {"mode": "interleaved", "chunk": chunk, "chunks": chunks, "runs": out}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--relax", type=float, default=400.0, help="time units of relaxation (default 400)")
    parser.add_argument("--flow", type=float, default=800.0, help="time units of flow (default 800)")
    parser.add_argument("--velocity", type=float, default=0.1, help="centre-line velocity U (default 0.1)")
    parser.add_argument("--room", type=float, nargs="+", default=[1.0], help="rooms of the shaped windows (default 1)")
    parser.add_argument("--repeats", type=int, default=2, help="alternations of the kinds (default 2)")
    parser.add_argument("--corrections", type=int, nargs="+", default=[2],
                        help="the shaped windows' advection corrections K (default 2, the default's)")
    parser.add_argument("--interleaved", type=int, metavar="N",
                        help="all kinds in one process, in N rotating chunks of --flow time units (one room)")
    parser.add_argument("--child", choices=("grid", "box", "shapes", "shaped"), help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=RESULT)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.relax, args.flow, args.velocity, args.room[0], args.corrections[0])))
        return
    if args.interleaved is not None:
        if args.interleaved < 2 or len(args.room) != 1:
            raise SystemExit(f"--interleaved {args.interleaved} with rooms {args.room}: at least 2 chunks (the first "
                             "is dropped) and one room")
        result = {"command": " ".join(["python benchmarks/mesh_window_floor.py", *sys.argv[1:]]),
                  "machine": common.machine(), "relax": args.relax, "velocity": args.velocity,
                  **interleaved(args.relax, args.flow, args.interleaved, args.velocity, args.room[0],
                                args.corrections)}
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(json.dumps(result, indent=1) + "\n")
        for run in result["runs"]:
            print(json.dumps({k: v for k, v in run.items() if k not in ("areas", "centroids")}), flush=True)
        return
    kinds = [("grid", 0.0, 2), ("box", 0.0, 2), ("shapes", 0.0, 2)]
    kinds += [("shaped", room, k) for room in args.room for k in args.corrections]
    runs = []
    for repeat in range(args.repeats):
        for kind, room, corrections in kinds:
            command = [sys.executable, __file__, "--child", kind, "--relax", str(args.relax), "--flow", str(args.flow),
                       "--velocity", str(args.velocity), "--room", str(room), "--corrections", str(corrections)]
            out = subprocess.run(command, env={**os.environ, **THREADS}, capture_output=True, text=True, cwd=ROOT)
            if out.returncode != 0:
                raise SystemExit(f"{kind} failed:\n{out.stderr[-3000:]}")
            run = {**json.loads(out.stdout.strip().splitlines()[-1]), "repeat": repeat}
            grid = next(r for r in runs if r["kind"] == "grid" and r["repeat"] == repeat) if kind != "grid" else run
            for part in ("flow", "floor"):
                run[f"{part}_to_grid_flow"] = run[f"{part}_cpu_s"] / grid["flow_cpu_s"]
            # the whole flow less the making of shaped windows: refits, layouts and blocks as femphase builds them
            run["layouts_as_today_to_grid_flow"] = ((run["flow_cpu_s"] - run.get("shaping_cpu_s", 0.0))
                                                    / grid["flow_cpu_s"])
            if kind == "shaped":
                run["design_to_grid_flow"] = design_seconds(
                    run["floor_cpu_s"], run["checking_cpu_s"], run["shaping_cpu_s"], run["layouts"],
                    run["in_place_layout_ms"]) / grid["flow_cpu_s"]
                box = next(r for r in runs if r["kind"] == "box" and r["repeat"] == repeat)
                shift = np.subtract(run["centroids"], box["centroids"])
                shift[:, 0] -= run["period"] * np.round(shift[:, 0] / run["period"])  # x periodic: the nearest image
                run["largest_centroid_difference"] = float(np.max(np.abs(shift)))
                run["largest_relative_area_difference"] = float(np.max(np.abs(
                    np.divide(run["areas"], box["areas"]) - 1.0)))
            runs.append(run)
            summary = {k: v for k, v in run.items() if k not in ("areas", "centroids")}
            print(json.dumps(summary), flush=True)
    result = {"command": " ".join(["python benchmarks/mesh_window_floor.py", *sys.argv[1:]]),
              "machine": common.machine(), "relax": args.relax, "flow": args.flow, "velocity": args.velocity,
              "runs": runs}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
