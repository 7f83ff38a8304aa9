"""Scenes: what to simulate, read from TOML, validated, with the paper's defaults.

A scene has the tables ``[model]``, ``[domain]``, ``[particles]``, ``[numerics]``,
``[output]`` and a list ``[[phases]]`` run in order (e.g. relax without flow, then shear).
Every key, its unit and default is listed in ``docs/scenes.md``; unknown keys and invalid
values raise :class:`~femphase.errors.SceneError` naming the key, the value and what is valid.
"""

from __future__ import annotations

import math
import sys
import warnings
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from .errors import ResolutionWarning, SceneError
from .flows import flow_from_spec
from .mesh import ChannelGrid, channel_grid, load_mesh
from .model import PAPER_SYMBOLS, ModelParameters
from .state import State, discs_state
from .stepping import Discretisation, Numerics
from .windows import WindowPolicy

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

LAYOUTS = ("single", "hexagonal", "random", "list")
#: "grid": the structured channel (this module); "mesh": any triangular mesh (femphase.unstructured)
DOMAIN_KINDS = ("grid", "mesh")
#: Largest total target area Σ πR_i² over channel area that a scene may ask for (the
#: paper's scene is at 1.20: the particles are compressed and deformed).
MAX_AREA_FRACTION = 1.5


@dataclass(frozen=True)
class Domain:
    """The channel [0, Lx) × [0, Ly] (lattice units) and its mesh spacing h."""

    Lx: float = 70.0
    Ly: float = 240.0
    h: float = 1.0
    mesh: str = ""  # optional meshio file of the structured channel, relative to the scene
    kind: str = "grid"  # "mesh" scenes are read by femphase.unstructured


@dataclass(frozen=True)
class Particles:
    """Initial particles. ``layout``: single | hexagonal | random | list.

    N               number of particles (hexagonal, random)
    initial_radius  radius of the initial discs (default R/2, as in the paper)
    seed            random seed (random layout)
    centres         [[x, y], ...] (list and single layouts; single defaults to the centre)
    radii           per-particle target radii R_i (default: model.R for all)
    per_row         particles per row of the hexagonal lattice (default from N and Lx/Ly)
    """

    layout: str = "random"
    N: int = 100
    initial_radius: float | None = None
    seed: int = 0
    centres: list | None = None
    radii: list | None = None
    per_row: int | None = None


@dataclass(frozen=True)
class Output:
    """What a run writes. fields: fields.xdmf every frame; per_particle_fields: one φ_i
    per particle in it too (large); observables: "shape" (always) plus "order" (Ψ6, Ψ2^L,
    lattice angle, T1 count); checkpoint: checkpoint.npz every frame."""

    fields: bool = True
    per_particle_fields: bool = False
    observables: tuple = ("shape",)
    checkpoint: bool = True


@dataclass(frozen=True)
class Phase:
    """A stretch of the run: duration and frame_interval in time units, dt the step."""

    name: str
    duration: float
    dt: float
    frame_interval: float
    flow: dict = field(default_factory=lambda: {"type": "none"})

    @property
    def n_steps(self) -> int:
        return round(self.duration / self.dt)

    @property
    def steps_per_frame(self) -> int:
        return round(self.frame_interval / self.dt)


@dataclass(frozen=True)
class Scene:
    name: str
    model: ModelParameters
    domain: Domain
    particles: Particles
    numerics: Numerics
    output: Output
    phases: tuple[Phase, ...]
    base_dir: str = "."

    def to_dict(self) -> dict:
        """The resolved scene as plain data (what ``scene.toml`` of a run directory holds)."""
        data = {
            "name": self.name,
            "model": asdict(self.model),
            "domain": asdict(self.domain),
            "particles": {k: v for k, v in asdict(self.particles).items() if v is not None},
            "numerics": asdict(self.numerics),
            "output": {**asdict(self.output), "observables": list(self.output.observables)},
            "phases": [asdict(p) for p in self.phases],
        }
        if self.domain.mesh:
            data["domain"]["mesh"] = str((Path(self.base_dir) / self.domain.mesh).resolve())
        return data

    @property
    def radii(self) -> np.ndarray:
        n = self.n_particles
        if self.particles.radii is not None:
            return np.asarray(self.particles.radii, dtype=float)
        return np.full(n, self.model.radius)

    @property
    def n_particles(self) -> int:
        p = self.particles
        if p.layout == "single":
            return 1
        if p.layout == "list":
            return len(p.centres or [])
        return p.N

    @property
    def grid(self) -> ChannelGrid:
        return channel_grid(self.domain.Lx, self.domain.Ly, self.domain.h)

    def discretisation(self) -> Discretisation:
        mesh = load_mesh(Path(self.base_dir) / self.domain.mesh) if self.domain.mesh else None
        return Discretisation.structured(self.grid, self.numerics.diagonals, mesh)

    def flow(self, phase: Phase):
        return flow_from_spec(phase.flow, self.domain.Ly)

    def window_policy(self) -> WindowPolicy:
        n = self.numerics
        return WindowPolicy.for_spacing(self.domain.h, threshold=n.threshold, margin=n.margin, enabled=n.windows)

    def initial_state(self) -> State:
        """Discs of radius initial_radius at the layout's centres."""
        centres = initial_centres(self)
        r0 = self.particles.initial_radius
        initial = np.full(len(centres), r0) if r0 is not None else 0.5 * self.radii
        return discs_state(self.grid, centres, self.radii, initial, self.model.interface_width, self.window_policy())


def _from_table(cls, table: dict, prefix: str, aliases: dict | None = None):
    """Build dataclass ``cls`` from a TOML table, rejecting unknown keys by name."""
    names = {f.name for f in fields(cls)}
    aliases = aliases or {}
    values = {}
    for key, value in table.items():
        name = aliases.get(key, key)
        if name not in names:
            valid = sorted(names | set(aliases))
            raise SceneError(f"{prefix}.{key}", value, f"not a known key; valid keys: {', '.join(valid)}")
        values[name] = value
    try:
        return cls(**values)
    except TypeError as exc:
        raise SceneError(prefix, table, str(exc)) from None


def _check_number(key: str, value, minimum: float = 0.0, strict: bool = True) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (value <= minimum if strict else value < minimum):
        relation = ">" if strict else "≥"
        raise SceneError(key, value, f"a finite number {relation} {minimum:g}")


def scene_from_dict(data: dict, base_dir: str | Path = ".") -> Scene:
    """Validate a scene given as nested dicts (the parsed TOML)."""
    known = {"name", "model", "domain", "particles", "numerics", "output", "phases"}
    for key in data:
        if key not in known:
            raise SceneError(key, data[key], f"not a known table; valid: {', '.join(sorted(known))}")
    model_table = dict(data.get("model", {}))
    for key, value in model_table.items():
        _check_number(f"model.{key}", value, 0.0, strict=False)
    model = _from_table(ModelParameters, model_table, "model", PAPER_SYMBOLS)
    domain = _from_table(Domain, data.get("domain", {}), "domain")
    for key in ("Lx", "Ly", "h"):
        _check_number(f"domain.{key}", getattr(domain, key))
    grid = channel_grid(domain.Lx, domain.Ly, domain.h)
    if model.interface_width / domain.h < 1.0:
        raise SceneError(
            "domain.h", domain.h,
            f"the interface (width ~2λ, λ = {model.interface_width:g}) needs h ≤ λ; use h ≤ {model.interface_width:g}",
        )
    if model.interface_width / domain.h < 2.0:
        warnings.warn(
            f"domain.h = {domain.h:g} puts only λ/h = {model.interface_width / domain.h:g} nodes across the "
            f"interface width λ = {model.interface_width:g}: interfaces pin to the grid (in the sheared lattice at "
            f"h = λ the lanes lock and oscillation periods come out 1–4% short, verification/README.md); use "
            f"h ≤ {model.interface_width / 2:g} for results converged in h",
            ResolutionWarning, stacklevel=2,
        )
    particles = _from_table(Particles, data.get("particles", {}), "particles")
    numerics = _from_table(Numerics, data.get("numerics", {}), "numerics")
    output_table = dict(data.get("output", {}))
    if "observables" in output_table:
        observables = tuple(output_table["observables"])
        for item in observables:
            if item not in ("shape", "order"):
                raise SceneError("output.observables", item, 'a list of "shape" and "order"')
        output_table["observables"] = tuple(dict.fromkeys(("shape",) + observables))
    output = _from_table(Output, output_table, "output")
    phases = tuple(_phase(i, table) for i, table in enumerate(data.get("phases", [])))
    if not phases:
        raise SceneError("phases", [], "at least one [[phases]] table with duration, dt, frame_interval")
    scene = Scene(
        name=str(data.get("name", "scene")), model=model, domain=domain, particles=particles,
        numerics=numerics, output=output, phases=phases, base_dir=str(base_dir),
    )
    _check_particles(scene, grid)
    for i, phase in enumerate(phases):
        try:
            scene.flow(phase)
        except SceneError as exc:
            raise SceneError(f"phases.{i}.{exc.key}", exc.value, exc.valid) from None
    return scene


def _phase(index: int, table: dict) -> Phase:
    prefix = f"phases.{index}"
    table = dict(table)
    table.setdefault("name", f"phase{index}")
    for key in ("duration", "dt", "frame_interval"):
        if key not in table:
            raise SceneError(f"{prefix}.{key}", None, "required (a number of time units)")
        _check_number(f"{prefix}.{key}", table[key])
    if "flow" in table and not isinstance(table["flow"], dict):
        raise SceneError(f"{prefix}.flow", table["flow"], 'a table such as {type = "shear", rate = 0.1}')
    phase = _from_table(Phase, table, prefix)
    for key in ("duration", "frame_interval"):
        ratio = getattr(phase, key) / phase.dt
        if abs(ratio - round(ratio)) > 1e-6 * max(1.0, ratio) or round(ratio) < 1:
            raise SceneError(f"{prefix}.{key}", getattr(phase, key), f"a whole multiple of dt = {phase.dt:g}")
    return phase


def _check_particles(scene: Scene, grid: ChannelGrid) -> None:
    p = scene.particles
    if p.layout not in LAYOUTS:
        raise SceneError("particles.layout", p.layout, f"one of {LAYOUTS}")
    if p.layout in ("hexagonal", "random") and (not isinstance(p.N, int) or p.N < 1):
        raise SceneError("particles.N", p.N, "a whole number ≥ 1")
    if p.layout == "list" and not p.centres:
        raise SceneError("particles.centres", p.centres, "a non-empty list of [x, y] pairs for layout = 'list'")
    if p.centres is not None:
        centres = np.asarray(p.centres, dtype=float)
        if centres.ndim != 2 or centres.shape[1] != 2:
            raise SceneError("particles.centres", p.centres, "a list of [x, y] pairs")
        inside = (centres[:, 1] >= 0) & (centres[:, 1] <= grid.width)
        if not inside.all():
            raise SceneError("particles.centres", p.centres, f"y between the walls, 0 ≤ y ≤ {grid.width:g}")
    n = scene.n_particles
    if p.radii is not None:
        radii = np.asarray(p.radii, dtype=float)
        if radii.shape != (n,) or not np.all(radii > 0):
            raise SceneError("particles.radii", p.radii, f"{n} radii, all > 0")
    if p.initial_radius is not None:
        _check_number("particles.initial_radius", p.initial_radius)
    fraction = np.sum(np.pi * scene.radii**2) / (grid.length * grid.width)
    if fraction > MAX_AREA_FRACTION:
        raise SceneError(
            "particles.N", n,
            f"the particles' total area is {fraction:.2f} × the channel's; at most {MAX_AREA_FRACTION} fits "
            f"(N ≤ {int(MAX_AREA_FRACTION * grid.length * grid.width / (np.pi * np.mean(scene.radii) ** 2))} "
            f"at R = {np.mean(scene.radii):g})",
        )


def initial_centres(scene: Scene) -> np.ndarray:
    """Centres (N, 2) of the initial discs for the scene's layout."""
    p, grid = scene.particles, scene.grid
    if p.layout == "single":
        return np.asarray(p.centres or [[0.5 * grid.length, 0.5 * grid.width]], dtype=float)[:1]
    if p.layout == "list":
        return np.asarray(p.centres, dtype=float)
    if p.layout == "hexagonal":
        return hexagonal_centres(p.N, grid.length, grid.width, p.per_row)
    r0 = p.initial_radius if p.initial_radius is not None else 0.5 * float(np.max(scene.radii))
    return random_centres(p.N, grid.length, grid.width, r0, p.seed)


def hexagonal_centres(n: int, length: float, width: float, per_row: int | None = None) -> np.ndarray:
    """A hexagonal lattice with rows along x filling the channel: per_row × rows = n.

    Without per_row, the row length is the one closest to an ideal lattice of n sites on
    the channel's area. Rows are ``width/rows`` apart, alternate rows offset by half a
    spacing (the paper's Fig. 2: 5 per row, 20 rows in 70 × 240).
    """
    if per_row is None:
        spacing = math.sqrt(2.0 * length * width / (math.sqrt(3.0) * n))
        per_row = max(1, round(length / spacing))
    if n % per_row:
        raise SceneError("particles.N", n, f"a multiple of per_row = {per_row} for the hexagonal layout")
    rows = n // per_row
    dx, dy = length / per_row, width / rows
    i, j = np.meshgrid(np.arange(per_row), np.arange(rows))
    x = ((i + 0.25 + 0.5 * (j % 2)) * dx) % length
    y = (j + 0.5) * dy
    return np.stack([x.ravel(), y.ravel()], axis=1)


def clear_of_discs(centres: np.ndarray, candidate: np.ndarray, period: float, radius: float) -> bool:
    """Whether a disc of ``radius`` at ``candidate`` overlaps none of the discs at ``centres``
    (the same radius; distances by the minimum image over the period in x)."""
    dx = (centres[:, 0] - candidate[0] + 0.5 * period) % period - 0.5 * period
    return bool(np.all(dx**2 + (centres[:, 1] - candidate[1]) ** 2 >= (2 * radius) ** 2))


def random_centres(n: int, length: float, width: float, radius: float, seed: int, attempts: int = 200_000) -> np.ndarray:
    """Uniformly random centres of non-overlapping discs of ``radius`` inside the channel."""
    rng = np.random.default_rng(seed)
    centres = np.empty((0, 2))
    for _ in range(attempts):
        candidate = np.array([rng.uniform(0, length), rng.uniform(radius, width - radius)])
        if clear_of_discs(centres, candidate, length, radius):
            centres = np.vstack([centres, candidate])
            if len(centres) == n:
                return centres
    raise SceneError(
        "particles.N", n,
        f"only {len(centres)} non-overlapping initial discs of radius {radius:g} fit after {attempts} tries; "
        "use fewer particles or a smaller particles.initial_radius",
    )


def set_value(data: dict, assignment: str) -> None:
    """Apply one ``--set key=value`` (dotted key, TOML value; phases by index: phases.1.dt)."""
    key, sep, text = assignment.partition("=")
    if not sep or not key:
        raise SceneError("--set", assignment, "key=value, e.g. model.mu=10 or phases.1.flow.rate=0.3")
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        value = text
    parts = key.split(".")
    target = data
    for depth, part in enumerate(parts[:-1]):
        if isinstance(target, list):
            if not part.isdigit() or int(part) >= len(target):
                raise SceneError(".".join(parts[: depth + 1]), part, f"an index 0 … {len(target) - 1}")
            target = target[int(part)]
        else:
            target = target.setdefault(part, {})
    target[parts[-1]] = value


def read_scene_data(path: str | Path, assignments: list[str] | None = None) -> dict:
    """The parsed TOML of a scene file with ``--set`` assignments applied (not validated)."""
    path = Path(path)
    if not path.is_file():
        raise SceneError("scene", str(path), "a TOML scene file that exists")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SceneError("scene", str(path), f"valid TOML ({exc})") from None
    for assignment in assignments or []:
        set_value(data, assignment)
    return data


def is_mesh_scene(data: dict) -> bool:
    """True for scenes on a meshed geometry (``[domain] kind = "mesh"``)."""
    kind = data.get("domain", {}).get("kind", "grid")
    if kind not in DOMAIN_KINDS:
        raise SceneError("domain.kind", kind, f"one of {DOMAIN_KINDS}")
    return kind == "mesh"


def load_scene(path: str | Path, assignments: list[str] | None = None) -> Scene:
    """Read and validate a scene file on the structured channel, applying ``--set`` first."""
    return scene_from_dict(read_scene_data(path, assignments), Path(path).parent)
