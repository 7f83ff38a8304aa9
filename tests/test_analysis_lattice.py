"""Neighbours, order parameters, lattice angle and T1 counting on constructed lattices."""

import numpy as np
import pytest

from femphase.analysis import lattice

# the paper's channel: 100 particles in 20 lanes of 5
LX, LY, PER_LANE, LANES = 70.0, 240.0, 5, 20
SPACING, LANE_GAP = LX / PER_LANE, LY / LANES  # a = 14, h = 12: nearly hexagonal


def lanes(shear_shift: float = 0.0) -> np.ndarray:
    """Hexagonal lanes along x, alternate lanes offset by half a spacing, and lane k further
    displaced by k * shear_shift along x (simple shear: every pair of neighbouring lanes
    has slid by shear_shift)."""
    lane, slot = np.divmod(np.arange(LANES * PER_LANE), PER_LANE)
    x = (slot + (lane % 2) / 2) * SPACING + lane * shear_shift
    return np.column_stack([np.mod(x, LX), (lane + 0.5) * LANE_GAP])


def wall_lanes(centroids: np.ndarray) -> np.ndarray:
    return (centroids[:, 1] < LANE_GAP) | (centroids[:, 1] > LY - LANE_GAP)


def neighbour_counts(pairs: np.ndarray, n_particles: int) -> np.ndarray:
    return np.bincount(pairs.ravel(), minlength=n_particles)


def test_pairs_are_unique_and_ordered():
    pairs = lattice.periodic_delaunay_pairs(lanes(), LX)
    assert pairs.dtype.kind == "i"
    assert (pairs[:, 0] < pairs[:, 1]).all()
    assert len(np.unique(pairs, axis=0)) == len(pairs)


def test_hexagonal_lanes_have_six_neighbours_across_the_seam():
    centroids = lanes()
    counts = neighbour_counts(lattice.periodic_delaunay_pairs(centroids, LX), len(centroids))
    # interior lanes need their neighbours across x = 0 ≡ Lx to reach six
    assert (counts[~wall_lanes(centroids)] == 6).all()
    # wall lanes: two in-lane neighbours and two in the one lane beside them
    assert (counts[wall_lanes(centroids)] == 4).all()


def test_neighbours_across_the_periodic_seam():
    centroids = np.array([[1.0, 20.0], [69.0, 20.0], [35.0, 20.0], [18.0, 32.0], [52.0, 8.0]])
    pairs = lattice.periodic_delaunay_pairs(centroids, LX)
    assert [0, 1] in pairs.tolist()
    # 2 apart through the seam, not 68 across the channel
    np.testing.assert_allclose(lattice.bond_vectors(centroids, LX, [[1, 0]]), [[2.0, 0.0]])


def test_hexagonal_lanes_have_bond_order_one():
    centroids = lanes()
    psi = lattice.bond_order(centroids, LX)
    interior = ~wall_lanes(centroids)
    # inclined bonds at atan(12/7) = 59.7°, not exactly 60°
    assert lattice.global_order(psi, where=interior) == pytest.approx(1.0, abs=1e-3)
    # wall particles only have lattice directions too: kept, and ψ6 = 1 there as well
    assert np.abs(psi) == pytest.approx(np.ones(len(psi)), abs=1e-3)


def test_odd_bond_order_sees_each_bond_from_both_ends():
    # six bonds at 60° steps: exp(3iθ) alternates ±1 and cancels, unless a bond seen from its
    # second particle were taken in the first particle's direction
    centroids = lanes()
    psi3 = lattice.bond_order(centroids, LX, m=3)
    assert np.abs(psi3[~wall_lanes(centroids)]).max() < 0.05


def test_disordered_positions_lower_bond_order():
    centroids = lanes() + np.random.default_rng(0).normal(scale=3.0, size=(100, 2))
    centroids[:, 0] %= LX
    psi = lattice.bond_order(centroids, LX)
    assert lattice.global_order(psi) < 0.5


def test_global_order_mask_and_particles_without_neighbours():
    psi = np.array([1.0, 1j, np.nan, -1.0])
    assert lattice.global_order(psi) == pytest.approx(abs(1 + 1j - 1) / 3)
    assert lattice.global_order(psi, where=[True, False, True, False]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="no particle"):
        lattice.global_order(psi, where=[False, False, True, False])


def test_nematic_order_of_aligned_and_crossed_lanes():
    centroids = lanes()
    pairs = lattice.periodic_delaunay_pairs(centroids, LX)
    n = len(centroids)
    aligned = lattice.nematic_order(np.full(n, 0.3), pairs, n)
    np.testing.assert_allclose(aligned, 1.0)

    lane = np.arange(n) // PER_LANE
    crossed = np.where(lane % 2 == 0, np.pi / 4, -np.pi / 4)
    psi2 = lattice.nematic_order(crossed, pairs, n)
    # two aligned in-lane neighbours (+1) and four at right angles in the next lanes (−1)
    np.testing.assert_allclose(psi2[~wall_lanes(centroids)], -1 / 3)
    # nematic: turning an axis by π changes nothing
    flipped = crossed + np.pi * (np.arange(n) % 3 == 0)
    np.testing.assert_allclose(lattice.nematic_order(flipped, pairs, n), psi2, atol=1e-12)


def test_nematic_order_is_relative_to_each_particle():
    # a triangle of particles with axes at 0, π/8 and π/4
    psi2 = lattice.nematic_order([0.0, np.pi / 8, np.pi / 4], [[0, 1], [0, 2], [1, 2]], 3)
    turn = np.exp(1j * np.pi / 4)  # exp(2i · π/8)
    np.testing.assert_allclose(
        psi2, [(turn**-1 + turn**-2) / 2, (turn + turn**-1) / 2, (turn**2 + turn) / 2]
    )


def test_frame_average():
    mean, std = lattice.frame_average([0.8, 0.9, 1.0])
    assert mean == pytest.approx(0.9)
    assert std == pytest.approx(np.sqrt(2 / 300))


def test_hexagonal_lattice_angle_is_pi_over_3():
    angle = lattice.lattice_angle(lanes(), LX)
    assert angle == pytest.approx(np.arctan(LANE_GAP / (SPACING / 2)))
    assert angle == pytest.approx(np.pi / 3, abs=5e-3)


def test_square_lattice_rotated_45_degrees_has_lattice_angle_pi_over_4():
    # bonds of length 14/√2 at ±45°; both diagonals of each square (horizontal and vertical)
    # are equally long, and the Delaunay choice between them must not matter
    lane, slot = np.divmod(np.arange(34 * PER_LANE), PER_LANE)
    x = (slot + (lane % 2) / 2) * SPACING
    centroids = np.column_stack([x, (lane + 0.5) * SPACING / 2])
    assert lattice.lattice_angle(centroids, LX) == pytest.approx(np.pi / 4)


def test_square_lattice_at_the_t1_has_lattice_angle_pi_over_4():
    # lanes stacked on top of each other: the degenerate diagonal carries the angle
    lane, slot = np.divmod(np.arange(17 * PER_LANE), PER_LANE)
    centroids = np.column_stack([slot * SPACING, (lane + 0.5) * SPACING])
    assert lattice.lattice_angle(centroids, LX) == pytest.approx(np.pi / 4)


@pytest.mark.parametrize(
    "shift, expected",
    [
        # before the T1 (s < a/2) the flattening bond spans a/2 + s along x ...
        (3.0, np.arctan(LANE_GAP / (SPACING / 2 + 3.0))),
        (6.5, np.arctan(LANE_GAP / (SPACING / 2 + 6.5))),
        # ... after it the new diagonal spans 3a/2 − s, rising back to the hexagonal angle
        (7.5, np.arctan(LANE_GAP / (3 * SPACING / 2 - 7.5))),
        (11.0, np.arctan(LANE_GAP / (3 * SPACING / 2 - 11.0))),
        (SPACING, np.arctan(LANE_GAP / (SPACING / 2))),
    ],
)
def test_lattice_angle_of_sliding_lanes(shift, expected):
    assert lattice.lattice_angle(lanes(shift), LX) == pytest.approx(expected)
    per_particle = lattice.particle_lattice_angles(lanes(shift), LX)
    np.testing.assert_allclose(per_particle, expected)


def test_lattice_angle_needs_inclined_bonds():
    centroids = np.array([[10.0, 5.0], [30.0, 5.0], [50.0, 5.0], [30.0, 100.0]])
    with pytest.raises(ValueError, match="no inclined bonds"):
        lattice.lattice_angle(centroids, LX)


def t1_quadrilateral(gap: float) -> np.ndarray:
    """a, b side by side 10 apart; c above and d below them, `gap` apart."""
    return np.array([[30.0, 10.0], [40.0, 10.0], [35.0, 10 + gap / 2], [35.0, 10 - gap / 2]])


def test_constructed_t1_loses_one_pair_and_gains_one():
    before = lattice.periodic_delaunay_pairs(t1_quadrilateral(14.0), LX)
    after = lattice.periodic_delaunay_pairs(t1_quadrilateral(8.0), LX)
    lost, gained = lattice.t1_events(before, after)
    np.testing.assert_array_equal(lost, [[0, 1]])
    np.testing.assert_array_equal(gained, [[2, 3]])
    frames = [t1_quadrilateral(14.0), t1_quadrilateral(8.0)]
    assert lattice.t1_event_times(frames, [0.0, 1.0], LX).tolist() == [1.0]


def test_a_flip_counts_once_the_lost_bond_is_ten_percent_longer_than_the_gained():
    # pins DEFAULT_LENGTH_CONTRAST: a doubled contrast passed every test, whose frames jumped
    # from a length ratio of 1.035 to 1.258. The lost bond a–b is 10, the gained c–d the gap:
    # 10/9.5 = 1.053 is not decisive, 10/8.8 = 1.136 is
    frames = [t1_quadrilateral(gap) for gap in (14.0, 9.5, 8.8)]
    assert lattice.t1_event_times(frames, [0.0, 1.0, 2.0], LX).tolist() == [2.0]
    assert lattice.t1_event_times(frames, [0.0, 1.0, 2.0], LX, length_contrast=0.2).tolist() == []


def test_t1_counting_ignores_flickering_at_the_square():
    # every lane interface slides one spacing, crossing one square (s = a/2) where its five
    # cells flip; near the square the Delaunay choice flickers back and forth
    fractions = [0.0, 0.45, 0.49, 0.51, 0.49, 0.51, 0.53, 0.7, 0.9, 1.0]
    frames = [lanes(fraction * SPACING) for fraction in fractions]
    times = np.arange(len(frames), dtype=float)

    event_times = lattice.t1_event_times(frames, times, LX)

    assert len(event_times) == (LANES - 1) * PER_LANE
    # counted once the lost diagonal is 10 % longer than the gained one: at s = 0.7 a
    assert (event_times == fractions.index(0.7)).all()
    # without the hysteresis every flicker would count
    pairs = [lattice.periodic_delaunay_pairs(centroids, LX) for centroids in frames]
    flips = sum(len(lattice.t1_events(*step)[0]) for step in zip(pairs[:-1], pairs[1:]))
    assert flips > len(event_times)


def test_t1_that_reverts_before_completing_is_not_counted():
    fractions = [0.0, 0.51, 0.45, 0.0]
    frames = [lanes(fraction * SPACING) for fraction in fractions]
    assert len(lattice.t1_event_times(frames, range(len(frames)), LX)) == 0


def test_bumps_in_a_wall_row_exchange_no_neighbours_and_count_no_t1():
    # a 5 × 6 hexagonal lattice whose bottom row wobbles by 0.6 across and 1.5 along: the
    # hull's skip-one bonds between wall particles flipped, (1, 3) lost and (0, 2) gained,
    # and counted as a T1
    a = 14.0
    rows = np.array([((i + 0.5 * (j % 2)) * a, 6.0 + j * a * np.sqrt(3) / 2) for j in range(6) for i in range(5)])
    before, after = rows.copy(), rows.copy()
    before[[2, 4], 1] += 0.6
    after[[1, 4], 1] += 0.6
    after[0, 0] += 1.5
    after[2, 0] -= 1.5
    lost, gained = lattice.t1_events(lattice.periodic_delaunay_pairs(before, 5 * a),
                                     lattice.periodic_delaunay_pairs(after, 5 * a))
    assert len(lost) and len(gained)  # the triangulation did change
    assert len(lattice.t1_event_times([before, after], [0.0, 1.0], 5 * a)) == 0


def test_a_particle_without_a_centroid_has_no_neighbours_and_the_others_keep_theirs():
    # a vanished particle's centroid is NaN: the rest triangulate as if it were not there
    centroids = lanes()
    gone = centroids.copy()
    gone[7] = np.nan
    kept = np.delete(np.arange(len(centroids)), 7)
    expected = kept[lattice.periodic_delaunay_pairs(centroids[kept], LX)]
    assert np.array_equal(lattice.periodic_delaunay_pairs(gone, LX), expected)
    order = lattice.frame_order(gone, np.zeros(len(gone)), LX)
    assert np.isnan(order["psi6_abs"][7]) and np.isnan(order["psi2_abs"][7])
    assert np.isfinite(order["Psi6"]) and order["Psi2"] == pytest.approx(1.0)
    counter = lattice.T1Counter(centroids, LX)
    assert counter.update(gone) == 0  # losing its bonds is no neighbour exchange


def test_order_parameters_leave_out_sliver_sides_along_a_wall():
    # the hull's edge from particle 1 to 3 over particle 2, set 0.3 inward, was a neighbour
    # bond: ψ2 of particle 1 counted particle 3's crossed axis. In a row level to 1e-7 such
    # an edge came and went with the order of the points given to the triangulation
    centroids = np.array([(14.0 * j + 7.0 * (k % 2) + 3.5, 6.0 + 12.0 * k) for k in range(4) for j in range(5)])
    centroids[2, 1] += 0.3
    every = {tuple(p) for p in lattice.periodic_delaunay_pairs(centroids, LX)}
    order = {tuple(p) for p in lattice.periodic_delaunay_pairs(centroids, LX, sliver_sides=False)}
    assert every - order == {(1, 3)} and order < every
    orientation = np.zeros(len(centroids))
    orientation[3] = np.pi / 2
    psi2 = lattice.frame_order(centroids, orientation, LX)["psi2_abs"]
    assert psi2[1] == 1.0  # its neighbours 0, 2 and two above, all aligned; with 3 it was 3/5
