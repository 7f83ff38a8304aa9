"""Fast subsets of the convergence checks in verification/ (their quick levels).

The full studies run with ``python -m verification``; these take seconds and write nothing.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from femphase.analysis.shape import shape_observables
from femphase.config import Numerics
from femphase.domains.grid.domain import GridDomain
from femphase.domains.grid.lattice import channel_grid
from femphase.timestepping.stepper import Stepper
from verification import equilibrium, flat_interface, mms


# -- manufactured solution ------------------------------------------------------------------
@pytest.fixture(scope="module")
def mms_spatial():
    return mms.spatial_study(mms.QUICK_SPACINGS)


def test_mms_is_second_order_in_L2_and_first_in_H1(mms_spatial):
    assert all(1.8 <= order <= 2.2 for order in mms_spatial["orders_L2"])
    assert all(0.85 <= order <= 1.15 for order in mms_spatial["orders_H1"])
    # dt ∝ h² keeps the raw (not time-extrapolated) error second order too
    assert 1.8 <= mms_spatial["orders_L2_raw"][-1] <= 2.2


def test_mms_is_first_order_in_dt():
    h, steps = mms.QUICK_TEMPORAL
    table = mms.temporal_study(h, steps)
    assert all(0.85 <= order <= 1.15 for order in table["orders_L2"])
    assert table["stabilisation"] == [0.0] * len(steps)


def test_mms_detects_a_model_term_the_solver_gets_wrong(monkeypatch):
    """A 10 % error in μ inside the solver (the source keeps the right one) must stall the
    convergence: the check can fail."""
    wrong = replace(mms.PARAMS, area_stiffness=0.9 * mms.PARAMS.area_stiffness)
    stepper = mms.Stepper
    monkeypatch.setattr(mms, "Stepper", lambda domain, params, *a, **k: stepper(domain, wrong, *a, **k))
    assert mms.spatial_study((1.0, 0.5))["orders_L2"][-1] < 1.0


def test_mms_error_norms_of_the_interpolant_have_the_interpolation_orders():
    """The measurement itself: on the nodal interpolant of φ_e the norms must show the P1
    interpolation orders, 2 in L2 and 1 in H1 (a centroid-only gradient rule would not be
    accurate enough for this at the levels used)."""
    errors = []
    for h in (1.0, 0.5, 0.25):
        domain = GridDomain(channel_grid(mms.LX, mms.LY, h))
        errors.append(mms.error_norms(domain, mms.exact(*domain.coordinates, 3.0), 3.0))
    l2, h1 = np.array(errors).T
    assert mms.observed_orders((1.0, 0.5, 0.25), l2) == pytest.approx([2.0, 2.0], abs=0.05)
    assert mms.observed_orders((1.0, 0.5, 0.25), h1) == pytest.approx([1.0, 1.0], abs=0.05)


# -- flat interface -------------------------------------------------------------------------
def test_flat_interface_converges_at_second_order():
    table = flat_interface.study(flat_interface.QUICK_SPACINGS)
    assert all(order >= 1.8 for order in table["orders_L2"])
    assert all(order >= 1.8 for order in table["orders_max"])
    assert all(order >= 1.8 for order in table["orders_energy"])
    assert max(np.abs(table["centre_shift"])) < 1e-9  # the symmetry pins the interface
    assert max(table["x_variation"]) < 1e-12  # exactly one-dimensional


# -- isolated particle ------------------------------------------------------------------------
def test_superlevel_area_is_exact_for_linear_fields():
    domain = GridDomain(channel_grid(8.0, 6.0, 1.0))
    _, y = domain.coordinates
    assert equilibrium.superlevel_area(domain, y / domain.width, 0.3) == pytest.approx(0.7 * 8.0 * 6.0, rel=1e-12)
    # with the level between two rows, triangles with one and with two corners above occur
    assert equilibrium.superlevel_area(domain, 1 - y / domain.width, 0.55) == pytest.approx(0.45 * 48.0, rel=1e-12)


def test_richardson_recovers_limit_and_order():
    h = [1.0, 0.5, 0.25]
    fit = equilibrium.richardson(h, [3.0 + 0.7 * s**2 for s in h])
    assert fit["order"] == pytest.approx(2.0, abs=1e-9)
    assert fit["limit"] == pytest.approx(3.0, abs=1e-12)


def test_equilibrium_area_converges_to_its_extrapolated_limit():
    data = equilibrium.study([(h, 1.0) for h in (1.0, 0.5, 0.25)])
    area = data["quantities"]["area"]
    assert 1.7 <= area["order"] <= 2.5
    finest = area["table"][-1][0]
    assert abs(finest - area["limit"]) < 5e-5 * area["limit"]
    # the soft constraint holds the area a few per cent below πR² against the tension
    target = np.pi * equilibrium.PARAMS.radius**2
    assert 0.96 < area["limit"] / target < 0.99


def test_equilibrium_does_not_depend_on_dt():
    """The equilibrium reached with dt = 1 is a fixed point of the steps with dt = 10 and 0.1
    (compared through ∫φ² and ∫φ, blind to the particle's slow neutral drift)."""
    domain, state = equilibrium.relaxed_state(2.0, 1.0)
    area, mass = equilibrium.integrals_of(domain, state)
    for dt in (10.0, 0.1):
        moved = state.copy()
        stepper = Stepper(domain, equilibrium.PARAMS, Numerics(scheme="euler"), dt, None, moved.radii)
        for _ in range(20):
            stepper.step(moved)
        assert equilibrium.integrals_of(domain, moved) == pytest.approx((area, mass), rel=1e-10)


# -- sweeps compared point by point -----------------------------------------------------------
def test_sweep_comparison_states_differences_in_standard_errors():
    from verification import fig1a_sweep

    this = [{"rate": 0.1, "done": 3, "Psi6_mean": {"mean": 0.40, "sd": 0.03}}]
    other = [{"rate": 0.1, "done": 3, "Psi6_mean": {"mean": 0.35, "sd": 0.04}},
             {"rate": 1.0, "done": 3, "Psi6_mean": {"mean": 0.2, "sd": 0.01}}]
    table = fig1a_sweep.comparison(this, other)
    # (0.40 − 0.35) / √(0.03²/3 + 0.04²/3) = 0.05 / 0.02887 = +1.7
    assert "| 0.1 | 0.4, 0.35, +1.7 |" in table
    assert len(table.splitlines()) == 3  # header, rule, one row: rates only the other sweep has are left out


def test_stored_sweeps_compare_without_their_runs(tmp_path, monkeypatch, capsys):
    import json
    import sys

    from verification import fig1a_sweep

    for name, mean in (("mine", 0.40), ("theirs", 0.35)):
        entry = {"rate": 0.1, "runs": 3, "done": 3, "Psi6_mean": {"mean": mean, "sd": 0.03 if mean > 0.36 else 0.04}}
        (tmp_path / f"{name}.json").write_text(json.dumps({"rates": [entry]}))
    monkeypatch.setattr(fig1a_sweep, "RESULTS", tmp_path)
    monkeypatch.setattr(sys, "argv", ["fig1a_sweep", "--stored", "mine", "--against", "theirs"])
    fig1a_sweep.main()
    out = capsys.readouterr().out
    assert "| 0.1 | 3/3 | 0.4 ± 0.03 |" in out and "| 0.1 | 0.4, 0.35, +1.7 |" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.json", "theirs.json"]  # nothing written
    monkeypatch.setattr(sys, "argv", ["fig1a_sweep", "--stored", "nothing"])
    with pytest.raises(SystemExit, match="no sweep results named 'nothing'.*stored sweeps: mine, theirs"):
        fig1a_sweep.main()


# -- how each domain reads the elongation -------------------------------------------------
def test_grid_and_mesh_read_an_ellipses_elongation_to_second_order():
    """The same ellipses read on the structured channel at h = 1, 0.5, 0.25: the differences
    between levels fall by 4 per halving (the nodal rule is O(h²)); the mesh at h ≈ 1.08
    reads within the grid's h = 1 error of the finest level."""
    from verification import shape_bias

    rng = np.random.default_rng(1)
    centres = np.column_stack([rng.uniform(0.0, 70.0, 6), rng.uniform(20.0, 220.0, 6)])
    angles = rng.uniform(-0.5 * np.pi, 0.5 * np.pi, 6)

    def read(path, *assignments):
        scene = shape_bias.example_scene(path, assignments)
        state = shape_bias.ellipses(scene, centres, angles, 0.2)
        return shape_observables(state).elongation.mean()

    coarse, middle, fine = (read("random.toml", f"domain.h={h}") for h in (1.0, 0.5, 0.25))
    assert np.log2((coarse - middle) / (middle - fine)) == pytest.approx(2.0, abs=0.3)
    assert abs(read("straight_mesh.toml") - fine) < abs(coarse - fine)


# -- the command ------------------------------------------------------------------------------
def _stored(directory):
    return {path.name: path.read_bytes() for path in sorted(directory.iterdir()) if path.is_file()}


def test_quick_levels_leave_the_stored_results_and_the_readme_alone(tmp_path, capsys, monkeypatch):
    import tempfile

    from verification import __main__ as command

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the quick run's own directory lands here
    stored, readme = _stored(command.RESULTS), command.README.read_bytes()
    assert command.main(["--quick", "--only", "mms"]) == 0
    assert command.main(["--quick", "--only", "mms", "--output", str(tmp_path / "named")]) == 0
    assert _stored(command.RESULTS) == stored and command.README.read_bytes() == readme
    for directory in [tmp_path / "named", *tmp_path.glob("verification-quick-*")]:
        assert json.loads((directory / "mms.json").read_text())["quick"] is True and (directory / "mms.png").is_file()
    temporary = [line for line in capsys.readouterr().out.splitlines() if line.startswith("results in ")]
    assert len(temporary) == 2 and len(list(tmp_path.glob("verification-quick-*"))) == 1


def test_false_periods_come_from_few_cycles_at_several_percent(tmp_path):
    # verification/README.md and docs/aggregation.md tell a false period by its cycles and
    # its relative uncertainty: the full study (a second) must keep saying so
    from verification import period_false_alarms

    results = period_false_alarms.run(quick=False, output=tmp_path)
    false = [f for row in results["red"] for f in row["found"]]
    assert 0 < len(false) < 0.1 * results["red_records"]
    assert all(cycles <= 10 and relative >= 0.04 for _, relative, cycles in false)
    assert results["periodic_within_10_percent"] > 0.75 * results["periodic_records"]
