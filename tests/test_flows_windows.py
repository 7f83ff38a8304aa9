"""Flow conventions and window behaviour at the periodic seam and at full width."""

import numpy as np
import pytest
from helpers import small_system, stepper

from femphase.analysis.shape import shape_observables
from femphase.domains.grid.domain import GridDomain
from femphase.domains.grid.lattice import channel_grid
from femphase.domains.grid.windows import GridLayout, Window, WindowPolicy, transfer
from femphase.errors import SceneError
from femphase.flows import flow_from_spec, linear_shear, poiseuille, python_flow


def test_flow_conventions():
    y = np.array([0.0, 60.0, 120.0, 240.0])
    shear = linear_shear(0.5, 240.0)
    assert np.allclose(shear.row_velocity(y, 0.0), 0.5 * y / 240.0)  # bottom wall at rest, top at γ̇
    assert np.allclose(linear_shear(0.5, 240.0, "shear_rate").row_velocity(y, 0.0), 0.5 * y)
    profile = poiseuille(0.5, 240.0).row_velocity(y, 0.0)
    assert profile[0] == profile[-1] == 0.0 and profile[2] == pytest.approx(0.5)
    u, v = shear.velocity(np.zeros(4), y, 0.0)
    assert np.allclose(v, 0.0) and np.allclose(u, shear.row_velocity(y, 0.0))
    # a scene's flow table measures y from the domain's lower wall and Ly between the walls
    domain = GridDomain(channel_grid(24.0, 240.0, 4.0))
    from_spec = flow_from_spec({"type": "shear", "rate": 0.5}, domain)
    assert np.allclose(from_spec.row_velocity(y, 0.0), shear.row_velocity(y, 0.0))
    with pytest.raises(SceneError, match="flow.rate"):
        flow_from_spec({"type": "shear"}, domain)


def test_a_particle_crossing_the_periodic_seam_stays_whole():
    domain, state = small_system([[50, 20]], length=60, width=40, initial_radius=8.0)
    relax = stepper(domain, state)
    for _ in range(100):
        relax.step(state)
    # a uniform row flow: pure translation, so the particle must not change while it crosses
    step = stepper(domain, state, flow=python_flow(lambda y: 0.5 + 0 * y, row=True))
    before = shape_observables(state)
    xs = []
    for _ in range(40):
        step.step(state)
        xs.append(shape_observables(state).x[0])
    after = shape_observables(state)
    assert state.windows[0].ix0 + state.windows[0].nx > 60 or state.windows[0].ix0 < 10  # wraps
    assert after.area[0] == pytest.approx(before.area[0], rel=1e-3)
    assert after.elongation[0] < 0.01
    steps = np.diff(np.unwrap(np.array(xs) * 2 * np.pi / 60) * 60 / (2 * np.pi))
    assert np.allclose(steps, 0.5, atol=0.05)  # moves steadily through the seam


def test_a_row_flow_may_give_one_number_for_a_uniform_flow():
    # row_flow passed u itself to the grid's advection, which indexed the number it returned
    # (IndexError); the docs' plug example hid it with "+ 0.0 * y"
    from femphase.flows import row_flow

    domain, state = small_system([[20, 20]], width=40, initial_radius=8.0)
    before = shape_observables(state).x[0]
    for flow in (row_flow("plug", lambda y, t: 0.5), python_flow(lambda y: 0.5, row=True)):
        assert flow.row_velocity(np.array([0.0, 1.0, 2.0]), 0.0).tolist() == [0.5, 0.5, 0.5]
        step = stepper(domain, state, flow=flow)
        step.step(state)
    assert shape_observables(state).x[0] == pytest.approx(before + 1.0, abs=0.05)


def test_a_particle_longer_than_the_period_gets_a_full_width_window_and_matches_the_full_mesh():
    fields = []
    for windows in (True, False):
        domain, state = small_system([[12, 20]], length=24, width=40, initial_radius=8.0, windows=windows)
        step = stepper(domain, state, windows=windows)
        for _ in range(30):
            step.step(state)
        fields.append(state.global_fields())
        if windows:
            assert state.windows[0].nx == domain.grid.nx  # 2(R + tail + margin) > Lx = 24
    # the window spans the width but not the channel's height: the truncation bound applies
    assert np.abs(fields[0] - fields[1]).max() < 2 * 0.01 * np.exp(-2 * 4.0 / 2.0)


def test_windows_grow_shrink_and_are_clipped_at_the_walls():
    grid = channel_grid(60, 40, 1.0)
    lattice = (grid.ny, grid.nx)
    policy = WindowPolicy.for_spacing(1.0)
    near_wall = policy.cover((0, 10), (20, 30), lattice)
    assert near_wall.iy0 == 0 and near_wall.ny < 10 + 1 + 2 * (policy.margin + policy.room) + policy.quantum
    window = Window(5, 30, 10, 30)
    phi = np.zeros((30, 30))
    phi[13:17, 13:17] = 1.0  # a small blob: margins of 13 > margin + 2 room + quantum → shrink
    shrunk = policy.fit(phi, window, lattice)
    assert shrunk.ny < window.ny and shrunk.nx < window.nx
    phi = np.zeros((30, 30))
    phi[1:29, 10:20] = 1.0  # inside the margin → grow, not forced square
    grown = policy.fit(phi, window, lattice)
    assert grown.ny > window.ny and grown.ny != grown.nx
    moved = transfer(phi, window, grown, grid.nx)
    assert moved.sum() == pytest.approx(phi.sum())


def test_a_moved_layout_is_the_layout_built_from_scratch():
    """Advection moves windows every substep; the channel then derives the new layout from
    the last one (Layout.moved) instead of building it. Both must agree exactly."""
    from femphase.domains.layout import Layout

    domain = GridDomain(channel_grid(40, 30, 1.0))
    windows = [Window(0, 12, 35, 12), Window(8, 12, 3, 12), Window(18, 12, 20, 16), Window(5, 8, 0, 40)]
    first = domain.layout(windows)
    shifted = [Window(w.iy0, w.ny, (w.ix0 + k) % 40, w.nx) for w, k in zip(windows, (7, -3, 1, 0))]
    moved = domain.layout(shifted)
    fresh = Layout(shifted, domain.window_key, domain._group_dofs, lambda w: w.shape, domain.operators.lumped_mass)
    assert moved is not first and moved.windows == fresh.windows
    for name in ("order", "sizes", "offsets", "owner", "node_index", "mass", "overlap_positions"):
        assert np.array_equal(getattr(moved, name), getattr(fresh, name)), name
    assert [(k, list(m), a, b, s) for k, m, a, b, s in moved.groups] == \
        [(k, list(m), a, b, s) for k, m, a, b, s in fresh.groups]
    # rows moved too (a window recentred in its shape, off the walls): the dofs rebuilt
    lifted = [Window(w.iy0 + k, w.ny, (w.ix0 + 2) % 40, w.nx) for w, k in zip(shifted, (0, 2, -1, 3))]
    relifted = domain.layout(lifted)
    fresh = Layout(lifted, domain.window_key, domain._group_dofs, lambda w: w.shape, domain.operators.lumped_mass)
    for name in ("node_index", "mass"):
        assert np.array_equal(getattr(relifted, name), getattr(fresh, name)), name
    # along x again: the rows' dofs and the lumped mass kept from the last move
    along = [Window(w.iy0, w.ny, (w.ix0 + 5) % 40, w.nx) for w in lifted]
    moved_along = domain.layout(along)
    fresh = Layout(along, domain.window_key, domain._group_dofs, lambda w: w.shape, domain.operators.lumped_mass)
    for name in ("node_index", "mass"):
        assert np.array_equal(getattr(moved_along, name), getattr(fresh, name)), name
    along_groups = moved_along.groups
    # the advection's moves: first columns given in layout order, the corners handed on
    advected = domain.moved_along_rows(moved_along, (moved_along.corners[:, 2] + 7) % 40)
    expected = [Window(w.iy0, w.ny, (w.ix0 + 7) % 40, w.nx) for w in along]
    assert advected.windows == tuple(expected) and advected.groups is along_groups
    fresh = GridLayout(expected, domain.window_key, domain._group_dofs, domain.operators.lumped_mass, domain.lattice)
    for name in ("node_index", "mass", "corners"):
        assert np.array_equal(getattr(advected, name), getattr(fresh, name)), name
    assert domain.moved_along_rows(advected, advected.corners[:, 2].copy()) is advected  # no move
    # a moved layout's dofs and masses are computed on first use: moves on from layouts
    # whose dofs nobody asked for (rows changed, then along x), each still its own
    unread = [domain.layout([Window(w.iy0 + k, w.ny, (w.ix0 + 3) % 40, w.nx) for w, k in zip(along, (0, -1, 1, 0))])]
    unread.append(domain.layout([Window(w.iy0, w.ny, (w.ix0 - 4) % 40, w.nx) for w in unread[0].windows]))
    unread.append(domain.layout([Window(w.iy0 + k, w.ny, w.ix0, w.nx) for w, k in zip(unread[1].windows, (0, 1, -2, 0))]))
    assert all(layout.groups is along_groups for layout in unread)  # all three moves
    assert all("node_index" not in layout.__dict__ for layout in unread)  # none computed yet
    for layout in reversed(unread):
        fresh = Layout(layout.windows, domain.window_key, domain._group_dofs, lambda w: w.shape,
                       domain.operators.lumped_mass)
        for name in ("node_index", "mass", "overlap_positions"):
            assert np.array_equal(getattr(layout, name), getattr(fresh, name)), name
    # a window of another shape (another key) is not a move: a new layout, built
    reshaped = domain.layout(shifted[:3] + [Window(5, 12, 0, 40)])
    assert reshaped.shapes != moved.shapes
    # with alternating diagonals a move by an odd number of nodes changes the key's parity:
    # not a move either
    alternating = GridDomain(channel_grid(40, 30, 1.0), diagonals="alternating")
    start = alternating.layout(windows)
    odd = alternating.layout([Window(w.iy0, w.ny, (w.ix0 + 1) % 40, w.nx) for w in windows[:3]] + windows[3:])
    assert [k for k, *_ in odd.groups] != [k for k, *_ in start.groups]
    advected = alternating.moved_along_rows(start, (start.corners[:, 2] + 1) % 40)
    assert [k for k, *_ in advected.groups] != [k for k, *_ in start.groups]
    assert advected.windows == tuple(Window(w.iy0, w.ny, (w.ix0 + 1) % 40, w.nx) for w in windows)


def test_misfits_of_a_whole_layout_follow_the_rule_window_by_window():
    """WindowPolicy.misfits finds every window's margins from one compiled scan of all windows
    (their occupied boxes); the rule, checked here window by window from each field's occupied nodes: a window
    fits while every margin not at a wall lies in [margin, longest_margin], full-width
    windows are always re-examined, empty ones never."""
    domain = GridDomain(channel_grid(40, 30, 1.0))
    lattice = (domain.grid.ny, domain.grid.nx)
    policy = WindowPolicy.for_spacing(1.0)
    windows = [Window(0, 16, 35, 16), Window(8, 16, 3, 16), Window(14, 16, 20, 16), Window(5, 8, 0, 40),
               Window(10, 16, 12, 16), Window(2, 12, 30, 12), Window(18, 12, 6, 12)]
    rng = np.random.default_rng(3)
    seen = set()
    for trial in range(20):
        layout = domain.layout(windows)
        fields = []
        for k, w in enumerate(windows):
            phi = np.zeros(w.shape)
            if (trial + k) % 5:  # every 5th field empty
                r0, c0 = rng.integers(0, w.ny - 1), rng.integers(0, w.nx - 1)
                phi[r0:rng.integers(r0 + 1, w.ny + 1), c0:rng.integers(c0 + 1, w.nx + 1)] = rng.uniform(0.02, 1.0)
            fields.append(phi.ravel())
        phi = layout.gather(fields)
        expected = []
        for i in layout.order:
            w = windows[i]
            rows, columns = np.nonzero(fields[i].reshape(w.shape) > policy.threshold)
            if rows.size == 0:
                expected.append(False)
                continue
            margins = [columns.min(), w.nx - 1 - columns.max(), rows.min(), w.ny - 1 - rows.max()]
            walls = [False, False, w.iy0 == 0, w.iy0 + w.ny == lattice[0]]
            bad = any(not wall and not policy.margin <= m <= policy.longest_margin
                      for m, wall in zip(margins, walls))
            expected.append(bad or w.nx == lattice[1])
        assert policy.misfits(layout, phi, lattice).tolist() == expected
        seen.update(expected)
    assert seen == {True, False}


def test_window_policy_numbers_at_h_1_and_a_quarter():
    # the other tests read the policy's room and longest margin back from it
    p = WindowPolicy.for_spacing(1.0)
    assert (p.margin, p.room, p.quantum, p.longest_margin) == (4, 1, 4, 4 + 2 * 1 + 4)
    q = WindowPolicy.for_spacing(0.25)  # margin 4/0.25 = 16 nodes, room ⌈16/4⌉ = 4, quantum 2·⌈1/0.25⌉ = 8
    assert (q.margin, q.room, q.quantum, q.longest_margin) == (16, 4, 8, 16 + 8 + 8)
