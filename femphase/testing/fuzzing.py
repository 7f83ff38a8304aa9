"""Bad-input fuzzing of ``femphase run``: every bad input gets one message.

Every bad input must end in exit code 2 with one message ``femphase: error: …`` that names
the key (and the value and what is valid), without a traceback, before any time step, and
without changing anything already in the run directory. This module generates bad inputs
systematically and checks them in-process:

* :func:`bad_inputs` ``(seed=0, count=None)`` → a list of :class:`BadInput`: for every key
  of every scene table a set of wrong types and values (strings, booleans — ``True`` is an
  int in Python —, lists, tables, negative, zero, NaN, ±inf, huge values, unknown names),
  structural corruptions (a value instead of a table, ragged lists, broken TOML, garbage and
  truncated mesh files), ``--set`` syntax errors, unusable run directories and mismatched
  ``--resume``; deterministic for a seed.
* :func:`check_bad_input` ``(item, workdir)`` → a :class:`Check`: runs
  ``femphase.cli.main(["run", scene, "-o", out, "-q", *options, "--set", …])`` in-process
  and reports the exit code, whether the message names ``item.key``, whether a traceback
  was printed, and whether the output path is byte-for-byte as before.
* :func:`run_fuzz` ``(seed=0, count=None, workdir=None)`` → a dict of counts (what
  ``benchmarks/faults.py`` reports).

Example::

    from femphase.testing.fuzzing import bad_inputs, check_bad_input
    for item in bad_inputs():
        check = check_bad_input(item, "/tmp/fuzz")
        assert check.clean, (item.description, check.message)
"""

from __future__ import annotations

import contextlib
import copy
import functools
import io
import json
import math
import os
import random
import shutil
import tempfile
import time
import warnings
from pathlib import Path
from typing import NamedTuple

from femphase.cli import main
from femphase.config import DIAGONAL_PATTERNS, FD_ADVECTION, MASS_TYPES, SOLVER_METHODS
from femphase.domains.mesh.stokes import channel_mesh
from femphase.fem.meshfiles import save_mesh
from femphase.flows import SHEAR_SCALES
from femphase.scene import LAYOUTS
from femphase.tomlio import toml_value

__all__ = ["BASE_SCENE", "MESH_FILE", "MESH_SCENE", "TARGETS", "bad_inputs", "BadInput", "Check", "check_bad_input",
           "make_run_directory", "mesh_files", "run_fuzz", "snapshot", "to_toml"]

#: A small valid scene on the structured channel: validated in milliseconds, and run (for
#: the run directory that ``--resume`` inputs need) in about a second.
BASE_SCENE: dict = {
    "name": "fuzz",
    "model": {"R": 5.0},
    "domain": {"kind": "grid", "Lx": 24.0, "Ly": 24.0, "h": 1.0},
    "particles": {"layout": "list", "centres": [[6.0, 12.0], [18.0, 12.0]], "initial_radius": 3.0},
    "numerics": {"scheme": "euler"},
    "output": {"fields": True, "observables": ["shape", "energy"]},
    "phases": [
        {"name": "relax", "duration": 2.0, "dt": 1.0, "frame_interval": 1.0},
        {"name": "shear", "duration": 2.0, "dt": 1.0, "frame_interval": 1.0, "flow": {"type": "shear", "rate": 0.1}},
    ],
}

#: The file name of the small channel mesh of :data:`MESH_SCENE` (written beside the scene).
MESH_FILE = "channel.vtu"

#: A small valid scene on a meshed channel (20 × 12, h = 1), with a Stokes flow phase (never
#: solved: every input built on it is rejected while the scene is checked).
MESH_SCENE: dict = {
    "name": "fuzz-mesh",
    "model": {"R": 3.0},
    "domain": {"kind": "mesh", "mesh": MESH_FILE},
    "particles": {"layout": "list", "centres": [[10.0, 6.0]], "initial_radius": 2.0},
    "phases": [
        {"name": "relax", "duration": 1.0, "dt": 1.0, "frame_interval": 1.0},
        {"name": "flow", "duration": 1.0, "dt": 1.0, "frame_interval": 1.0,
         "flow": {"type": "stokes", "max_velocity": 0.1}},
    ],
}

#: What the ``-o`` path is when a bad input is checked.
TARGETS = {
    "new": "a path that does not exist",
    "run": "a copy of a finished run directory of BASE_SCENE",
    "file": "a regular file",
    "under-file": "a path inside a regular file",
    "truncated": "a copy of the run directory whose checkpoint.h5 is cut to half its size",
    "garbage": "a copy of the run directory whose checkpoint.h5 is random bytes",
    "no-checkpoint": "a copy of the run directory without checkpoint.h5",
}


class BadInput(NamedTuple):
    """One bad input to ``femphase run``.

    ============ ========================================================================
    description  what is wrong (unique within :func:`bad_inputs`)
    scene        the scene: a dict (written as TOML), TOML text, raw bytes, or None for a
                 scene file that does not exist
    sets         the ``--set`` strings (each passed as ``--set STRING``)
    key          the key the error message must name (e.g. "model.mu", "--resume", "-o")
    files        (name, bytes) pairs written beside the scene (mesh files)
    options      further command-line arguments, e.g. ("--resume",)
    target       what the ``-o`` path is, a key of :data:`TARGETS`
    ============ ========================================================================
    """

    description: str
    scene: dict | str | bytes | None
    sets: tuple = ()
    key: str = ""
    files: tuple = ()
    options: tuple = ()
    target: str = "new"


class Check(NamedTuple):
    """What :func:`check_bad_input` saw.

    =========== =====================================================================
    exit_code   the exit code of ``femphase run`` (2 expected)
    names_key   the message names the expected key
    traceback   a traceback was printed, or an exception escaped ``main``
    untouched   the ``-o`` path is byte-for-byte as before (files, their bytes, the
                entries of its directories; a path that did not exist still does not)
    message     what was printed to stderr
    seconds     wall time of the call
    =========== =====================================================================
    """

    exit_code: int
    names_key: bool
    traceback: bool
    untouched: bool
    message: str
    seconds: float

    @property
    def clean(self) -> bool:
        """Rejected as required: exit 2, the key named, no traceback, nothing changed."""
        return self.exit_code == 2 and self.names_key and not self.traceback and self.untouched


# -- generating -------------------------------------------------------------------------------

_DELETE = object()
_NAN, _INF = float("nan"), float("inf")


def _set_path(data, path: str, value) -> None:
    """Set (or with ``_DELETE`` remove) the dotted ``path`` in nested dicts and lists."""
    parts = path.split(".")
    target = data
    for part in parts[:-1]:
        target = target[int(part)] if isinstance(target, list) else target.setdefault(part, {})
    last = parts[-1]
    if isinstance(target, list):
        target[int(last)] = value
    elif value is _DELETE:
        target.pop(last, None)
    else:
        target[last] = value


def _variant(base: dict, changes: dict) -> dict:
    data = copy.deepcopy(base)
    for path, value in changes.items():
        _set_path(data, path, value)
    return data


def to_toml(data: dict) -> str:
    """A scene dict as TOML text, every top-level key as ``key = <inline value>`` (so any
    structure, valid or not, survives the round trip through ``tomllib``)."""
    return "".join(f"{json.dumps(str(k))} = {toml_value(v)}\n" for k, v in data.items())


def _describe(value) -> str:
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    return toml_value(value) if not isinstance(value, (dict, list)) or len(toml_value(value)) < 40 else \
        f"{type(value).__name__} of {len(value)}"


# wrong values by the kind of a key
_TYPE_ERRORS = [("a string", "7"), ("true (a bool, not a number)", True), ("a list", [1.0]),
                ("a table", {"x": 1.0})]
_BAD_POSITIVE = _TYPE_ERRORS + [("negative", -1.0), ("zero", 0.0), ("NaN", _NAN), ("inf", _INF),
                                ("-inf", -_INF)]
_BAD_NONNEGATIVE = _TYPE_ERRORS + [("negative", -0.5), ("NaN", _NAN), ("inf", _INF), ("-inf", -_INF)]
_BAD_BOOL = [("1 (an int, not a bool)", 1), ("0 (an int, not a bool)", 0), ("the string 'true'", "true"),
             ("a list", [True])]
_BAD_INTEGER = [("a string", "3"), ("true (a bool)", True), ("a fraction", 2.5), ("zero", 0),
                ("negative", -2), ("a list", [2]), ("1e30 (a float)", 1e30)]


def _choice_errors(valid: tuple[str, ...]) -> list:
    return [("an unknown name", "bogus"), ("a number", 3), ("true", True), ("a list", [valid[0]]),
            ("an empty string", "")]


#: Scene keys of :data:`BASE_SCENE` (dotted path, wrong values, the key a message names).
def _grid_keys() -> list[tuple[str, list]]:

    keys = [(f"model.{k}", _BAD_POSITIVE) for k in ("lambda", "interface_width", "J0", "mobility", "R")]
    keys += [(f"model.{k}", _BAD_NONNEGATIVE) for k in ("gamma", "tension", "kappa", "repulsion", "mu",
                                                        "area_stiffness")]
    keys += [
        ("domain.kind", _choice_errors(("grid",))),
        ("domain.Lx", _BAD_POSITIVE + [("not a multiple of h", 24.5), ("2e9 (too many nodes)", 2e9)]),
        ("domain.Ly", _BAD_POSITIVE + [("not a multiple of h", 23.3), ("1 (fewer than 2 cells)", 1.0)]),
        ("domain.h", _BAD_POSITIVE + [("coarser than λ", 3.0), ("1e-4 (too many nodes)", 1e-4)]),
        ("domain.mesh", [("a number", 3), ("true", True), ("a list", ["a.vtu"]), ("a missing file", "missing.vtu")]),
        ("particles.layout", _choice_errors(LAYOUTS)),
        ("particles.N", _BAD_INTEGER),
        ("particles.seed", [("a string", "a"), ("true", True), ("negative", -1), ("a fraction", 1.5), ("a list", [1])]),
        ("particles.per_row", [("a string", "2"), ("true", True), ("zero", 0), ("negative", -1), ("a fraction", 1.5)]),
        ("particles.initial_radius", _BAD_POSITIVE),
        ("particles.centres", [
            ("a number", 3), ("a string", "[[6, 12]]"), ("ragged", [[6.0, 12.0], [18.0]]),
            ("triples", [[6.0, 12.0, 0.0], [18.0, 12.0, 0.0]]), ("strings inside", [["6", "12"], ["18", "12"]]),
            ("NaN inside", [[_NAN, 12.0], [18.0, 12.0]]), ("inf inside", [[6.0, _INF], [18.0, 12.0]]),
            ("bools inside", [[True, 12.0], [18.0, 12.0]]), ("a centre outside the walls", [[6.0, 12.0], [18.0, 99.0]]),
            ("empty for layout list", []), ("a table", {"x": 6.0, "y": 12.0}), ("nested deeper", [[[6.0, 12.0]]]),
        ]),
        ("particles.radii", [
            ("a number", 5.0), ("too few", [5.0]), ("too many", [5.0, 5.0, 5.0]), ("a negative radius", [5.0, -5.0]),
            ("a zero radius", [0.0, 5.0]), ("a string inside", ["5", 5.0]), ("NaN inside", [_NAN, 5.0]),
            ("true inside", [True, 5.0]), ("a table", {"a": 5.0}),
        ]),
        ("numerics.scheme", _choice_errors(("euler",))),
        ("numerics.mass", _choice_errors(MASS_TYPES)),
        ("numerics.stabilisation", [("an unknown word", "often"), ("negative", -1.0), ("NaN", _NAN), ("inf", _INF),
                                    ("true", True), ("a list", [1.0])]),
        ("numerics.solver", _choice_errors(SOLVER_METHODS)),
        ("numerics.tolerance", _BAD_POSITIVE),
        ("numerics.windows", _BAD_BOOL),
        ("numerics.threshold", _TYPE_ERRORS + [("zero", 0.0), ("0.5", 0.5), ("one", 1.0), ("negative", -0.1),
                                               ("NaN", _NAN)]),
        ("numerics.margin", _BAD_POSITIVE),
        ("numerics.diagonals", _choice_errors(DIAGONAL_PATTERNS)),
        ("numerics.blowup_margin", _BAD_POSITIVE),
        ("numerics.fd_advection", _choice_errors(FD_ADVECTION)),
        ("numerics.merged_steps", _BAD_INTEGER),
        ("output.fields", _BAD_BOOL),
        ("output.per_particle_fields", _BAD_BOOL),
        ("output.checkpoint", _BAD_BOOL),
        ("output.t1_interval", _BAD_POSITIVE),
        ("output.observables", [("a string", "order"), ("an unknown name", ["orders"]), ("a number inside", [3]),
                                ("true inside", [True]), ("a nested list", [["order"]]), ("a table", {"order": True})]),
        ("name", [("a number", 3), ("an empty string", ""), ("true", True), ("a list", ["fuzz"])]),
    ]
    for k in (0, 1):
        p = f"phases.{k}"
        keys += [
            (f"{p}.duration", _BAD_POSITIVE + [("not a multiple of dt", 2.5), ("1e300 (too many steps)", 1e300)]),
            (f"{p}.dt", _BAD_POSITIVE + [("not a divisor of the duration", 0.7), ("1e-300 (too many steps)", 1e-300)]),
            (f"{p}.frame_interval", _BAD_POSITIVE + [("not a multiple of dt", 1.5)]),
            (f"{p}.name", [("a number", 3), ("an empty string", ""), ("true", True)]),
            (f"{p}.flow", [("a number", 3), ("a string", "shear"), ("a list", ["shear"]), ("true", True)]),
        ]
    keys += [
        ("phases.1.flow.type", _choice_errors(("shear",))),
        ("phases.1.flow.rate", _TYPE_ERRORS + [("NaN", _NAN), ("inf", _INF), ("-inf", -_INF)]),
        ("phases.1.flow.scale", _choice_errors(SHEAR_SCALES)),
    ]
    return keys


def _structural(base: dict) -> list[BadInput]:
    """Corruptions of the scene's structure, written into the scene."""
    items = []
    for table in ("model", "domain", "particles", "numerics", "output"):
        for what, value in (("a number", 3), ("a string", "x"), ("a list", [1]), ("true", True)):
            items.append(BadInput(f"[{table}] is {what}", _variant(base, {table: value}), key=table))
        items.append(BadInput(f"unknown key in [{table}]", _variant(base, {f"{table}.colour": 1.0}),
                              key=f"{table}.colour"))
    for what, value in (("a number", 3), ("a string", "relax"), ("a table", {"dt": 1.0}), ("an empty list", []),
                        ("true", True)):
        items.append(BadInput(f"phases is {what}", _variant(base, {"phases": value}), key="phases"))
    for what, value in (("[3]", [3]), ('["relax"]', ["relax"]), ("[[1, 2]]", [[1, 2]]), ("[true]", [True])):
        items.append(BadInput(f"phases = {what}", _variant(base, {"phases": value}), key="phases.0"))
    items.append(BadInput("second phase is a number", _variant(base, {"phases": [base["phases"][0], 7]}),
                          key="phases.1"))
    for key in ("duration", "dt", "frame_interval"):
        items.append(BadInput(f"phases.0.{key} missing", _variant(base, {f"phases.0.{key}": _DELETE}),
                              key=f"phases.0.{key}"))
    items += [
        BadInput("unknown top-level table", _variant(base, {"modle": {"mu": 1.0}}), key="modle"),
        BadInput("unknown key in a phase", _variant(base, {"phases.0.speed": 1.0}), key="phases.0.speed"),
        BadInput("model.mu and model.area_stiffness both given",
                 _variant(base, {"model.mu": 10.0, "model.area_stiffness": 20.0}), key="model.area_stiffness"),
        BadInput("model.R and model.radius both given", _variant(base, {"model.radius": 6.0}), key="model.radius"),
        BadInput("layout random with N too large for the domain",
                 _variant(base, {"particles": {"layout": "random", "N": 40}}), key="particles.N"),
        BadInput("layout random with N = 10**15", _variant(base, {"particles": {"layout": "random", "N": 10**15}}),
                 key="particles.N"),
        BadInput("layout hexagonal with N = 2**62", _variant(base, {"particles": {"layout": "hexagonal", "N": 2**62}}),
                 key="particles.N"),
        BadInput("layout random with discs wider than the channel",
                 _variant(base, {"particles": {"layout": "random", "N": 2, "initial_radius": 13.0}}),
                 key="particles.initial_radius"),
        BadInput("layout single with a disc wider than the channel",
                 _variant(base, {"particles": {"layout": "single", "initial_radius": 13.0}}),
                 key="particles.initial_radius"),
        BadInput("layout list with a disc longer than the period",
                 _variant(base, {"domain.Lx": 12.0, "particles": {"layout": "list", "centres": [[6.0, 12.0]],
                                                                   "initial_radius": 7.0}}),
                 key="particles.initial_radius"),
        BadInput("layout hexagonal, N not a multiple of per_row",
                 _variant(base, {"particles": {"layout": "hexagonal", "N": 4, "per_row": 3}}), key="particles.N"),
        BadInput("layout hexagonal, per_row larger than N",
                 _variant(base, {"particles": {"layout": "hexagonal", "N": 4, "per_row": 8}}), key="particles.per_row"),
        BadInput("layout list without centres", _variant(base, {"particles.centres": _DELETE}),
                 key="particles.centres"),
        BadInput("model R so large the listed particles overfill the domain", _variant(base, {"model.R": 14.0}),
                 key="model.radius"),
        BadInput("stokes flow on the structured channel",
                 _variant(base, {"phases.1.flow": {"type": "stokes", "max_velocity": 0.1}}), key="phases.1.flow.type"),
        BadInput("shear flow with an extra key", _variant(base, {"phases.1.flow.frequency": 1.0}),
                 key="phases.1.flow.frequency"),
        BadInput("shear flow without rate", _variant(base, {"phases.1.flow.rate": _DELETE}), key="phases.1.flow.rate"),
        BadInput("poiseuille flow with rate NaN",
                 _variant(base, {"phases.1.flow": {"type": "poiseuille", "rate": _NAN}}), key="phases.1.flow.rate"),
        BadInput("poiseuille flow with rate a string",
                 _variant(base, {"phases.1.flow": {"type": "poiseuille", "rate": "fast"}}), key="phases.1.flow.rate"),
        BadInput("oscillating shear without frequency",
                 _variant(base, {"phases.1.flow": {"type": "oscillating_shear", "rate": 0.1}}),
                 key="phases.1.flow.frequency"),
        BadInput("oscillating shear with frequency true",
                 _variant(base, {"phases.1.flow": {"type": "oscillating_shear", "rate": 0.1, "frequency": True}}),
                 key="phases.1.flow.frequency"),
        BadInput("oscillating shear with phase inf",
                 _variant(base, {"phases.1.flow": {"type": "oscillating_shear", "rate": 0.1, "frequency": 1.0,
                                                   "phase": _INF}}), key="phases.1.flow.phase"),
        BadInput("flow of no type and an extra key", _variant(base, {"phases.1.flow": {"rate": 0.1}}),
                 key="phases.1.flow.rate"),
        BadInput("fd-heun with dt above its stability limit", _variant(base, {"numerics.scheme": "fd-heun"}),
                 key="phases.0.dt"),
        BadInput("tensor solver with the consistent mass",
                 _variant(base, {"numerics.solver": "tensor", "numerics.mass": "consistent"}), key="numerics.solver"),
        BadInput("tensor solver with alternating diagonals",
                 _variant(base, {"numerics.solver": "tensor", "numerics.diagonals": "alternating"}),
                 key="numerics.solver"),
        BadInput("consistent mass under the adaptive scheme",
                 _variant(base, {"numerics.scheme": "adaptive", "numerics.mass": "consistent"}), key="numerics.mass"),
    ]
    for what, function in (("a missing module", "no_such_module_xyz:f"), ("a missing attribute", "math:no_such"),
                           ("no colon", "math.sin"), ("not callable", "math:pi"), ("a relative import", "..x:y"),
                           ("an empty string", ""), ("a number", 3)):
        items.append(BadInput(f"python flow function {what}",
                              _variant(base, {"phases.1.flow": {"type": "python", "function": function}}),
                              key="phases.1.flow.function"))
    for what, function, extra in (("of the wrong signature", "math:sin", {}),
                                  ("returning one array", "math:hypot", {}),
                                  ("taking no arguments", "os:getcwd", {"row_flow": True}),
                                  ("returning -inf", "numpy:log", {"row_flow": True})):
        items.append(BadInput(f"python flow function {what}",
                              _variant(base, {"phases.1.flow": {"type": "python", "function": function, **extra}}),
                              key="phases.1.flow.function"))
    for key, value in (("row_flow", "yes"), ("steady", 0)):
        items.append(BadInput(f"python flow {key} = {value!r}",
                              _variant(base, {"phases.1.flow": {"type": "python", "function": "math:hypot",
                                                                key: value}}), key=f"phases.1.flow.{key}"))
    return items


def _set_syntax(base: dict) -> list[BadInput]:
    """Malformed ``--set`` assignments."""
    cases = [
        ("model.mu", "--set"), ("=3", "--set"), ("", "--set"), (".mu=3", "--set"), ("model..mu=3", "--set"),
        ("model.=3", "--set"), ("phases.9.dt=1", "phases.9"), ("phases.x.dt=1", "phases.x"),
        ("phases.-1.dt=1", "phases.-1"), ("phases.2=3", "phases.2"), ("phases.0.dt.x=1", "phases.0.dt"),
        ("phases.0.flow.type.x=1", "phases.0.flow.type"), ("name.first=1", "name"), ("model.R.x=1", "model.R"),
        ("particles.centres.5=1", "particles.centres.5"), ("particles.centres.0.7=1", "particles.centres.0.7"),
        ("model=3", "model"), ("domain=[1]", "domain"), ("particles=true", "particles"), ("numerics='x'", "numerics"),
        ("output=1", "output"), ("phases=3", "phases"), ("phases=[3]", "phases.0"), ("phases.0=3", "phases.0"),
        ("phases.1={}", "phases.1.duration"), ("model.mu=", "model.mu"), ("model.mu=[1,", "model.mu"),
        ("model.mu=1 2", "model.mu"), ("model.mu=0x", "model.mu"), ("particles.N=99999999999999999999", "particles.N"),
        ("particles.N=1e400", "particles.N"), ("model.mu={x=1}", "model.mu"), ("model.colour=3", "model.colour"),
        ("output.observables=order", "output.observables"), ("numerics.scheme=rk4", "numerics.scheme"),
        ("phases.1.flow.type=vortex", "phases.1.flow.type"), ("domain.kind=sphere", "domain.kind"),
    ]
    return [BadInput(f"--set {text!r}", base, (text,), key) for text, key in cases]


@functools.cache
def mesh_files() -> dict[str, bytes]:
    """Mesh files for the mesh inputs (name → bytes): the valid channel of
    :data:`MESH_SCENE`, and damaged ones."""
    import meshio
    import numpy as np


    files = {}
    with tempfile.TemporaryDirectory() as tmp:
        mesh = channel_mesh(20.0, 12.0, 20, 12)
        save_mesh(mesh, Path(tmp) / MESH_FILE)
        files[MESH_FILE] = (Path(tmp) / MESH_FILE).read_bytes()
        points = np.vstack([mesh.p, np.zeros(mesh.p.shape[1])]).T
        meshio.write(Path(tmp) / "lines.vtu", meshio.Mesh(points, [("line", mesh.facets.T)]))
        files["lines.vtu"] = (Path(tmp) / "lines.vtu").read_bytes()
        bad = points.copy()
        bad[3] = np.nan
        meshio.write(Path(tmp) / "nan.vtu", meshio.Mesh(bad, [("triangle", mesh.t.T)]))
        files["nan.vtu"] = (Path(tmp) / "nan.vtu").read_bytes()
        skew = points.copy()
        skew[:, 0] += 0.3 * skew[:, 1] * (skew[:, 0] > 19.5)  # the right side is no copy of the left
        meshio.write(Path(tmp) / "skew.vtu", meshio.Mesh(skew, [("triangle", mesh.t.T)]))
        files["skew.vtu"] = (Path(tmp) / "skew.vtu").read_bytes()
        meshio.write(Path(tmp) / "outside.vtu", meshio.Mesh(points, [("triangle", mesh.t.T + len(points))]))
        files["outside.vtu"] = (Path(tmp) / "outside.vtu").read_bytes()
    rng = random.Random(1)
    noise = bytes(rng.getrandbits(8) for _ in range(4096))
    valid = files[MESH_FILE]
    files.update({
        "noise.msh": noise, "noise.vtu": noise, "noise.xdmf": noise, "noise.stl": noise, "noise.vtk": noise,
        "noise.obj": noise, "noise.off": noise, "noise.ply": noise, "noise.mesh": noise, "noise.xyz": noise,
        "empty.msh": b"", "empty.vtu": b"", "text.msh": b"hello\n",
        "version.msh": b"$MeshFormat\n9.9 0 8\n$EndMeshFormat\n",
        "nodes.msh": b"$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n",
        "truncated.vtu": valid[: len(valid) // 2], "tail.vtu": valid[len(valid) // 2:],
        "flipped.vtu": valid[:200] + bytes(b ^ 0x5A for b in valid[200:400]) + valid[400:],
    })
    return files


def _mesh_inputs() -> list[BadInput]:
    files = mesh_files()
    base = MESH_SCENE
    valid = ((MESH_FILE, files[MESH_FILE]),)
    items = []
    for name in files:
        if name == MESH_FILE:
            continue
        items.append(BadInput(f"mesh domain, mesh file {name}", _variant(base, {"domain.mesh": name}),
                              key="domain.mesh", files=((name, files[name]),)))
    for name in ("noise.msh", "truncated.vtu", "empty.vtu", "nan.vtu"):
        items.append(BadInput(f"grid domain, mesh file {name}", _variant(BASE_SCENE, {"domain.mesh": name}),
                              key="domain.mesh", files=((name, files[name]),)))
    items.append(BadInput("grid domain, mesh file of another channel",
                          _variant(BASE_SCENE, {"domain.mesh": MESH_FILE}), key="domain.mesh", files=valid))
    cases = [
        ("domain.mesh", ""), ("domain.mesh", 3), ("domain.mesh", "missing.vtu"), ("domain.mesh", _DELETE),
        ("domain.periodic", "left"), ("domain.periodic", ["left"]), ("domain.periodic", ["left", "left"]),
        ("domain.periodic", [1, 2]), ("domain.periodic", ["top", "bottom"]), ("domain.periodic", {"a": 1}),
        ("domain.boundaries", "left"), ("domain.boundaries", {"left": "one"}), ("domain.boundaries", {"left": True}),
        ("domain.boundaries", {}), ("domain.h", 0.0), ("domain.h", "1"), ("domain.h", _NAN), ("domain.h", True),
        ("domain.h", 3.0), ("domain.h", 0.3), ("domain.periodic", ["right", "left"]), ("domain.Lx", 99.0),
        ("domain.Ly", 99.0), ("domain.Lx", -20.0), ("domain.Ly", "12"),
        ("domain.radius", 1.0), ("numerics.scheme", "fd-heun"), ("numerics.solver", "tensor"),
        ("phases.1.flow.max_velocity", "fast"), ("phases.1.flow.max_velocity", _NAN),
        ("phases.1.flow.max_velocity", True), ("phases.1.flow.viscosity", 0.0), ("phases.1.flow.viscosity", -1.0),
        ("phases.1.flow.viscosity", _INF), ("phases.1.flow.viscosity", "thick"), ("phases.1.flow.flux", 1.0),
        ("phases.1.flow.rate", 1.0), ("particles.centres", [[10.0, 60.0]]),
    ]
    for path, value in cases:
        key = path
        if path == "domain.mesh" and value is _DELETE:
            description = "mesh domain without a mesh key"
        else:
            description = f"mesh domain, {path} = {_describe(value)}"
        if path == "domain.periodic" and value == ["top", "bottom"]:
            description += " (no such boundaries)"
        if path == "domain.h" and value == 3.0:
            description += " (coarser than λ)"
        if path == "domain.h" and value == 0.3:
            description += " (finer than the mesh's nodes)"
        if path == "domain.periodic" and value == ["right", "left"]:
            description += " (sides in the wrong order)"
        if path == "phases.1.flow.flux":
            key = "phases.1.flow"  # two driving keys
        if path == "particles.centres":
            description += " (outside the mesh)"
        items.append(BadInput(description, _variant(base, {path: value}), key=key, files=valid))
    return items


def _raw_inputs() -> list[BadInput]:
    """Scene files that are no valid TOML, or none at all."""
    return [
        BadInput("scene file does not exist", None, key="scene"),
        BadInput("scene file is empty (no phases)", "", key="phases"),
        BadInput("scene is broken TOML (unclosed table header)", "[model\nmu = 1\n", key="scene"),
        BadInput("scene is broken TOML (duplicate key)", "[model]\nmu = 1\nmu = 2\n", key="scene"),
        BadInput("scene is broken TOML (bare value)", "3\n", key="scene"),
        BadInput("scene is not UTF-8", b"name = \"\xff\xfe\"\n", key="scene"),
        BadInput("scene is random bytes", bytes(random.Random(2).getrandbits(8) for _ in range(256)), key="scene"),
        BadInput("scene is deeply nested arrays", "x = " + "[" * 3000 + "]" * 3000 + "\n", key="scene"),
        BadInput("scene is JSON", json.dumps({"model": {"mu": 1}}), key="scene"),
    ]


def _directory_inputs(base: dict) -> list[BadInput]:
    """Unusable run directories and mismatched ``--resume``."""
    shorter = copy.deepcopy(base)
    shorter["phases"] = shorter["phases"][:1]
    return [
        BadInput("-o is a regular file", base, key="-o", target="file"),
        BadInput("-o is a regular file, with --resume", base, key="-o", options=("--resume",), target="file"),
        BadInput("-o is inside a regular file", base, key="-o", target="under-file"),
        BadInput("-o holds a run, without --resume or --overwrite", base, key="-o", target="run"),
        BadInput("--resume of a directory that does not exist", base, key="--resume", options=("--resume",)),
        BadInput("--resume with a truncated checkpoint", base, key="--resume", options=("--resume",),
                 target="truncated"),
        BadInput("--resume with a checkpoint of random bytes", base, key="--resume", options=("--resume",),
                 target="garbage"),
        BadInput("--resume of a run without checkpoint.h5", base, key="--resume", options=("--resume",),
                 target="no-checkpoint"),
        BadInput("--resume with another model.mu", base, ("model.mu=10",), "model.area_stiffness", (),
                 ("--resume",), "run"),
        BadInput("--resume with another model.R", base, ("model.R=6",), "model.radius", (), ("--resume",), "run"),
        BadInput("--resume with another initial radius", base, ("particles.initial_radius=2.5",),
                 "particles.initial_radius", (), ("--resume",), "run"),
        BadInput("--resume with other centres", base, ("particles.centres=[[7.0, 12.0], [18.0, 12.0]]",),
                 "particles.centres", (), ("--resume",), "run"),
        BadInput("--resume on another domain", base, ("domain.Lx=30",), "domain.Lx", (), ("--resume",), "run"),
        BadInput("--resume with more observables", base, ('output.observables=["order"]',), "output.observables",
                 (), ("--resume",), "run"),
        BadInput("--resume with other diagonals", base, ("numerics.diagonals='left'",), "numerics.diagonals", (),
                 ("--resume",), "run"),
        BadInput("--resume changing a finished phase's duration", base, ("phases.0.duration=3",),
                 "phases.0.duration", (), ("--resume",), "run"),
        BadInput("--resume changing a finished phase's flow", base, ("phases.0.flow={type='shear', rate=0.2}",),
                 "phases.0.flow", (), ("--resume",), "run"),
        BadInput("--resume dropping a finished phase", shorter, key="phases", options=("--resume",), target="run"),
        BadInput("--resume with --method fd", base, key="--method", options=("--resume", "--method", "fd"),
                 target="run"),
        BadInput("--resume and --overwrite together", base, key="--overwrite", options=("--resume", "--overwrite"),
                 target="run"),
        BadInput("--method of an unknown name", base, key="--method", options=("--method", "rk4")),
    ]


def _systematic() -> list[BadInput]:
    items: list[BadInput] = []
    carrier = 0
    for path, bad_values in _grid_keys():
        for what, value in bad_values:
            description = f"{path} = {_describe(value)} ({what})"
            if path == "particles.N" or path == "particles.per_row" or path == "particles.seed":
                base = _variant(BASE_SCENE, {"particles": {"layout": "random", "N": 2, "initial_radius": 3.0}})
                if path == "particles.per_row":
                    base = _variant(BASE_SCENE, {"particles": {"layout": "hexagonal", "N": 4, "initial_radius": 3.0}})
            else:
                base = BASE_SCENE
            carrier += 1
            if carrier % 2 and path != "model.radius":  # every other one through --set
                items.append(BadInput(f"--set {description}", base, (f"{path}={toml_value(value)}",), path))
            else:
                scene = _variant(base, {path: value})
                if path.startswith("model.") and path != "model.R":
                    scene["model"].pop("R", None)
                    scene["model"][path.split(".")[1]] = value
                items.append(BadInput(description, scene, key=path))
    items += _structural(BASE_SCENE)
    items += _set_syntax(BASE_SCENE)
    items += _mesh_inputs()
    items += _raw_inputs()
    items += _directory_inputs(BASE_SCENE)
    return items


def bad_inputs(seed: int = 0, count: int | None = None) -> list[BadInput]:
    """Distinct bad inputs to ``femphase run``, deterministic for ``seed``.

    ``count`` None: every systematic input (several hundred). A smaller count: a seeded
    sample of them (in their order); a larger one: all of them plus seeded random ones
    (random wrong numbers, strings and lists for numeric keys, through ``--set``)."""
    items = _systematic()
    rng = random.Random(seed)
    if count is not None and count < len(items):
        chosen = sorted(rng.sample(range(len(items)), count))
        return [items[i] for i in chosen]
    if count is not None:
        seen = {item.description for item in items}
        numeric = [(path, ">=0" if values is _BAD_NONNEGATIVE else ">0") for path, values in _grid_keys()
                   if values in (_BAD_POSITIVE, _BAD_NONNEGATIVE)]
        while len(items) < count:
            path, relation = rng.choice(numeric)
            kind = rng.randrange(4)
            if kind == 0:
                value = -10 ** rng.uniform(-6, 6)
            elif kind == 1:
                value = "".join(rng.choice("abcxyz_-+ ") for _ in range(rng.randint(1, 8))) or "x"
            elif kind == 2:
                value = [round(rng.uniform(0, 10), 3) for _ in range(rng.randint(1, 3))]
            else:
                value = rng.choice([-_INF, _INF, _NAN, True, False, {"v": 1}])
                if value is False and relation == ">=0":
                    value = "false"
            description = f"--set {path} = {_describe(value)} (random, seed {seed})"
            if description in seen:
                continue
            seen.add(description)
            items.append(BadInput(description, BASE_SCENE, (f"{path}={toml_value(value)}",), path))
    return items


# -- checking -------------------------------------------------------------------------------

def snapshot(path: Path) -> dict | None:
    """Everything under ``path``: relative name → file bytes (None for a directory); None
    when it does not exist."""
    path = Path(path)
    if not path.exists():
        return None
    if path.is_file():
        return {".": path.read_bytes()}
    out = {}
    for root, dirs, files in os.walk(path):
        for name in dirs:
            out[os.path.relpath(os.path.join(root, name), path)] = None
        for name in files:
            full = os.path.join(root, name)
            out[os.path.relpath(full, path)] = Path(full).read_bytes()
    return out


def make_run_directory(path: str | Path) -> Path:
    """A finished run of :data:`BASE_SCENE` in ``path`` (the run directory that ``--resume``
    inputs are given); about a second."""

    path = Path(path)
    scene = path.parent / f"{path.name}.scene.toml"
    scene.write_text(to_toml(BASE_SCENE))
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err, \
            warnings.catch_warnings():
        code = main(["run", str(scene), "-o", str(path), "-q"])
    if code != 0:
        raise RuntimeError(f"the base scene did not run (exit {code}): {err.getvalue()}")
    return path


def _template(workdir: Path) -> Path:
    template = workdir / "template-run"
    if not (template / "checkpoint.h5").is_file():
        if template.exists():
            shutil.rmtree(template)
        make_run_directory(template)
    return template


def _prepare_target(kind: str, place: Path, workdir: Path, template: Path | None) -> Path:
    if kind == "new":
        return place / "out"
    if kind == "file":
        out = place / "out"
        out.write_text("not a directory\n")
        return out
    if kind == "under-file":
        (place / "blocker").write_text("a regular file\n")
        return place / "blocker" / "out"
    if kind not in TARGETS:
        raise ValueError(f"unknown target {kind!r}; one of {sorted(TARGETS)}")
    out = place / "out"
    shutil.copytree(template or _template(workdir), out)
    checkpoint = out / "checkpoint.h5"
    if kind == "truncated":
        data = checkpoint.read_bytes()
        checkpoint.write_bytes(data[: len(data) // 2])
    elif kind == "garbage":
        checkpoint.write_bytes(bytes(random.Random(3).getrandbits(8) for _ in range(4096)))
    elif kind == "no-checkpoint":
        checkpoint.unlink()
    return out


def check_bad_input(item: BadInput, workdir: str | Path, *, target: str | None = None, resume: bool = False,
                    template: str | Path | None = None) -> Check:
    """Run ``femphase run`` in-process on ``item`` and report what happened (:class:`Check`).

    ``workdir``: a folder for the scene and output (each call uses a fresh subfolder).
    ``target``: overrides ``item.target`` (e.g. "run": give every input a finished run
    directory as ``-o``); ``resume``: add ``--resume``. ``template``: a finished run
    directory of :data:`BASE_SCENE` to copy for the targets that need one (default: made
    once in ``workdir``, :func:`make_run_directory`)."""

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    place = Path(tempfile.mkdtemp(prefix="case-", dir=workdir))
    scene_path = place / "scene.toml"
    if isinstance(item.scene, dict):
        scene_path.write_text(to_toml(item.scene))
    elif isinstance(item.scene, str):
        scene_path.write_text(item.scene)
    elif isinstance(item.scene, bytes):
        scene_path.write_bytes(item.scene)
    for name, data in item.files:
        (place / name).write_bytes(data)
    output = _prepare_target(target or item.target, place, workdir, Path(template) if template else None)
    options = list(item.options)
    if resume and "--resume" not in options:
        options.append("--resume")
    argv = ["run", str(scene_path), "-o", str(output), "-q", *options]
    for assignment in item.sets:
        argv += ["--set", assignment]
    before = snapshot(output)
    out, err = io.StringIO(), io.StringIO()
    escaped = False
    start = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's own errors (exit 2 with a usage line)
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:  # an escaped exception is what this looks for
            import traceback

            traceback.print_exc(file=err)
            code, escaped = 1, True
    seconds = time.perf_counter() - start
    message = err.getvalue()
    return Check(
        exit_code=code,
        names_key=bool(item.key) and item.key in message,
        traceback=escaped or "Traceback (most recent call last)" in message + out.getvalue(),
        untouched=snapshot(output) == before,
        message=message.strip(),
        seconds=seconds,
    )


def run_fuzz(seed: int = 0, count: int | None = None, workdir: str | Path | None = None,
             into_run: bool = True) -> dict:
    """Check every input of :func:`bad_inputs` and count the outcomes.

    With ``into_run``, every input whose target is a new path is checked a second time with
    a finished run directory as ``-o`` and ``--resume``, which must stay byte-for-byte as it
    was. Returns {"tried", "rejected_cleanly", "exit_2", "names_key", "tracebacks",
    "untouched", "seconds", "failures": [{"description", "pass", "exit_code", …}]}, counted
    over all checks (``tried`` counts checks, ``inputs`` the distinct inputs)."""
    items = bad_inputs(seed, count)
    own = workdir is None
    folder = Path(tempfile.mkdtemp(prefix="femphase-fuzz-")) if own else Path(workdir)
    folder.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    counts = {"inputs": len(items), "tried": 0, "rejected_cleanly": 0, "exit_2": 0, "names_key": 0,
              "tracebacks": 0, "untouched": 0}
    failures = []
    try:
        template = _template(folder)
        runs = [(item, None, False) for item in items]
        if into_run:
            runs += [(item, "run", True) for item in items if item.target == "new" and not item.options]
        for item, target, resume in runs:
            check = check_bad_input(item, folder, target=target, resume=resume, template=template)
            counts["tried"] += 1
            counts["rejected_cleanly"] += check.clean
            counts["exit_2"] += check.exit_code == 2
            counts["names_key"] += check.names_key
            counts["tracebacks"] += check.traceback
            counts["untouched"] += check.untouched
            if not check.clean:
                failures.append({"description": item.description, "pass": "into a run with --resume" if resume
                                 else "as given", "key": item.key, "exit_code": check.exit_code,
                                 "names_key": check.names_key, "traceback": check.traceback,
                                 "untouched": check.untouched, "message": check.message[-2000:]})
    finally:
        if own:
            shutil.rmtree(folder, ignore_errors=True)
    return {**counts, "seconds": time.perf_counter() - start, "failures": failures}
