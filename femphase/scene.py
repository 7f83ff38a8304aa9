"""Scenes: what to simulate, read from TOML, validated, with the paper's defaults.

A scene has the tables ``[model]``, ``[domain]``, ``[particles]``, ``[numerics]``,
``[output]`` and a list ``[[phases]]`` run in order (e.g. relax without flow, then shear).
Every key, its unit and default is listed in ``docs/scenes.md``; unknown keys and invalid
values raise :class:`~femphase.errors.SceneError` naming the key, the value and what is valid.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property
from pathlib import Path

import numpy as np

from femphase import tomlio
from femphase.analysis.observables import OBSERVABLES
from femphase.config import Numerics
from femphase.domains import DOMAINS, Domain, domain_from_table
from femphase.domains.mesh.stokes import check_open_channel, stokes_drive
from femphase.errors import FlowError, FlowWarning, ModelWarning, ResolutionWarning, SceneError, StiffnessWarning
from femphase.flows import FLOWS, Flow, flow_defects, flow_from_spec, largest_speed
from femphase.model.parameters import PAPER_SYMBOLS, ModelParameters
from femphase.placement import hexagonal_centres
from femphase.registry import Registry, import_extensions
from femphase.state import State, discs_state
from femphase.timestepping import SCHEMES, Stepper
from femphase.timestepping.base import scheme_class

__all__ = ["LAYOUTS", "MAX_AREA_FRACTION", "MAX_PARTICLES", "MAX_PHASE_STEPS", "check_flow", "check_numerics",
           "initial_centres", "load_scene", "Output", "parse_assignment", "Particles", "Phase", "placed_count",
           "read_scene_data", "registries", "Scene", "scene_from_dict", "set_value"]


def registries() -> tuple[Registry, ...]:
    """The names a scene may use, each registry filled with its built-in entries: domain
    kinds, flows, time schemes and observables (``docs/scenes.md`` lists them)."""
    return DOMAINS, FLOWS, SCHEMES, OBSERVABLES


LAYOUTS = ("single", "hexagonal", "random", "list")
#: Largest total target area Σ πR_i² over the domain's area that a scene may ask for (the
#: paper's scene is at 1.20: the particles are compressed and deformed).
MAX_AREA_FRACTION = 1.5
#: Most particles a scene may ask for (the paper's scenes have 100; far beyond any run that
#: fits in memory, so a mistyped N is refused whatever the layout).
MAX_PARTICLES = 1_000_000
#: Most time steps a phase may ask for (duration/dt): a bound far beyond any feasible run,
#: so that a mistyped dt is refused at once instead of starting a run that cannot end.
MAX_PHASE_STEPS = 10**12


@dataclass(frozen=True)
class Particles:
    """Initial particles. ``layout``: single | hexagonal | random | list.

    N               number of particles (hexagonal, random; single places 1, list one per centre)
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
    :data:`femphase.analysis.observables.OBSERVABLES` ("shape" and "energy" always, e.g. "order"
    for Ψ6, Ψ2^L, lattice angle, T1 count); checkpoint: checkpoint.h5 every frame;
    t1_interval: time units between the looks of the "order" observable's T1 counter at
    the centroids, between frames too (after the step that reaches each multiple of it),
    so that the count does not depend on the frame interval. The default, 20, counts
    within 3.6 % of looks every 2.5 at γ̇ = 1 (benchmarks/t1_counting.py)."""

    fields: bool = True
    per_particle_fields: bool = False
    observables: tuple = ("shape", "energy")
    checkpoint: bool = True
    t1_interval: float = 20.0


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
        the domain table gains its measured Lx and Ly, a grid its h, a mesh file its absolute
        path. A mesh keeps the h its scene gives, if any: a nominal h judges the mesh where it
        is coarser than the nodes
        (:attr:`femphase.domains.mesh.domain.MeshDomain.resolution`), so a measured one written
        there would make the file describe another scene than the one that ran."""
        domain = self.domain
        table = {"kind": domain.kind, **self.domain_table, "Lx": domain.period, "Ly": domain.width}
        if domain.kind != "mesh":
            table["h"] = float(self.domain_table.get("h", domain.spacing))
        if table.get("mesh"):
            table["mesh"] = str((Path(self.base_dir) / table["mesh"]).resolve())
        return {
            "name": self.name,
            "model": asdict(self.model),
            "domain": table,
            # N as placed: the single and list layouts do not read it
            "particles": {k: v for k, v in asdict(self.particles).items() if v is not None} | {"N": self.n_particles},
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
        placed = placed_count({"layout": self.particles.layout, "centres": self.particles.centres})
        return self.particles.N if placed is None else placed

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


def _check_keys(cls, table: dict, prefix: str, aliases: dict | None = None) -> dict:
    """The table's values by field name of dataclass ``cls``; SceneError naming an unknown
    key, or a key given twice (under its name and its alias)."""
    names = {f.name for f in fields(cls)}
    aliases = aliases or {}
    values, spelled = {}, {}
    for key, value in table.items():
        name = aliases.get(key, key)
        if not isinstance(key, str) or name not in names:
            valid = sorted(names | set(aliases))
            raise SceneError(f"{prefix}.{key}", value, f"not a known key; valid keys: {', '.join(valid)}")
        if name in values:
            raise SceneError(f"{prefix}.{key}", value, f"given once only: {prefix}.{spelled[name]} is the same "
                             "parameter")
        values[name], spelled[name] = value, key
    return values


def _from_table(cls, table: dict, prefix: str, aliases: dict | None = None):
    """Build dataclass ``cls`` from a TOML table, rejecting unknown keys by name."""
    values = _check_keys(cls, table, prefix, aliases)
    try:
        return cls(**values)
    except TypeError as exc:
        raise SceneError(prefix, table, str(exc)) from None


def _is_number(value) -> bool:
    """A finite int or float (``True`` is an int in Python, but not a number in a scene)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_number(key: str, value, minimum: float = 0.0, strict: bool = True) -> None:
    if not _is_number(value) or (value <= minimum if strict else value < minimum):
        relation = ">" if strict else "≥"
        raise SceneError(key, value, f"a finite number {relation} {minimum:g}")


def _check_integer(key: str, value, minimum: int, meaning: str = "") -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise SceneError(key, value, f"a whole number ≥ {minimum}{meaning}")


def _check_bool(key: str, value) -> None:
    if not isinstance(value, bool):
        raise SceneError(key, value, "true or false")


def _check_string(key: str, value, meaning: str = "") -> None:
    if not isinstance(value, str) or not value.strip():
        raise SceneError(key, value, f"a non-empty string{meaning}")


def scene_from_dict(data: dict, base_dir: str | Path = ".", scheme: str | None = None) -> Scene:
    """Validate a scene given as nested dicts (the parsed TOML). The modules of extensions
    named in ``FEMPHASE_IMPORT`` are imported first (:func:`femphase.registry.import_extensions`).
    ``scheme``: the time scheme the run uses, if not the scene's ``numerics.scheme``
    (``femphase run --method fd``: "fd-heun"); the scheme's own checks are made for it."""
    import_extensions()
    if not isinstance(data, dict):
        raise SceneError("scene", data, "a TOML document of tables")
    known = {"name", "model", "domain", "particles", "numerics", "output", "phases"}
    for key in data:
        if key not in known:
            raise SceneError(key, data[key], f"not a known table; valid: {', '.join(sorted(known))}")
    name = data.get("name", "scene")
    _check_string("name", name, " (the scene's name)")
    model_table = dict(_table(data, "model"))
    _check_keys(ModelParameters, model_table, "model", PAPER_SYMBOLS)
    for key, value in model_table.items():
        parameter = PAPER_SYMBOLS.get(key, key)
        positive = parameter in ("interface_width", "radius", "mobility")  # the others may be 0
        if not _is_number(value) or (value <= 0 if positive else value < 0):
            named = f"model.{parameter}" if positive else f"model.{key}"
            raise SceneError(named, value, f"a finite number {'>' if positive else '≥'} 0"
                             + (f" (given as model.{key})" if positive and key != parameter else ""))
    model = _from_table(ModelParameters, model_table, "model", PAPER_SYMBOLS)
    particles_table = _table(data, "particles")
    _check_keys(Particles, particles_table, "particles")
    _check_particle_types(particles_table)
    _check_given_count(particles_table)
    particles = _from_table(Particles, particles_table, "particles")
    numerics_table = _table(data, "numerics")
    _check_keys(Numerics, numerics_table, "numerics")
    stabilisation = numerics_table.get("stabilisation", "auto")
    if stabilisation != "auto" and not (_is_number(stabilisation) and stabilisation >= 0):
        raise SceneError("numerics.stabilisation", stabilisation, '"auto" or a finite number ≥ 0')
    scene_scheme = SCHEMES.get(numerics_table.get("scheme", Numerics.scheme), "numerics.scheme")
    if stabilisation != "auto" and not getattr(scene_scheme, "stabilised", False):
        warnings.warn(f"numerics.stabilisation = {stabilisation!r} is not used: only the euler scheme stabilises its "
                      f"step, numerics.scheme = {numerics_table.get('scheme', Numerics.scheme)!r} does not",
                      ModelWarning, stacklevel=2)
    numerics = _from_table(Numerics, numerics_table, "numerics")
    output = _output(_table(data, "output"))
    phase_tables = data.get("phases", [])
    if not isinstance(phase_tables, list):
        raise SceneError("phases", phase_tables, "a list of [[phases]] tables")
    phases = tuple(_phase(i, table) for i, table in enumerate(phase_tables))
    if not phases:
        raise SceneError("phases", [], "at least one [[phases]] table with duration, dt, frame_interval")
    domain_table = dict(_table(data, "domain"))
    domain_table.setdefault("kind", "grid")
    _check_domain_types(domain_table)
    scene = Scene(
        name=name, model=model, domain_table=domain_table, particles=particles,
        numerics=numerics, output=output, phases=phases, base_dir=str(base_dir),
    )
    _check_resolution(scene)
    _check_particles(scene)
    for i, phase in enumerate(phases):
        try:
            flow = check_flow(phase.flow, scene.domain)
            _check_step_displacement(flow, phase.flow, scene.domain, phase.dt)
            _warn_flow_defects(flow, scene.domain, f"phases.{i}.flow")
        except SceneError as exc:
            raise SceneError(f"phases.{i}.{exc.key}", exc.value, exc.valid) from None
        except FlowError as exc:  # a python flow that failed on the walls' or the period's points
            raise SceneError(f"phases.{i}.flow.function", exc.function, f"a callable computing a finite velocity "
                             f"at every point of the domain ({exc.reason}, checking the walls and the period at "
                             f"t = {exc.time:g})") from None
        if flow is not None and not flow.steady and scene.numerics.mesh_advection == "semi-lagrangian" \
                and scene.domain.kind == "mesh":
            raise SceneError("numerics.mesh_advection", "semi-lagrangian",
                             f'"auto" or "galerkin": phases.{i}.flow changes with time, and the semi-Lagrangian '
                             "step on meshes is one matrix per steady flow and dt")
    check_numerics(scene, scheme)
    _check_area_ceiling(scene, scheme)
    _check_split_repulsion(scene, scheme)
    return scene


def _check_split_repulsion(scene: Scene, scheme: str | None = None) -> None:
    """Warn when a flow phase's split repulsion (``numerics.repulsion_split``, sav2 and
    adaptive) decays at c·h above :attr:`AdaptiveSAV2.DECAY_STEP`, c = 4·J0·κ/λ its rate where
    a neighbour's φ is 1 (the splitting's error is not in the estimate): sav2 at its dt; the
    adaptive scheme, whose substeps that bound caps, where it forces more than
    :data:`CEILING_SUBSTEPS` substeps per step of dt."""
    from femphase.timestepping.adaptive import AdaptiveSAV2

    numerics, model = scene.numerics, scene.model
    scheme = numerics.scheme if scheme is None else scheme
    if scheme not in ("adaptive", "sav2") or not numerics.repulsion_split or model.repulsion <= 0 \
            or scene.n_particles < 2:
        return
    rate = model.repulsion_rate()
    ceiling = AdaptiveSAV2.DECAY_STEP / rate
    effect = ("measured: two pressed discs under shear, their repulsion energy 3.6 % off at c·h = 10, 12 % at 19, "
              "4.8-fold at 188; docs/decisions/0052-split-repulsion-decay-ceiling.md")
    for k, phase in enumerate(scene.phases):
        if phase.flow.get("type", "none") == "none":
            continue
        if scheme == "sav2" and phase.dt > ceiling:
            warnings.warn(
                f'numerics.scheme = "sav2" at phases.{k}.dt = {phase.dt:g}: model.repulsion (κ) = '
                f"{model.repulsion:g} splits off the step a decay at up to c = 4·J0·κ/λ = {rate:.3g} per time "
                f"unit, c·dt = {rate * phase.dt:.3g}, whose splitting error the step does not see ({effect}). "
                f"Set phases.{k}.dt ≤ {ceiling:.3g}, or the adaptive scheme, which keeps c·h ≤ "
                f"{AdaptiveSAV2.DECAY_STEP:g}",
                StiffnessWarning, stacklevel=3)
        elif scheme == "adaptive" and phase.dt / ceiling > CEILING_SUBSTEPS:
            warnings.warn(
                f"model.repulsion (κ) = {model.repulsion:g}: under phases.{k}.flow the repulsion is split off the "
                f"step as a decay at up to c = 4·J0·κ/λ = {rate:.3g} per time unit, and the adaptive substep stays "
                f"below {AdaptiveSAV2.DECAY_STEP:g}/c = {ceiling:.3g} time units, where the splitting's error stays "
                f"small ({effect}): at least {phase.dt / ceiling:.0f} substeps per step of phases.{k}.dt = "
                f"{phase.dt:g}. A smaller κ lowers c",
                StiffnessWarning, stacklevel=3)


#: Substeps per step of dt that the area-mode ceiling alone may force before a scene warns:
#: the paper's μ needs none (ceiling 3.77 against dt = 10), μ × 10 about 27, μ × 100 about 270.
CEILING_SUBSTEPS = 64


def _check_area_ceiling(scene: Scene, scheme: str | None = None) -> None:
    """Warn when the adaptive scheme's area-mode ceiling (:attr:`AdaptiveSAV2.RANK_ONE_STEP`,
    or :attr:`AdaptiveSAV2.IMPLICIT_RANK_ONE_STEP` with ``numerics.area_implicit``, over the
    area constraint's rate c = J0·8μ/(πR²), the smallest R, areas at their target) holds a
    phase's substeps below dt/:data:`CEILING_SUBSTEPS`, and when sav2, the same step at a
    fixed dt, steps past that ceiling."""
    from femphase.timestepping.adaptive import AdaptiveSAV2

    numerics, model = scene.numerics, scene.model
    scheme = numerics.scheme if scheme is None else scheme
    if scheme not in ("adaptive", "sav2") or model.area_stiffness <= 0:
        return
    radius = float(np.min(scene.radii))
    rate = model.area_rate(radius)
    implicit = numerics.area_implicit
    bound = AdaptiveSAV2.IMPLICIT_RANK_ONE_STEP if implicit else AdaptiveSAV2.RANK_ONE_STEP
    ceiling = bound / rate
    k, phase = max(enumerate(scene.phases), key=lambda item: item[1].dt)
    if scheme == "sav2" and phase.dt > ceiling:  # the same step, without the ceiling
        seen = ("with the area mode implicit a lone disc fell into a period-2 oscillation of its area (±30 %) "
                "past c·dt = 4.7, docs/scenes.md" if implicit else
                "on examples/single.toml it blew up at dt = 5 and ended 31 % off in area at dt = 10")
        remedy = "" if implicit else ", numerics.area_implicit = true"
        warnings.warn(
            f'numerics.scheme = "sav2" at phases.{k}.dt = {phase.dt:g} steps past {bound:g}/c = '
            f"{ceiling:.3g} time units (c = J0·8μ/(πR²) = {rate:.3g} at R = {radius:g}), where its step "
            f"stops damping the area: {seen}. Set the phases' dt ≤ {ceiling:.3g}{remedy}, or the adaptive scheme",
            StiffnessWarning, stacklevel=3,
        )
    elif scheme == "adaptive" and phase.dt / ceiling > CEILING_SUBSTEPS:
        remedy = ("" if implicit else
                  f"numerics.area_implicit = true raises that ceiling to {AdaptiveSAV2.IMPLICIT_RANK_ONE_STEP:g}/c "
                  "(with errors of the area mode the estimate does not see, docs/scenes.md); ")
        warnings.warn(
            f"model.area_stiffness = {model.area_stiffness:g} makes the area constraint stiff (rate "
            f"c = J0·8μ/(πR²) = {rate:.3g} per time unit at R = {radius:g}): the adaptive substep stays below "
            f"{bound:g}/c = {ceiling:.3g} time units, where its step stops damping the area, at least "
            f"{phase.dt / ceiling:.0f} substeps per step of phases.{k}.dt = {phase.dt:g}. "
            f"{remedy}{'a' if remedy else 'A'} smaller area_stiffness lowers c",
            StiffnessWarning, stacklevel=3,
        )


def check_numerics(scene: Scene, scheme: str | None = None) -> None:
    """What the time stepping would refuse at its first step, refused now: a time mass the
    scheme cannot step with, the finite-difference scheme off the structured channel or
    above its explicit stability limit, the tensor solver where the system has no
    tensor-product form, and on a mesh a choice of the structured channel's diagonals.

    ``scheme``: the time scheme the run uses, if not the scene's ``numerics.scheme`` (``femphase
    run --method fd`` uses "fd-heun"); :func:`femphase.run.runner.run_scene` should call this
    with it before touching the run directory."""
    numerics, domain = scene.numerics, scene.domain
    scheme = numerics.scheme if scheme is None else scheme
    key = "numerics.scheme" if scheme == numerics.scheme else "--method"
    # as the user wrote it: --method takes "fem" or "fd", numerics.scheme the schemes' names
    from femphase.timestepping.fd import fem_schemes

    given, instead = ("fd", '"fem"') if key == "--method" else (scheme, fem_schemes())
    scheme_entry = scheme_class(scheme)
    if key == "--method" and numerics.mass not in scheme_entry.masses:
        # the scene's own scheme is not run, so advice to change it would not help
        raise SceneError("numerics.mass", numerics.mass, " or ".join(f'"{m}"' for m in scheme_entry.masses)
                         + f" with --method {given} (the finite-difference reference is the structured channel's "
                         'lumped-mass scheme)')
    scheme_entry.check_mass(numerics.mass)
    if domain.kind == "mesh" and numerics.diagonals != Numerics.diagonals:
        raise SceneError("numerics.diagonals", numerics.diagonals, f'"{Numerics.diagonals}" (the default) on a mesh: '
                         "the diagonals are the structured channel's triangulation, a mesh's triangles its file's")
    if scheme == "fd-heun":
        if domain.kind != "grid":
            raise SceneError(key, given, f'{instead} on this domain: the finite-difference reference needs the '
                             f'structured channel ([domain] kind = "grid"; this scene\'s kind is "{domain.kind}")')
        for i, phase in enumerate(scene.phases):
            # the scheme's own checks (its stability limit), phase by phase
            try:
                Stepper(domain, scene.model, numerics, phase.dt, scene.flow(phase), scene.radii, scheme=scheme)
            except SceneError as exc:
                raise SceneError(f"phases.{i}.{exc.key.removeprefix('phases.')}", exc.value,
                                 f"{exc.valid} ({key} = \"{given}\")") from None
            except Exception as exc:  # a python flow runs the user's code
                raise SceneError(f"phases.{i}.flow", phase.flow, f"a flow that gives (u, v) at the nodes "
                                 f"({type(exc).__name__}: {exc})") from None
    elif numerics.solver == "tensor":
        reason = None
        if domain.kind != "grid":
            reason = f'the structured channel ([domain] kind = "grid", not "{domain.kind}")'
        elif numerics.mass != "lumped":
            reason = 'the lumped mass (numerics.mass = "lumped")'
        elif getattr(domain, "alternating", False):
            reason = ("one diagonal direction (numerics.diagonals right or left, and a mesh file without "
                      "alternating diagonals)")
        if reason is not None:
            raise SceneError("numerics.solver", "tensor",
                             f'"auto", "direct", "amg" or "batched": the tensor solver needs {reason}')


def _table(data: dict, name: str) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise SceneError(name, table, f"a table [{name}] of keys")
    return table


def _output(table: dict) -> Output:
    """The [output] table, every key checked."""
    table = dict(table)
    _check_keys(Output, table, "output")
    for key in ("fields", "per_particle_fields", "checkpoint"):
        if key in table:
            _check_bool(f"output.{key}", table[key])
    if "t1_interval" in table:
        _check_number("output.t1_interval", table["t1_interval"])
    if "observables" in table:
        requested = table["observables"]
        if not isinstance(requested, (list, tuple)):
            raise SceneError("output.observables", requested, f"a list of names from {OBSERVABLES.names()}")
        for item in requested:
            OBSERVABLES.get(item, "output.observables")
        table["observables"] = tuple(dict.fromkeys(("shape", "energy") + tuple(requested)))
    return _from_table(Output, table, "output")


def _check_particle_types(table: dict) -> None:
    """Types of the [particles] keys, whichever the layout (a key the layout does not use
    must still be valid: a typo there would otherwise pass unnoticed)."""
    if "layout" in table and table["layout"] not in LAYOUTS:
        raise SceneError("particles.layout", table["layout"], f"one of {LAYOUTS}")
    if "N" in table:
        _check_integer("particles.N", table["N"], 1, " (the number of particles)")
        if table["N"] > MAX_PARTICLES:
            raise SceneError("particles.N", table["N"], f"a whole number from 1 to {MAX_PARTICLES}")
    if "seed" in table:
        _check_integer("particles.seed", table["seed"], 0, " (the random layout's seed)")
    if table.get("per_row") is not None:
        _check_integer("particles.per_row", table["per_row"], 1, " (particles per row)")
    if table.get("initial_radius") is not None:
        _check_number("particles.initial_radius", table["initial_radius"])
    if table.get("centres") is not None:
        centres = table["centres"]
        def pair(c) -> bool:
            return isinstance(c, (list, tuple)) and len(c) == 2 and all(_is_number(v) for v in c)

        if not isinstance(centres, (list, tuple)) or not all(pair(c) for c in centres):
            raise SceneError("particles.centres", centres, "a list of [x, y] pairs of finite numbers")
    if table.get("radii") is not None:
        radii = table["radii"]
        if not isinstance(radii, (list, tuple)) or not all(_is_number(r) and r > 0 for r in radii):
            raise SceneError("particles.radii", radii, "a list of finite numbers > 0, one per particle")


def placed_count(particles: dict) -> int | None:
    """The number of particles a [particles] table's layout places without reading N
    (single: 1, list: one per centre); None for the layouts that read N."""
    layout = particles.get("layout", Particles.layout)
    return {"single": 1, "list": len(particles.get("centres") or [])}.get(layout)


def _check_given_count(table: dict) -> None:
    """An N given in the [particles] table of a layout that does not read it must say what the
    layout places (it would be ignored: single places 1, list one per centre)."""
    layout, placed = table.get("layout", Particles.layout), placed_count(table)
    if "N" in table and placed is not None and table["N"] != placed:
        raise SceneError("particles.N", table["N"], f"{placed}, or no N: the {layout} layout places "
                         + ("one particle" if layout == "single" else "one particle per centre")
                         + " (particles.N counts the random and hexagonal layouts')")


def _check_domain_types(table: dict) -> None:
    """The [domain] keys every kind shares; the kind's own checks follow when it is built."""
    DOMAINS.get(table["kind"], "domain.kind")
    for key in ("Lx", "Ly", "h"):
        if key in table:
            _check_number(f"domain.{key}", table[key])
    if "mesh" in table and not (isinstance(table["mesh"], str) and (table["mesh"] or table["kind"] == "grid")):
        raise SceneError("domain.mesh", table["mesh"], "the path of a mesh file (a string, relative to the scene)")


def check_flow(spec: dict, domain: Domain) -> Flow | None:
    """Validate a phase's flow table without solving anything (a stokes flow is solved
    when its phase starts, and None returned for it); returns the flow."""
    if isinstance(spec, dict) and spec.get("type") == "stokes" and "stokes" in FLOWS:
        stokes_drive(spec)
        if domain.kind != "mesh":
            raise SceneError("flow.type", "stokes", 'a type other than "stokes" on the structured channel: a stokes '
                             'flow is solved on a meshed domain ([domain] kind = "mesh")')
        check_open_channel(domain)
        return None
    return flow_from_spec(spec, domain)


#: The most a flow may move the fields in one step of dt (lattice units): a particle's position
#: keeps about 16 digits, so beyond ~1e6 a step's shift keeps no digit of its motion relative
#: to its neighbours' (a shear rate of 1e200 ran to its end: overflowing squares, elongation 40).
MAX_STEP_DISPLACEMENT = 1e6


def _check_step_displacement(flow: Flow | None, spec: dict, domain: Domain, dt: float) -> None:
    """SceneError (key ``flow``, the table ``spec``) when ``flow`` moves the fields by more
    than :data:`MAX_STEP_DISPLACEMENT` in one step of ``dt``."""
    speed = 0.0 if flow is None else largest_speed(flow, domain)
    if not speed * dt <= MAX_STEP_DISPLACEMENT:
        raise SceneError("flow", spec, f"a flow that moves the fields by at most {MAX_STEP_DISPLACEMENT:g} "
                         f"lattice units in a step: at its largest speed, {speed:.3g}, one step of dt = {dt:g} "
                         f"moves them {speed * dt:.3g}")


def _warn_flow_defects(flow: Flow | None, domain: Domain, key: str) -> None:
    """FlowWarning when ``flow`` crosses the walls or is not periodic in x
    (:func:`femphase.flows.flow_defects`)."""
    defects = {} if flow is None else flow_defects(flow, domain)
    meaning = {
        "walls": ("crosses the walls: its normal velocity reaches", "The fields see the walls only through their "
                  "Neumann condition, so such a flow carries φ through them; a flow for meshed walls that are "
                  'curved or have obstacles is {type = "stokes", ...}'),
        "period": (f"is not periodic in x: v(x + {domain.period:g}, y) − v(x, y) reaches",
                   "The domain is periodic, so the fields meet a jump in the flow at its seam"),
    }
    for name, (value, speed, (x, y)) in defects.items():
        what, consequence = meaning[name]
        warnings.warn(f"{key} {what} {value:.3g} (its largest speed is {speed:.3g}) at (x, y) = ({x:.4g}, {y:.4g}). "
                      f"{consequence}", FlowWarning, stacklevel=3)


#: A mesh's local spacing √(area per node) above this many λ does not resolve an interface.
#: A uniform Delaunay mesh made for h = λ has at most 0.25 % of its area so coarse
#: (meshes/*.vtu, *.msh at h = 1: its coarsest node 1.33).
COARSE_SPACING = 1.25
#: The largest fraction of a mesh's area that may be coarser than :data:`COARSE_SPACING` λ
#: without a warning.
COARSE_AREA = 0.01


def _check_resolution(scene: Scene) -> None:
    domain, lam = scene.domain, scene.model.interface_width
    h = domain.resolution
    measured = h != domain.spacing  # a mesh's node density, not the h the scene gives
    name = "the mesh's effective spacing √(area/dofs)" if measured else "domain.h"
    if lam / h < 1.0:
        raise SceneError(
            "domain.mesh" if measured else "domain.h", domain.source if measured else h,
            f"the interface (width ~2λ, λ = {lam:g}) needs h ≤ λ ({name} is {h:g}); use h ≤ {lam:g}",
        )
    coarse = domain.coarse_area(COARSE_SPACING * lam)
    if coarse > COARSE_AREA:
        warnings.warn(f"{coarse:.1%} of the mesh's area has a local spacing √(area per node) above "
                      f"{COARSE_SPACING:g}λ = {COARSE_SPACING * lam:g} (its effective spacing {h:.3g} averages its fine "
                      "and coarse parts): a particle there is not resolved (on a mesh with 47 % of its area so coarse, "
                      f"a lone disc relaxed to elongation 0.3, not 0); refine it to h ≤ {lam:g} where particles go",
                      ResolutionWarning, stacklevel=3)
    if lam / h < 2.0:
        warnings.warn(
            f"{name} = {h:g} puts only λ/h = {lam / h:g} nodes across the interface width λ = {lam:g}: "
            f"interfaces pin to the grid (in the sheared lattice at h = λ the lanes lock and oscillation "
            f"periods come out 1–4% short, verification/README.md); use h ≤ {lam / 2:g} for results "
            f"converged in h",
            ResolutionWarning, stacklevel=3,
        )


def _phase(index: int, table: dict) -> Phase:
    prefix = f"phases.{index}"
    if not isinstance(table, dict):
        raise SceneError(prefix, table, "a [[phases]] table with duration, dt, frame_interval (and flow)")
    table = dict(table)
    _check_keys(Phase, table, prefix)
    table.setdefault("name", f"phase{index}")
    _check_string(f"{prefix}.name", table["name"], " (the phase's label)")
    for key in ("duration", "dt", "frame_interval"):
        if key not in table:
            raise SceneError(f"{prefix}.{key}", None, "required (a number of time units)")
        _check_number(f"{prefix}.{key}", table[key])
    if "flow" in table and not isinstance(table["flow"], dict):
        raise SceneError(f"{prefix}.flow", table["flow"], 'a table such as {type = "shear", rate = 0.1}')
    for key in ("duration", "dt", "frame_interval"):
        table[key] = float(table[key])
    phase = _from_table(Phase, table, prefix)
    for key in ("duration", "frame_interval"):
        ratio = getattr(phase, key) / phase.dt
        if not ratio <= MAX_PHASE_STEPS:
            raise SceneError(f"{prefix}.{key}", getattr(phase, key), f"at most {MAX_PHASE_STEPS:.0e} steps of "
                             f"dt = {phase.dt:g} (it is {ratio:.3g} steps): a larger {prefix}.dt or a shorter "
                             f"{prefix}.{key}")
        if abs(ratio - round(ratio)) > 1e-6 * max(1.0, ratio) or round(ratio) < 1:
            raise SceneError(f"{prefix}.{key}", getattr(phase, key), f"a whole multiple (≥ 1) of {prefix}.dt = "
                             f"{phase.dt:g}")
    return phase


#: Smallest target radius, in interface widths λ, whose relaxed particle has a bulk (φ ≈ 1):
#: a lone relaxed disc peaks at φ = 0.36, 0.73, 0.87, 1.00 and 1.04 at R/λ = 0.4, 0.75, 1, 1.5
#: and ≥ 2 (λ = 2, the paper's μ, 300 time units at the default scheme).
BULK_RADIUS = 1.5


def _check_particles(scene: Scene) -> None:
    p, domain = scene.particles, scene.domain
    _check_particle_types(asdict(p))
    if p.layout == "list" and not p.centres:
        raise SceneError("particles.centres", p.centres, "a non-empty list of [x, y] pairs for layout = 'list'")
    n = scene.n_particles
    if p.radii is not None and len(p.radii) != n:
        raise SceneError("particles.radii", p.radii, f"{n} radii (one per particle), all > 0")
    # from the count, not an array: N may be any whole number here
    mean_square = float(np.mean(np.square(p.radii))) if p.radii is not None else scene.model.radius**2
    fraction = n * np.pi * mean_square / domain.area
    if fraction > MAX_AREA_FRACTION:
        # the domain's size too: a mesh drawn in other units shows here first
        valid = (f"the particles' total area is {fraction:.3g} × the domain's ({domain.period:.4g} × "
                 f"{domain.width:.4g} lattice units, area {domain.area:.4g}); at most {MAX_AREA_FRACTION} fits")
        # the key the user can change: the count where the layout takes one, else the radii
        if p.layout in ("random", "hexagonal"):
            most = int(MAX_AREA_FRACTION * domain.area / (np.pi * mean_square))
            raise SceneError("particles.N", n, f"{valid} (N ≤ {most} at R = {np.sqrt(mean_square):g})")
        largest = np.floor(100 * np.sqrt(MAX_AREA_FRACTION * domain.area / (np.pi * n))) / 100  # rounded down: it fits
        key, value = ("particles.radii", p.radii) if p.radii is not None else ("model.radius", scene.model.radius)
        raise SceneError(key, value, f"{valid} (a root-mean-square radius ≤ {largest:g} for {n} particles)")
    if p.layout == "hexagonal" and p.per_row is not None and p.per_row > n:
        raise SceneError("particles.per_row", p.per_row, f"a whole number from 1 to particles.N = {n}")
    # a disc wider than the channel is cut by both walls, one longer than the period overlaps
    # its own image: the particle started so vanished (its area 182 of 1597, x and y NaN)
    diameter = 2 * float(np.max(scene.initial_radii()))
    if diameter >= min(domain.width, domain.period):
        # unset, the initial radius is R/2: the key to change is still initial_radius (or R)
        target = "particles.radii" if p.radii is not None else "model.radius"
        default = "" if p.initial_radius is not None else (
            f"; unset, it is half of each particle's target radius ({target} = {float(np.max(scene.radii)):g} at most)")
        raise SceneError("particles.initial_radius", diameter / 2, f"initial discs that fit between the walls and "
                         f"within the period: a radius < {min(domain.width, domain.period) / 2:g} (half the width "
                         f"Ly = {domain.width:g} and half the period Lx = {domain.period:g}){default}")
    if p.layout != "random":  # fixed centres: check them now, not at the run
        _warn_cut_discs(scene, initial_centres(scene))
    lam, smallest = scene.model.interface_width, float(np.min(scene.radii))
    if smallest < BULK_RADIUS * lam:
        key = "particles.radii" if p.radii is not None else "model.radius"
        warnings.warn(
            f"{key}: a target radius R = {smallest:g} below {BULK_RADIUS:g}λ = {BULK_RADIUS * lam:g} (λ = {lam:g}, "
            f"model.interface_width) leaves the particle without a bulk: it is all interface, and relaxed it peaks "
            f"below φ = 1 (0.87 at R = λ, 0.36 at R = 0.4λ); the area term still holds ∫φ² at πR², but its shape "
            f"and the interface energy are not a particle's, and below about R = 0.53λ (at h = 1) it peaks under "
            f"1/2, where it counts as vanished and its x, y, elongation and orientation are NaN "
            f"(docs/outputs.md). Use R ≥ {BULK_RADIUS * lam:g} or a smaller "
            f"model.interface_width", ModelWarning, stacklevel=3)


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
    where = (f"y between the walls, {low:g} ≤ y ≤ {high:g}" if domain.kind == "grid"
             else "in the mesh's triangles, not in an obstacle or beyond a wall")
    outside = ~domain.inside(centres[:, 0], centres[:, 1])
    if outside.any() and p.centres:
        raise SceneError("particles.centres", centres[outside].tolist(), f"centres inside the domain ({where})")
    if outside.any():
        x, y = centres[np.argmax(outside)]
        raise SceneError("particles.layout", p.layout, f"a layout whose centres lie inside the domain ({where}); "
                         f"the {p.layout} layout puts {int(outside.sum())} of its centres outside, e.g. "
                         f"({x:.4g}, {y:.4g}): layout = \"random\" places discs clear of walls and obstacles, or "
                         "list the centres")
    _check_distinct(centres, domain.period, domain.spacing)
    return centres


def _warn_cut_discs(scene: Scene, centres: np.ndarray) -> None:
    """ModelWarning when a placed layout starts discs that a wall or obstacle cuts: they start
    with less than their area, and a disc over an obstacle grows around it."""
    walls = scene.domain.wall_points()
    dx = (walls[0][None, :] - centres[:, :1] + 0.5 * scene.domain.period) % scene.domain.period - 0.5 * scene.domain.period
    clearance = np.hypot(dx, walls[1][None, :] - centres[:, 1:]).min(axis=1)
    # wall points are nodes: a disc that only touches a wall between two of them is not cut
    cut = clearance < scene.initial_radii() - 0.5 * scene.domain.spacing
    if cut.any():
        k = int(np.argmax(cut))
        warnings.warn(f"the {scene.particles.layout} layout starts {int(cut.sum())} of {len(centres)} particles cut by "
                      f"a wall or obstacle, e.g. particle {k} at ({centres[k, 0]:.4g}, {centres[k, 1]:.4g}), whose "
                      f"initial disc of radius {scene.initial_radii()[k]:g} has a wall node {clearance[k]:.3g} from its "
                      "centre: they start with less than their area (layout = \"random\" places "
                      "discs clear of walls and obstacles)", ModelWarning, stacklevel=4)


def _check_distinct(centres: np.ndarray, period: float, spacing: float) -> None:
    """SceneError when two listed centres lie within one spacing of each other (x periodic):
    two fields started there are the same field, and the dynamics, symmetric in them, never
    tells them apart (a centre listed twice, as a rule)."""
    if len(centres) < 2:
        return
    dx = np.abs(centres[:, None, 0] - centres[None, :, 0]) % period
    distance = np.hypot(np.minimum(dx, period - dx), centres[:, None, 1] - centres[None, :, 1])
    distance[np.diag_indices(len(centres))] = np.inf
    i, j = np.unravel_index(np.argmin(distance), distance.shape)
    if distance[i, j] < spacing:
        raise SceneError("particles.centres", [centres[min(i, j)].tolist(), centres[max(i, j)].tolist()],
                         f"distinct centres: particles {min(i, j)} and {max(i, j)} are {distance[i, j]:.3g} apart, "
                         f"less than the spacing h = {spacing:g} (x is periodic with period {period:g})")


def parse_assignment(assignment: str) -> tuple[list[str], object]:
    """(the dotted key's parts, the value) of one ``--set key=value``: the value TOML, or a
    string where it is not TOML; a table value (``phases.1.flow={type="none"}``) replaces
    the table it is assigned to. SceneError for no ``=`` or an empty key part."""
    if not isinstance(assignment, str):
        raise SceneError("--set", assignment, "key=value, e.g. model.mu=10 or phases.1.flow.rate=0.3")
    key, sep, text = assignment.partition("=")
    key = key.strip()
    if not sep or not key:
        raise SceneError("--set", assignment, "key=value, e.g. model.mu=10 or phases.1.flow.rate=0.3")
    parts = [part.strip() for part in key.split(".")]
    if not all(parts):
        raise SceneError("--set", assignment, "a dotted key without empty parts, e.g. phases.1.flow.rate=0.3")
    return parts, tomlio.parse_value(text)


def set_value(data: dict, assignment: str) -> None:
    """Apply one ``--set key=value`` (dotted key, TOML value; phases by index: phases.1.dt).

    A value that is not TOML is taken as a string (``--set particles.layout=hexagonal``).
    SceneError for a malformed assignment (no ``=``, an empty key part), an index that is
    not one of the list's (``--set`` changes entries, it cannot add them), or a dotted key
    that runs through a value that is not a table (``model.mu.x``)."""
    parts, value = parse_assignment(assignment)
    target = data
    for depth, part in enumerate(parts):
        path, last = ".".join(parts[: depth + 1]), depth == len(parts) - 1
        if isinstance(target, list):
            parent = ".".join(parts[:depth])
            if not part.isdecimal() or int(part) >= len(target):
                valid = f"an index 0 … {len(target) - 1}" if target else "no index: the list is empty"
                raise SceneError(path, assignment, f"{valid} into '{parent}', which has {len(target)} entries "
                                 "(--set changes entries, it cannot add them)")
            if last:
                target[int(part)] = value
            else:
                target = target[int(part)]
        elif isinstance(target, dict):
            if last:
                target[part] = value
            else:
                target = target.setdefault(part, {})
        else:
            parent = ".".join(parts[:depth])
            raise SceneError(parent, target, f"a table to set '{part}' in (--set {assignment}); "
                             f"'{parent}' holds a {type(target).__name__}")


def read_scene_data(path: str | Path, assignments: list[str] | str | None = None) -> dict:
    """The parsed TOML of a scene file with ``--set`` assignments applied (not validated);
    ``assignments`` is a list of ``"key=value"`` strings, or one such string."""
    path = Path(path)
    if not path.is_file():
        raise SceneError("SCENE", str(path), "a TOML scene file" + (" (this path is a directory)" if path.is_dir()
                                                                     else " that exists"))
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise SceneError("SCENE", str(path), f"a readable file ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise SceneError("SCENE", str(path), f"a UTF-8 text file (TOML); byte {exc.start} is not UTF-8") from None
    try:
        data = tomlio.loads(text)
    except (tomlio.TOMLDecodeError, RecursionError, ValueError) as exc:
        raise SceneError("SCENE", str(path), f"valid TOML ({exc})") from None
    for assignment in [assignments] if isinstance(assignments, str) else assignments or []:
        set_value(data, assignment)
    return data


def load_scene(path: str | Path, assignments: list[str] | str | None = None) -> Scene:
    """Read and validate a scene file (any domain kind), applying ``--set`` first (a list of
    ``"key=value"`` strings, or one)."""
    return scene_from_dict(read_scene_data(path, assignments), Path(path).parent)
