import numpy as np
import pytest
from skfem import MeshTri

from femphase.domains.mesh.stokes import channel_mesh, poiseuille_profile, solve_stokes
from femphase.fem.periodic import fold_matrix, periodic_dof_map

LX, LY = 7.0, 24.0


def relative_error(flow, pressure_gradient):
    """Max nodal error of (u, v) against Poiseuille, relative to the
    centreline velocity."""
    U = pressure_gradient * LY**2 / (8 * flow.viscosity)
    u, v = flow.velocity_at_nodes()
    exact = poiseuille_profile(flow.mesh.p[1], LY, U)
    return max(np.abs(u - exact).max(), np.abs(v).max()) / U


# periodic.py

def test_structured_map_pairs_right_side_with_left():
    mesh = MeshTri.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 4))
    dof_map = periodic_dof_map(mesh.p, 2.0)
    x, y = mesh.p
    right = np.flatnonzero(x == 2)
    assert np.all(x[dof_map[right]] == 0)
    assert np.array_equal(y[dof_map[right]], y[right])
    others = np.setdiff1d(np.arange(x.size), right)
    assert np.array_equal(dof_map[others], others)


def test_map_is_independent_of_node_order():
    mesh = MeshTri.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 4))
    order = np.random.default_rng(0).permutation(mesh.p.shape[1])
    points = mesh.p[:, order]
    dof_map = periodic_dof_map(points, 2.0)
    moved = dof_map != np.arange(len(dof_map))
    assert moved.sum() == 4
    assert np.allclose(points[0, moved], 2) and np.allclose(
        points[0, dof_map[moved]], 0
    )
    assert np.allclose(points[1, moved], points[1, dof_map[moved]])


def test_map_along_y():
    mesh = MeshTri.init_tensor(np.linspace(0, 1, 3), np.linspace(-1, 2, 4))
    dof_map = periodic_dof_map(mesh.p, 3.0, axis=1)
    top = np.flatnonzero(mesh.p[1] == 2)
    assert np.allclose(mesh.p[:, dof_map[top]], mesh.p[:, top] - [[0], [3]])


def test_mismatched_sides_raise_naming_the_point():
    mesh = MeshTri.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 4))
    points = mesh.p.copy()
    moved = np.flatnonzero((points[0] == 2) & (points[1] > 0) & (points[1] < 1))[0]
    points[1, moved] += 0.01
    with pytest.raises(ValueError, match=r"1 of 4 points on the max side.*"
                       rf"{points[1, moved]:.6g}"):
        periodic_dof_map(points, 2.0)


def test_wrong_period_raises():
    mesh = MeshTri.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 4))
    with pytest.raises(ValueError, match="min side have no periodic partner"):
        periodic_dof_map(mesh.p, 2.5)


def test_fold_matrix_sums_partners_and_unfolds_periodic_values():
    mesh = MeshTri.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 4))
    dof_map = periodic_dof_map(mesh.p, 2.0)
    P, compact = fold_matrix(dof_map)
    assert P.shape == (mesh.p.shape[1], mesh.p.shape[1] - 4)
    assert np.array_equal(P.indices, compact)
    # a periodic function unfolds onto both sides with equal values
    periodic = np.cos(np.pi * mesh.p[0]) + mesh.p[1]
    assert np.allclose(P @ periodic[np.unique(dof_map)], periodic)
    # folding adds the partner's row: each min-side node counts twice
    assert sorted(set(P.T @ np.ones(P.shape[0]))) == [1.0, 2.0]


# stokes.py

@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_pressure_driven_poiseuille_is_exact(jitter):
    mesh = channel_mesh(LX, LY, 4, 8, jitter=jitter, seed=1)
    flow = solve_stokes(mesh, LX, pressure_drop=3.0, viscosity=2.0)
    assert relative_error(flow, 3.0 / LX) < 1e-8
    # the periodic part of the pressure vanishes for plane Poiseuille
    assert np.abs(flow.pressure).max() < 1e-8 * 3.0


def test_flux_driven_flow_has_prescribed_flux():
    mesh = channel_mesh(LX, LY, 4, 8, jitter=0.2, seed=2)
    flow = solve_stokes(mesh, LX, flux=5.0)
    assert flow.flux == pytest.approx(5.0, rel=1e-12)
    # Poiseuille: Q = G Ly³ / (12 η)
    gradient = 12 * 5.0 / LY**3
    assert flow.pressure_drop == pytest.approx(gradient * LX, rel=1e-10)
    assert relative_error(flow, gradient) < 1e-8
    # flux through the section x = 0, Gauss-integrated between its nodes
    side = np.sort(mesh.p[1, mesh.p[0] == 0])[:, None]
    g, w = np.polynomial.legendre.leggauss(3)
    half = np.diff(side, axis=0) / 2
    ys = (side[:-1] + half * (g + 1)).ravel()
    u, _ = flow(np.zeros_like(ys), ys)
    assert ((half * w).ravel() @ u) == pytest.approx(5.0, rel=1e-12)


def test_evaluation_wraps_x_into_the_period():
    flow = solve_stokes(channel_mesh(LX, LY, 4, 8), LX, pressure_drop=1.0)
    y = np.array([1.0, 12.0, 20.0])
    inside = flow(np.full(3, 2.0), y)
    outside = flow(np.full(3, 2.0 + 3 * LX), y)
    assert np.allclose(inside, outside, rtol=0, atol=1e-14)


def test_given_wall_facets_match_detected_ones():
    mesh = channel_mesh(LX, LY, 4, 8, jitter=0.1, seed=3)
    walls = mesh.facets_satisfying(
        lambda x: np.isclose(x[1], 0) | np.isclose(x[1], LY),
        boundaries_only=True,
    )
    given = solve_stokes(mesh, LX, wall_facets=walls, pressure_drop=1.0)
    detected = solve_stokes(mesh, LX, pressure_drop=1.0)
    assert np.allclose(given.velocity, detected.velocity, atol=1e-14)


def test_wavy_channel_flux_is_the_same_through_every_section():
    # a non-trivial periodic flow: top wall y = Ly (1 + 0.3 sin(2πx/Lx))
    mesh = channel_mesh(LX, LY, 16, 24)
    x, y = mesh.p
    mesh = MeshTri(
        np.vstack([x, y * (1 + 0.3 * np.sin(2 * np.pi * x / LX))]), mesh.t
    )
    flow = solve_stokes(mesh, LX, flux=1.0)
    for section in [0.0, LX / 4, LX / 2]:
        height = LY * (1 + 0.3 * np.sin(2 * np.pi * section / LX))
        y, w = np.polynomial.legendre.leggauss(200)
        u, _ = flow(np.full(y.shape, section), (y + 1) / 2 * height)
        assert (w * u).sum() * height / 2 == pytest.approx(1.0, rel=1e-3)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(), "exactly one of pressure_drop and flux"),
        (dict(pressure_drop=1.0, flux=1.0), "flux=1.0"),
        (dict(pressure_drop=1.0, viscosity=0.0), "viscosity must be positive; got 0.0"),
        (dict(flux=float("nan")), "flux=nan"),
    ],
)
def test_bad_driving_or_viscosity_raises(kwargs, message):
    with pytest.raises(ValueError, match=message):
        solve_stokes(channel_mesh(LX, LY, 2, 2), LX, **kwargs)


def test_period_not_matching_mesh_raises():
    with pytest.raises(ValueError, match="period 8.0 does not match .* 7.0"):
        solve_stokes(channel_mesh(LX, LY, 2, 2), 8.0, pressure_drop=1.0)


def test_jitter_out_of_range_raises():
    with pytest.raises(ValueError, match="jitter .* got 0.3"):
        channel_mesh(LX, LY, 2, 2, jitter=0.3)
