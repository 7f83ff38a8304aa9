"""Scenes on meshed channels, and running them into run directories.

A mesh scene is an ordinary scene (``docs/scenes.md``) whose ``[domain]`` table reads

    [domain]
    kind = "mesh"                      # the unstructured path (the default "grid" is the lattice)
    mesh = "../meshes/obstacle.vtu"    # any file meshio reads, relative to the scene
    periodic = ["left", "right"]       # optional: the periodic pair of boundary names
    boundaries = {left = 1, right = 2} # optional: names of the file's integer tags
    h = 1.0                            # optional: nominal spacing (default: median edge)

Lx and Ly follow from the mesh (the period and the wall-to-wall extent) and may be omitted.
Phases take every flow of the structured solver (evaluated at the mesh's points) and

    flow = { type = "stokes", max_velocity = 0.1 }   # or flux = …, or pressure_drop = …

the Stokes flow of the same mesh (:func:`femphase.unstructured.transport.stokes_flow`); its
unit solution is cached next to the mesh as ``<mesh>.stokes.npz``. Particle layouts are the
structured scenes' (single, hexagonal, random, list), restricted to the meshed domain: random
discs are drawn inside it, clear of every wall and obstacle.

``femphase run SCENE.toml -o DIR [--set key=value ...] [--resume]`` runs mesh scenes too.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..analysis.shape import ShapeObservables
from ..errors import SceneError
from ..flows import flow_from_spec
from ..io import load_observers, to_toml
from ..scene import (
    MAX_AREA_FRACTION, Phase, Scene, clear_of_discs, hexagonal_centres, read_scene_data, scene_from_dict,
)
from ..simulation import Frame, ProgressBar, RunDirectory, Simulation, Tracker
from .domain import PERIODIC_PAIR, MeshDomain, read_domain
from .shape import mesh_shape_observables
from .state import MeshState, load_mesh_checkpoint, mesh_discs_state, save_mesh_checkpoint
from .stepping import UnstructuredStepper
from .transport import stokes_drive, stokes_flow, unit_stokes_flow
from .windows import MeshWindowPolicy


MESH_DOMAIN_KEYS = ("kind", "mesh", "h", "periodic", "boundaries", "Lx", "Ly")


@dataclass
class MeshScene:
    """A validated scene on a meshed channel.

    ``scene`` is the ordinary :class:`~femphase.scene.Scene` (its domain's Lx, Ly are the
    mesh's period and height, h the nominal spacing); ``domain_table`` is the scene's own
    ``[domain]`` table (written back to run directories).
    """

    scene: Scene
    domain: MeshDomain
    domain_table: dict
    mesh_path: Path
    _unit_flows: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        data = self.scene.to_dict()
        data["domain"] = {**self.domain_table, "mesh": str(self.mesh_path.resolve())}
        return data

    def flow(self, phase: Phase):
        """The phase's flow: a StokesFlow on the mesh or an analytic Flow."""
        spec = phase.flow
        if spec.get("type") != "stokes":
            return flow_from_spec(spec, self.scene.domain.Ly)
        _, _, viscosity = stokes_drive(spec)
        if viscosity not in self._unit_flows:
            cache = self.mesh_path.with_name(self.mesh_path.name + ".stokes.npz")
            self._unit_flows[viscosity] = unit_stokes_flow(self.domain, viscosity, cache)
        return stokes_flow(self.domain, spec, self._unit_flows[viscosity])

    def window_policy(self) -> MeshWindowPolicy:
        n = self.scene.numerics
        return MeshWindowPolicy.for_spacing(self.domain.spacing, threshold=n.threshold,
                                            margin=n.margin, enabled=n.windows)

    def initial_state(self) -> MeshState:
        """Discs of radius initial_radius at the layout's centres, inside the domain."""
        scene = self.scene
        r0 = scene.particles.initial_radius
        initial = np.full(scene.n_particles, r0) if r0 is not None else 0.5 * scene.radii
        centres = mesh_initial_centres(self, float(np.max(initial)))
        return mesh_discs_state(self.domain, centres, scene.radii, initial,
                                scene.model.interface_width, self.window_policy())


def mesh_initial_centres(mesh_scene: MeshScene, initial_radius: float) -> np.ndarray:
    """Centres (N, 2) for the scene's layout; raises SceneError when one is outside the domain."""
    p, domain = mesh_scene.scene.particles, mesh_scene.domain
    low, high = domain.y_range
    if p.layout == "random":
        return random_mesh_centres(domain, p.N, initial_radius, p.seed)
    if p.layout == "hexagonal":
        centres = hexagonal_centres(p.N, domain.period, high - low, p.per_row) + [domain.x0, low]
    elif p.layout == "list" or p.centres:
        centres = np.asarray(p.centres, dtype=float)[: 1 if p.layout == "single" else None]
    else:
        centres = np.array([[domain.x0 + 0.5 * domain.period, 0.5 * (low + high)]])
    outside = ~domain.inside(centres[:, 0], centres[:, 1])
    if outside.any():
        raise SceneError("particles.centres", centres[outside].tolist(), "centres inside the meshed domain")
    return centres


def random_mesh_centres(domain: MeshDomain, n: int, radius: float, seed: int,
                        attempts: int = 200_000) -> np.ndarray:
    """Uniformly random centres of non-overlapping discs of ``radius`` inside the domain,
    each disc clear of every wall and obstacle (as :func:`femphase.scene.random_centres`)."""
    rng = np.random.default_rng(seed)
    low, high = domain.y_range
    walls = domain.mesh.p[:, np.unique(domain.mesh.facets[:, domain.wall_facets])]
    centres = np.empty((0, 2))
    batch = 256
    for _ in range(0, attempts, batch):
        candidates = np.stack([domain.x0 + rng.uniform(0, domain.period, batch), rng.uniform(low, high, batch)], 1)
        dx = np.mod(walls[0][None] - candidates[:, :1] + 0.5 * domain.period, domain.period) - 0.5 * domain.period
        clear = np.hypot(dx, walls[1][None] - candidates[:, 1:]).min(axis=1) >= radius
        candidates = candidates[clear & domain.inside(candidates[:, 0], candidates[:, 1])]
        for candidate in candidates:
            if clear_of_discs(centres, candidate, domain.period, radius):
                centres = np.vstack([centres, candidate])
                if len(centres) == n:
                    return centres
    raise SceneError(
        "particles.N", n,
        f"only {len(centres)} non-overlapping initial discs of radius {radius:g} fit after {attempts} "
        "tries; use fewer particles or a smaller particles.initial_radius",
    )


def mesh_scene_from_dict(data: dict, base_dir: str | Path = ".") -> MeshScene:
    """Validate a mesh scene given as nested dicts (the parsed TOML)."""
    table = dict(data.get("domain", {}))
    for key in table:
        if key not in MESH_DOMAIN_KEYS:
            raise SceneError(f"domain.{key}", table[key],
                             f"not a key of a mesh domain; valid: {', '.join(MESH_DOMAIN_KEYS)}")
    if table.get("kind") != "mesh":
        raise SceneError("domain.kind", table.get("kind"), '"mesh" for a scene on a meshed channel')
    if not table.get("mesh"):
        raise SceneError("domain.mesh", table.get("mesh"), "the mesh file of a mesh domain")
    periodic = tuple(table.get("periodic", PERIODIC_PAIR))
    if len(periodic) != 2:
        raise SceneError("domain.periodic", list(periodic), "two boundary names [min side, max side]")
    mesh_path = Path(base_dir) / table["mesh"]
    domain = read_domain(mesh_path, periodic=periodic, names=table.get("boundaries"))
    low, high = domain.y_range
    extents = {"Lx": domain.period, "Ly": high - low}
    for key, value in extents.items():
        if key in table and not np.isclose(table[key], value, rtol=1e-6):
            raise SceneError(f"domain.{key}", table[key], f"the mesh's value {value:g} (or leave it out)")
    h = table.get("h", domain.spacing)

    # the shared validator checks everything but the domain: give it a lattice channel of the
    # mesh's size, and flows and centres it knows (stokes flows and centres are checked here)
    checked = {key: value for key, value in data.items() if key != "domain"}
    checked["domain"] = {key: h * max(2, round(value / h)) for key, value in extents.items()} | {"h": h}
    checked["phases"] = [dict(phase) for phase in data.get("phases", [])]
    for phase in checked["phases"]:
        if isinstance(phase.get("flow"), dict) and phase["flow"].get("type") == "stokes":
            phase["flow"] = {"type": "none"}
    if "particles" in data:
        checked["particles"] = {k: v for k, v in data["particles"].items() if k != "centres"}
        if "centres" in data["particles"]:
            checked["particles"]["centres"] = [[0.0, 0.0]] * len(data["particles"]["centres"])
    base = scene_from_dict(checked, base_dir)
    phases = tuple(replace(p, flow=dict(raw.get("flow", p.flow)))
                   for p, raw in zip(base.phases, data.get("phases", [])))
    particles = replace(base.particles, centres=data.get("particles", {}).get("centres"))
    scene = replace(base, domain=replace(base.domain, Lx=extents["Lx"], Ly=extents["Ly"], h=h,
                                         mesh=str(table["mesh"])),
                    particles=particles, phases=phases)
    mesh_scene = MeshScene(scene, domain, table, mesh_path)
    fraction = float(np.sum(np.pi * scene.radii**2) / domain.area)
    if fraction > MAX_AREA_FRACTION:
        raise SceneError("particles.N", scene.n_particles, f"the particles' total area is {fraction:.2f} × "
                         f"the meshed domain's; at most {MAX_AREA_FRACTION}")
    if scene.particles.layout != "random":  # fixed centres: check them now, not at the run
        mesh_initial_centres(mesh_scene, 0.0)
    for i, phase in enumerate(phases):
        if phase.flow.get("type") == "stokes":
            try:
                stokes_drive(phase.flow)
            except SceneError as exc:
                raise SceneError(f"phases.{i}.{exc.key}", exc.value, exc.valid) from None
    return mesh_scene


def load_mesh_scene(path: str | Path, assignments: list[str] | None = None) -> MeshScene:
    """Read and validate a mesh scene file, applying ``--set`` assignments first."""
    return mesh_scene_from_dict(read_scene_data(path, assignments), Path(path).parent)


class UnstructuredSimulation(Simulation):
    """:class:`~femphase.simulation.Simulation` on a meshed channel (``method="fem"`` only).

    ``discretisation`` is the :class:`MeshDomain` (it has the ``mesh``, ``dof_map`` and
    ``operators`` that trackers use). Run directories hold the mesh state's checkpoint
    (:class:`MeshCheckpoint`), so the scene seen by :class:`RunDirectory` has its own
    checkpoint switched off.
    """

    def __init__(self, mesh_scene: MeshScene, method: str = "fem",
                 observers: dict[str, np.ndarray] | None = None) -> None:
        if method != "fem":
            raise SceneError("--method", method, '"fem" (the finite-difference reference needs the lattice)')
        self.mesh_scene, self.method = mesh_scene, method
        scene = mesh_scene.scene
        self.scene = replace(scene, output=replace(scene.output, checkpoint=False))
        self.discretisation = mesh_scene.domain
        self._order = None
        self._observers = observers or None

    def stepper(self, phase: Phase, radii: np.ndarray) -> UnstructuredStepper:
        return UnstructuredStepper(self.discretisation, self.scene.model, self.scene.numerics, phase.dt,
                                   self.mesh_scene.flow(phase), radii)

    def shape(self, state: MeshState) -> ShapeObservables:
        return mesh_shape_observables(state)

    def period_x(self) -> float:
        return self.discretisation.period


class MeshCheckpoint(Tracker):
    """Writes ``checkpoint.npz`` (a :class:`MeshState`) every frame and the mesh scene's own
    ``scene.toml``; place it after the :class:`RunDirectory` of the same directory."""

    def __init__(self, directory: str | Path, mesh_scene: MeshScene) -> None:
        self.directory, self.mesh_scene = Path(directory), mesh_scene

    def start(self, simulation: Simulation, state: MeshState) -> None:
        self.simulation = simulation
        (self.directory / "scene.toml").write_text(to_toml(self.mesh_scene.to_dict()))

    def frame(self, frame: Frame) -> None:
        if self.mesh_scene.scene.output.checkpoint:
            save_mesh_checkpoint(self.directory / "checkpoint.npz", frame.state, self.simulation.observers())


def run_mesh_scene(mesh_scene: MeshScene, directory: str | Path, *, resume: bool = False,
                   progress: bool | None = None) -> MeshState:
    """Run a mesh scene into a run directory (the layout of :mod:`femphase.io`)."""
    directory = Path(directory)
    checkpoint = directory / "checkpoint.npz"
    if resume:
        if not checkpoint.exists():
            raise SceneError("--resume", str(directory), "a run directory that holds checkpoint.npz")
        state = load_mesh_checkpoint(checkpoint, mesh_scene.domain)
        simulation = UnstructuredSimulation(mesh_scene, observers=load_observers(checkpoint))
    else:
        state = mesh_scene.initial_state()
        simulation = UnstructuredSimulation(mesh_scene)
    trackers: list[Tracker] = [RunDirectory(directory, resume), MeshCheckpoint(directory, mesh_scene)]
    if progress is not False:
        trackers.insert(0, ProgressBar(disable=None if progress is None else not progress))
    return simulation.run(state, trackers)

