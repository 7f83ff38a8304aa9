"""Faults of the user's own flows, observables and schemes are named, not taken for femphase's.

Each of these was "internal error (…); this is a bug", exit 1, naming neither the entry nor
what was wrong with it, or (a NaN from a registered flow) a blow-up of φ.
"""

from pathlib import Path

import numpy as np
import pytest

from femphase.analysis.observables import OBSERVABLES, Observable
from femphase.cli import main
from femphase.errors import SceneError
from femphase.flows import FLOWS, row_flow
from femphase.scene import scene_from_dict
from femphase.timestepping import SCHEMES
from femphase.timestepping.euler import LinearlyImplicitEuler

SCENE = {
    "name": "extensions",
    "domain": {"Lx": 30.0, "Ly": 30.0, "h": 1.0},
    "particles": {"layout": "list", "centres": [[15.0, 15.0]]},
    "model": {"radius": 5.0},
    "phases": [{"name": "relax", "duration": 2.0, "dt": 1.0, "frame_interval": 1.0},
               {"name": "flow", "duration": 4.0, "dt": 1.0, "frame_interval": 1.0,
                "flow": {"type": "shear", "rate": 0.1}}],
}


def raising_builder(spec, domain):
    raise KeyError("oops")


def function_builder(spec, domain):
    return lambda x, y, t: (x, y)


def nan_builder(spec, domain):
    return row_flow("nan", lambda y, t: np.where(t > 2.5, np.nan, 0.01 * y), steady=False)


class RaisingObservable(Observable):
    name = "raising"
    global_columns = ("peak",)

    def __call__(self, state, values):
        raise RuntimeError("boom")


class SilentObservable(Observable):
    name = "silent"
    global_columns = ("peak",)

    def __call__(self, state, values):
        return None


class RaisingScheme(LinearlyImplicitEuler):
    name = "raising"

    def advance(self, phi, layout, state):
        raise RuntimeError("boom")


class ShortScheme(LinearlyImplicitEuler):
    name = "short"

    def advance(self, phi, layout, state):
        return phi[:-3], layout


class OrderlessScheme(LinearlyImplicitEuler):
    name = "orderless"
    order = None


def scheme_function(stepper):
    return None


@pytest.fixture(autouse=True)
def entries():
    added = [(FLOWS, "raising", raising_builder), (FLOWS, "function", function_builder), (FLOWS, "nan", nan_builder),
             (OBSERVABLES, "raising", RaisingObservable), (OBSERVABLES, "silent", SilentObservable),
             (SCHEMES, "raising", RaisingScheme), (SCHEMES, "short", ShortScheme),
             (SCHEMES, "orderless", OrderlessScheme), (SCHEMES, "function", scheme_function)]
    for registry, name, entry in added:
        registry.register(name)(entry)
    yield
    for registry, name, _ in added:
        registry.unregister(name)


def scene(**changes) -> dict:
    data = {key: dict(value) if isinstance(value, dict) else list(value) for key, value in SCENE.items()
            if key != "name"}
    data["name"] = SCENE["name"]
    for key, value in changes.items():
        data[key] = value
    return data


def run(tmp_path: Path, data: dict, capsys, name: str = "run") -> tuple[int, str]:
    from femphase.tomlio import to_toml

    path = tmp_path / "scene.toml"
    path.write_text(to_toml(data))
    capsys.readouterr()
    code = main(["run", str(path), "-o", str(tmp_path / name), "-q"])
    return code, capsys.readouterr().err


def with_flow(flow: dict) -> dict:
    return scene(phases=[SCENE["phases"][0], {**SCENE["phases"][1], "flow": flow}])


@pytest.mark.parametrize("flow, reason", [
    ("raising", "a flow type whose builder builds its flow: test_extensions.raising_builder raised KeyError: 'oops'"),
    ("function", "a flow type whose builder returns a femphase.flows.Flow: test_extensions.function_builder "
                 "returned function"),
])
def test_a_flow_builder_that_fails_is_named(flow, reason):
    with pytest.raises(SceneError) as refused:
        scene_from_dict(with_flow({"type": flow}))
    assert refused.value.key == "phases.1.flow.type" and reason in str(refused.value)


def test_a_registered_flow_that_gives_nan_is_named_not_taken_for_a_blow_up(tmp_path, capsys):
    code, err = run(tmp_path, with_flow({"type": "nan"}), capsys)
    assert code == 3 and "the flow function test_extensions.nan_builder failed at t = " in err, err
    assert "it returned NaN or inf" in err and "blew up" not in err


def test_an_observable_that_fails_is_named(tmp_path, capsys):
    code, err = run(tmp_path, scene(output={"observables": ["shape", "raising"]}), capsys)
    assert code == 3, err
    assert ("the observable 'raising' (test_extensions.RaisingObservable) failed at step 0 (t = 0): it raised "
            "RuntimeError: boom") in err
    code, err = run(tmp_path, scene(output={"observables": ["shape", "silent"]}), capsys, "silent")
    assert code == 2 and "an observable that returns a mapping of its columns; it returned NoneType" in err, err


@pytest.mark.parametrize("scheme, code, reason", [
    ("raising", 3, "the time scheme 'raising' (test_extensions.RaisingScheme) failed at step 0 (t = 0): its "
                   "advance raised RuntimeError: boom"),
    ("short", 3, "its advance must return (φ, layout), φ one value per position of the layout; it returned φ of "
                 "shape (781,) for a layout of 784 positions"),  # the disc's window, 28 × 28 nodes
    ("orderless", 2, "a scheme that states its order of accuracy in dt: test_extensions.OrderlessScheme has no "
                     "class attribute order > 0 (it has None)"),
    ("function", 2, "a registered subclass of femphase.timestepping.base.TimeScheme; test_extensions.scheme_function "
                    "is a function"),
])
def test_a_scheme_that_fails_is_named(tmp_path, capsys, scheme, code, reason):
    returned, err = run(tmp_path, scene(numerics={"scheme": scheme}), capsys)
    assert returned == code and reason in err, err
    assert "internal error" not in err


def test_an_energy_term_that_returns_the_wrong_shape_is_named():
    # a derivative of the wrong shape stopped the stepper with a bare numpy broadcast error,
    # an energy that is an array with "only 0-dimensional arrays can be converted"
    from dataclasses import dataclass
    from typing import ClassVar

    from femphase.model.energy import EnergyTerm, FreeEnergy
    from femphase.run import Simulation

    @dataclass(frozen=True)
    class Lopsided(EnergyTerm):
        name: ClassVar[str] = "lopsided"
        short: bool = True

        def energy(self, fields):
            return 0.0 if self.short else fields.phi

        def explicit_derivative(self, fields):
            return fields.phi[:-1] if self.short else 0 * fields.phi

        def curvature_bound(self, smallest_radius, pairs):
            return 0.0

    data = scene()
    data["output"] = {"fields": False}
    built = scene_from_dict(data)
    for short, reason in ((True, r"explicit_derivative\(\) must return one finite value per position of the layout, "
                                 r"shape \(784,\); it returned shape \(783,\)"),
                          (False, r"energy\(\) must return one finite number; it returned ndarray of shape \(784,\)")):
        energy = FreeEnergy(list(FreeEnergy.paper(built.model).terms) + [Lopsided(short)])
        with pytest.raises(ValueError, match=r"the energy term 'lopsided' \(test_extensions\..*Lopsided\): " + reason):
            Simulation(built, energy=energy).run(built.initial_state())
