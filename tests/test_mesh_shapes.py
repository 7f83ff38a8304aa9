"""Shaped windows on meshes: what a shape holds, when it is made anew, and that runs on shapes
agree with runs on boxes and resume from checkpoints bit for bit."""

import numpy as np
import pytest
from helpers import stepper

from femphase.config import Numerics
from femphase.domains.mesh.boxes import Box, BoxPolicy
from femphase.domains.mesh.domain import MeshDomain
from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing
from femphase.domains.mesh.shapes import Shape, ShapePolicy
from femphase.flows import poiseuille
from femphase.io.checkpoints import load_checkpoint, save_checkpoint
from femphase.state import discs_state

EDGE = edge_for_spacing(1.0)


def straight(length: float, height: float, seed: int = 1) -> MeshDomain:
    return MeshDomain.from_mesh(*delaunay_channel(length, EDGE, lambda x: 0 * x, lambda x: 0 * x + height, seed=seed))


def discs(domain, centres, numerics=Numerics(), initial_radius=6.0):
    n = len(centres)
    return discs_state(domain, np.asarray(centres, dtype=float), np.full(n, 8.0), np.full(n, initial_radius), 2.0,
                       domain.window_policy(numerics))


def euclidean_to(domain, dofs, members):
    """The straight-line distance of every dof of ``dofs`` to the nearest of ``members`` (x periodic)."""
    x, y = domain.coordinates
    dx = x[dofs][:, None] - x[members][None, :]
    dx -= domain.period * np.round(dx / domain.period)
    return np.sqrt(dx**2 + (y[dofs][:, None] - y[members][None, :]) ** 2).min(axis=1)


@pytest.mark.parametrize("solver, mode, kind", [("auto", "auto", ShapePolicy), ("direct", "auto", BoxPolicy),
                                                ("auto", "boxes", BoxPolicy), ("direct", "shapes", ShapePolicy)])
def test_shapes_are_the_default_where_windows_are_solved_at_once(solver, mode, kind):
    policy = straight(30.0, 20.0).window_policy(Numerics(solver=solver, mesh_windows=mode))
    assert isinstance(policy, kind)
    # without windows every field is on the whole mesh, whatever the windows' kind
    assert not straight(30.0, 20.0).window_policy(Numerics(mesh_windows="shapes", windows=False)).enabled


def test_a_dilation_holds_the_dofs_within_its_reach_at_no_less_than_their_distance():
    domain = straight(40.0, 30.0)
    x, y = domain.coordinates
    rng = np.random.default_rng(5)
    sets = []
    for cx, cy in ((20.0, 15.0), (1.0, 10.0), (39.0, 28.0)):  # inside, across the seam, at a wall
        dx = x - cx - domain.period * np.round((x - cx) / domain.period)
        sets.append(np.flatnonzero(dx**2 / 36.0 + (y - cy) ** 2 / 9.0 <= 1.0))
    sets.append(rng.choice(domain.n_dofs, 5, replace=False))  # scattered dofs
    reach = 6.0
    for members, (dofs, distances) in zip(sets, domain.dilation(sets, reach)):
        assert np.all(np.diff(dofs) > 0)
        straight_line = euclidean_to(domain, dofs, members)
        assert np.all(distances >= straight_line - 1e-12) and np.all(distances <= reach)
        assert np.all(distances[np.isin(dofs, members)] == 0.0)
        # every dof a spacing inside the reach, in a straight line, is in (along the edges a
        # path may be a little longer)
        every = euclidean_to(domain, np.arange(domain.n_dofs), members)
        assert np.isin(np.flatnonzero(every <= reach - 1.0), dofs).all()


def test_a_dilation_along_a_motion_holds_the_swept_set():
    # a fast flow's particle: the set swept along its motion, each dof standing for the
    # segment from it to it moved, and the dofs within reach of that
    domain = straight(40.0, 30.0)
    x, y = domain.coordinates
    members = np.flatnonzero(np.hypot(x - 12.0, y - 15.0) <= 5.0)
    motion = np.array([[6.0, 2.0]])
    starts = np.array([0, members.size])
    (dofs, distances), = domain._dilate(members, starts, np.array([3.0]), motion)
    (still, _), = domain._dilate(members, starts, np.array([3.0]), np.zeros((1, 2)))
    moved = np.flatnonzero(np.hypot(x - 18.0, y - 17.0) <= 5.0)  # the set at the motion's end
    assert np.isin(moved, dofs).all() and not np.isin(moved, still).all()
    # the segments start at the set's edge dofs, and a dof is measured to the segment of the
    # dof that reached it, not the nearest: where the set moves to lies within the room (2),
    # so the margin around it stays inside (1.5 at most here)
    assert np.all(distances[np.isin(dofs, moved)] <= 2.0)
    # and no farther than the reach from the swept discs (a capsule of radius 5 + 3)
    t = np.clip(((x[dofs] - 12.0) * 6.0 + (y[dofs] - 15.0) * 2.0) / 40.0, 0.0, 1.0)
    assert np.all(np.hypot(x[dofs] - 12.0 - 6.0 * t, y[dofs] - 15.0 - 2.0 * t) <= 8.0 + 1e-9)


def test_a_disc_shape_reaches_past_the_disc_by_margin_and_room():
    domain = straight(40.0, 30.0)
    policy = ShapePolicy.for_spacing(1.0)
    shape = domain.disc_window((1.5, 12.0), 7.0, policy)  # across the seam
    x, y = domain.coordinates
    dx = x - 1.5 - domain.period * np.round((x - 1.5) / domain.period)
    distance = np.hypot(dx, y - 12.0)
    assert shape.reach == policy.reach() == policy.margin + policy.room
    np.testing.assert_array_equal(shape.dofs, np.flatnonzero(distance <= 7.0 + policy.reach()))
    np.testing.assert_allclose(shape.distances, np.maximum(distance[shape.dofs] - 7.0, 0.0))


def test_shapes_are_made_anew_only_when_a_particle_leaves_their_room_and_then_together():
    policy = ShapePolicy.for_spacing(1.0)
    assert (policy.room, policy.early) == (2.0, 1.0)
    reaches = np.full(3, policy.reach())
    assert not policy.to_remake(np.array([0.5, 1.9, 2.0]), reaches).any()
    assert policy.to_remake(np.array([2.1, 1.5, 0.9]), reaches).tolist() == [True, True, False]
    # the room a shape leaves is its own reach less the margin and the coming motion
    assert policy.to_remake(np.array([0.5, 0.5, 0.5]), reaches, np.array([0.0, 1.0, 1.6])).tolist() == [
        False, True, True]
    # a shape made to reach farther (for a margin widened by a changing flow's motion) has more room
    assert not policy.to_remake(np.array([3.0]), np.array([policy.reach() + 2.0]), 0.5).any()


def test_a_refit_leaves_a_moving_particle_its_margin_inside_its_shape():
    # a disc growing and carried along the channel: at every refit each dof within the
    # margin of the particle (φ > threshold) lies inside its shape, and shapes are made
    # anew as it goes
    domain = straight(40.0, 24.0)
    numerics = Numerics()
    state = discs(domain, [[10.0, 12.0]], numerics)
    policy = domain.window_policy(numerics)
    step = stepper(domain, state, dt=1.0, flow=poiseuille(1.0, 24.0))
    made = set()
    for _ in range(30):
        step.step(state)
        layout, phi = domain.refit(*state.flat(), policy, None)
        shape = layout.windows[0]
        made.add(shape.serial)
        members = shape.dofs[phi > policy.threshold]
        near = np.flatnonzero(euclidean_to(domain, np.arange(domain.n_dofs), members) <= policy.margin)
        assert np.isin(near, shape.dofs).all()
    assert len(made) > 3


def test_runs_on_shapes_agree_with_the_whole_mesh_as_runs_on_boxes_do():
    # a shape keeps the paper's margin and little more, a box more on most sides: against
    # the whole mesh a shaped run's φ differs by 2.8e-4, in the tail the margin cuts
    # (φ ≈ 2e-4 at 4 beyond the threshold), the boxes' by 3.2e-5; the observables of a pair
    # relaxing in Poiseuille flow differ by 7e-8 (area, relative), 1.1e-4 (centroid) and
    # 5e-7 (shape tensor, of its scale)
    domain = straight(40.0, 30.0)
    ends = {}
    for mode, windows in (("shapes", True), ("boxes", True), ("boxes", False)):
        numerics = Numerics(mesh_windows=mode, windows=windows)
        state = discs(domain, [[12.0, 11.0], [26.0, 19.0]], numerics)
        step = stepper(domain, state, dt=2.0, flow=poiseuille(0.5, 30.0), mesh_windows=mode, windows=windows,
                       scheme="adaptive")
        for _ in range(30):
            step.step(state)
        if windows:
            assert all(isinstance(w, Shape if mode == "shapes" else Box) for w in state.windows)
        ends[mode, windows] = (domain.shape_moments(*state.flat()), sum(f.size for f in state.fields))
    (area, centroid, tensor), _ = ends["boxes", False]
    for mode in ("shapes", "boxes"):
        (ours, our_centroid, our_tensor), _ = ends[mode, True]
        assert np.abs(ours / area - 1.0).max() < 1e-6
        assert np.abs(our_centroid - centroid).max() < 1e-3
        assert np.abs(our_tensor - tensor).max() < 1e-5 * np.abs(tensor).max()
    assert ends["shapes", True][1] < 0.9 * ends["boxes", True][1]


def test_shapes_go_through_a_checkpoint_and_resume_bit_for_bit(tmp_path):
    domain = straight(40.0, 30.0)
    state = discs(domain, [[12.0, 11.0], [26.0, 19.0], [38.0, 15.0]])
    step = stepper(domain, state, dt=2.0, flow=poiseuille(0.5, 30.0))
    for _ in range(5):
        step.step(state)
    save_checkpoint(tmp_path / "c.h5", state)
    back, _ = load_checkpoint(tmp_path / "c.h5", domain)
    for ours, theirs in zip(state.windows, back.windows):
        assert ours.serial == theirs.serial
        np.testing.assert_array_equal(ours.dofs, theirs.dofs)
        np.testing.assert_array_equal(ours.distances, theirs.distances)
    # on a fresh domain, whose next shape would otherwise take a serial already saved
    fresh = straight(40.0, 30.0)
    resumed, _ = load_checkpoint(tmp_path / "c.h5", fresh)
    for run, on in ((state, domain), (resumed, fresh)):
        go = stepper(on, run, dt=2.0, flow=poiseuille(0.5, 30.0))
        for _ in range(10):
            go.step(run)
    assert [w.serial for w in resumed.windows] == [w.serial for w in state.windows]
    np.testing.assert_array_equal(resumed.global_fields(), state.global_fields())


def test_a_run_on_boxes_continues_on_shapes_and_back():
    # a resume with the other kind of window: the first refit makes the new kind for every
    # particle, and the run goes on as one that kept its boxes
    domain = straight(40.0, 30.0)
    ends = []
    for modes in (("boxes", "boxes"), ("shapes", "boxes")):
        state = discs(domain, [[12.0, 11.0], [26.0, 19.0]], Numerics(mesh_windows="boxes"))
        for mode in modes:
            stepper(domain, state, dt=0.5, flow=None, mesh_windows=mode).step(state)
            assert all(isinstance(w, Shape if mode == "shapes" else Box) for w in state.windows)
        ends.append(state.global_fields())
    assert np.abs(ends[0] - ends[1]).max() < 1e-4


def test_windows_from_rows_without_their_dofs_are_refused():
    domain = straight(30.0, 20.0)
    with pytest.raises(ValueError, match="shape_dofs"):
        domain.windows_from_array(np.array([[3.0, -1.0, 10.0, 0.0]]))
