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
from functools import cached_property
from pathlib import Path

import numpy as np

from .domain import Domain, domain_from_table
from .errors import ResolutionWarning, SceneError
from .flows import FLOWS, Flow, flow_from_spec
from .model import PAPER_SYMBOLS, ModelParameters
from .placement import hexagonal_centres
from .state import State, discs_state
from .stepping import Numerics

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

LAYOUTS = ("single", "hexagonal", "random", "list")
#: Largest total target area Σ πR_i² over the domain's area that a scene may ask for (the
#: paper's scene is at 1.20: the particles are compressed and deformed).
MAX_AREA_FRACTION = 1.5


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
    per particle in it too (large); observables: names in
    :data:`femphase.observables.OBSERVABLES` ("shape" and "energy" always, e.g. "order"
    for Ψ6, Ψ2^L, lattice angle, T1 count); checkpoint: checkpoint.h5 every frame."""

    fields: bool = True
    per_particle_fields: bool = False
    observables: tuple = ("shape", "energy")
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
    """A validated scene. ``domain_table`` is the scene's ``[domain]`` table (with ``kind``);
    :attr:`domain` is the Domain it describes, built once."""

    name: str
    model: ModelParameters
    domain_table: dict
    particles: Particles
    numerics: Numerics
    output: Output
    phases: tuple[Phase, ...]
    base_dir: str = "."

    @cached_property
    def domain(self) -> Domain:
        return domain_from_table(self.domain_table, self.base_dir, self.numerics)

    def to_dict(self) -> dict:
        """The resolved scene as plain data (what ``scene.toml`` of a run directory holds):
        the domain table gains its measured Lx, Ly and h, a mesh file its absolute path."""
        domain = self.domain
        table = {"kind": domain.kind, **self.domain_table, "Lx": domain.period, "Ly": domain.width,
                 "h": float(self.domain_table.get("h", domain.spacing))}
        if table.get("mesh"):
            table["mesh"] = str((Path(self.base_dir) / table["mesh"]).resolve())
        return {
            "name": self.name,
            "model": asdict(self.model),
            "domain": table,
            "particles": {k: v for k, v in asdict(self.particles).items() if v is not None},
            "numerics": asdict(self.numerics),
            "output": {**asdict(self.output), "observables": list(self.output.observables)},
            "phases": [asdict(p) for p in self.phases],
        }

    @property
    def radii(self) -> np.ndarray:
        if self.particles.radii is not None:
            return np.asarray(self.particles.radii, dtype=float)
        return np.full(self.n_particles, self.model.radius)

    @property
    def n_particles(self) -> int:
        p = self.particles
        if p.layout == "single":
            return 1
        if p.layout == "list":
            return len(p.centres or [])
        return p.N

    def flow(self, phase: Phase) -> Flow:
        return flow_from_spec(phase.flow, self.domain)

    def window_policy(self):
        return self.domain.window_policy(self.numerics)

    def initial_radii(self) -> np.ndarray:
        r0 = self.particles.initial_radius
        return np.full(self.n_particles, r0) if r0 is not None else 0.5 * self.radii

    def initial_state(self) -> State:
        """Discs of radius initial_radius at the layout's centres."""
        return discs_state(self.domain, initial_centres(self), self.radii, self.initial_radii(),
                           self.model.interface_width, self.window_policy())


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
    if not isinstance(data, dict):
        raise SceneError("scene", data, "a TOML document of tables")
    known = {"name", "model", "domain", "particles", "numerics", "output", "phases"}
    for key in data:
        if key not in known:
            raise SceneError(key, data[key], f"not a known table; valid: {', '.join(sorted(known))}")
    model_table = dict(_table(data, "model"))
    for key, value in model_table.items():
        _check_number(f"model.{key}", value, 0.0, strict=False)
    model = _from_table(ModelParameters, model_table, "model", PAPER_SYMBOLS)
    particles = _from_table(Particles, _table(data, "particles"), "particles")
    numerics = _from_table(Numerics, _table(data, "numerics"), "numerics")
    output_table = dict(_table(data, "output"))
    if "observables" in output_table:
        from .observables import OBSERVABLES

        requested = output_table["observables"]
        if not isinstance(requested, (list, tuple)):
            raise SceneError("output.observables", requested, f"a list of names from {OBSERVABLES.names()}")
        for item in requested:
            OBSERVABLES.get(item, "output.observables")
        output_table["observables"] = tuple(dict.fromkeys(("shape", "energy") + tuple(requested)))
    output = _from_table(Output, output_table, "output")
    phase_tables = data.get("phases", [])
    if not isinstance(phase_tables, list):
        raise SceneError("phases", phase_tables, "a list of [[phases]] tables")
    phases = tuple(_phase(i, table) for i, table in enumerate(phase_tables))
    if not phases:
        raise SceneError("phases", [], "at least one [[phases]] table with duration, dt, frame_interval")
    domain_table = dict(_table(data, "domain"))
    domain_table.setdefault("kind", "grid")
    scene = Scene(
        name=str(data.get("name", "scene")), model=model, domain_table=domain_table, particles=particles,
        numerics=numerics, output=output, phases=phases, base_dir=str(base_dir),
    )
    _check_resolution(scene)
    _check_particles(scene)
    for i, phase in enumerate(phases):
        try:
            check_flow(phase.flow, scene.domain)
        except SceneError as exc:
            raise SceneError(f"phases.{i}.{exc.key}", exc.value, exc.valid) from None
    return scene


def _table(data: dict, name: str) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise SceneError(name, table, f"a table [{name}] of keys")
    return table


def check_flow(spec: dict, domain: Domain) -> None:
    """Validate a phase's flow table without solving anything (a stokes flow is solved
    when its phase starts)."""
    if isinstance(spec, dict) and spec.get("type") == "stokes" and "stokes" in FLOWS:
        from .stokes import stokes_drive

        stokes_drive(spec)
        if domain.kind != "mesh":
            raise SceneError("flow.type", "stokes", 'a flow without "stokes": a stokes flow needs a meshed domain')
        return
    flow_from_spec(spec, domain)


def _check_resolution(scene: Scene) -> None:
    h, lam = scene.domain.spacing, scene.model.interface_width
    if lam / h < 1.0:
        raise SceneError(
            "domain.h", h,
            f"the interface (width ~2λ, λ = {lam:g}) needs h ≤ λ; use h ≤ {lam:g}",
        )
    if lam / h < 2.0:
        warnings.warn(
            f"domain.h = {h:g} puts only λ/h = {lam / h:g} nodes across the interface width λ = {lam:g}: "
            f"interfaces pin to the grid (in the sheared lattice at h = λ the lanes lock and oscillation "
            f"periods come out 1–4% short, verification/README.md); use h ≤ {lam / 2:g} for results "
            f"converged in h",
            ResolutionWarning, stacklevel=3,
        )


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


def _check_particles(scene: Scene) -> None:
    p, domain = scene.particles, scene.domain
    if p.layout not in LAYOUTS:
        raise SceneError("particles.layout", p.layout, f"one of {LAYOUTS}")
    if p.layout in ("hexagonal", "random") and (not isinstance(p.N, int) or isinstance(p.N, bool) or p.N < 1):
        raise SceneError("particles.N", p.N, "a whole number ≥ 1")
    if p.layout == "list" and not p.centres:
        raise SceneError("particles.centres", p.centres, "a non-empty list of [x, y] pairs for layout = 'list'")
    if p.centres is not None:
        try:
            centres = np.asarray(p.centres, dtype=float)
        except (TypeError, ValueError):
            centres = np.zeros(0)
        if centres.ndim != 2 or centres.shape[1] != 2:
            raise SceneError("particles.centres", p.centres, "a list of [x, y] pairs")
    n = scene.n_particles
    if p.radii is not None:
        radii = np.asarray(p.radii, dtype=float)
        if radii.shape != (n,) or not np.all(radii > 0):
            raise SceneError("particles.radii", p.radii, f"{n} radii, all > 0")
    if p.initial_radius is not None:
        _check_number("particles.initial_radius", p.initial_radius)
    fraction = np.sum(np.pi * scene.radii**2) / domain.area
    if fraction > MAX_AREA_FRACTION:
        raise SceneError(
            "particles.N", n,
            f"the particles' total area is {fraction:.2f} × the domain's; at most {MAX_AREA_FRACTION} fits "
            f"(N ≤ {int(MAX_AREA_FRACTION * domain.area / (np.pi * np.mean(scene.radii) ** 2))} "
            f"at R = {np.mean(scene.radii):g})",
        )
    if p.layout != "random":  # fixed centres: check them now, not at the run
        initial_centres(scene)


def initial_centres(scene: Scene) -> np.ndarray:
    """Centres (N, 2) of the initial discs for the scene's layout; SceneError when a fixed
    centre lies outside the domain."""
    p, domain = scene.particles, scene.domain
    low, high = domain.y_range
    if p.layout == "random":
        return domain.random_centres(p.N, float(np.max(scene.initial_radii())), p.seed)
    if p.layout == "hexagonal":
        centres = hexagonal_centres(p.N, domain.period, high - low, p.per_row) + [domain.x0, low]
    elif p.centres:
        centres = np.asarray(p.centres, dtype=float)[: 1 if p.layout == "single" else None]
    else:
        centres = np.array([[domain.x0 + 0.5 * domain.period, 0.5 * (low + high)]])
    outside = ~domain.inside(centres[:, 0], centres[:, 1])
    if outside.any():
        raise SceneError("particles.centres", centres[outside].tolist(),
                         f"centres inside the domain (y between the walls, {low:g} ≤ y ≤ {high:g})")
    return centres


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


def load_scene(path: str | Path, assignments: list[str] | None = None) -> Scene:
    """Read and validate a scene file (any domain kind), applying ``--set`` first."""
    return scene_from_dict(read_scene_data(path, assignments), Path(path).parent)
