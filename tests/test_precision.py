"""numerics.precision: the single-precision steps of "mixed" against double."""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import small_system
from test_unstructured import PARAMS, discs, straight

from femphase.config import Numerics
from femphase.domains.grid.advection import row_phases, shift_rows
from femphase.domains.grid.domain import GridDomain, tensor_basis
from femphase.domains.grid.lattice import channel_grid
from femphase.domains.grid.windows import Window
from femphase.domains.mesh.domain import MeshDomain
from femphase.domains.mesh.generation import structured_channel
from femphase.errors import SceneError
from femphase.flows import linear_shear, poiseuille
from femphase.model.parameters import ModelParameters
from femphase.timestepping.stepper import Stepper


def test_the_tensor_solve_of_a_float32_right_hand_side_rounds_like_single_precision():
    grid = channel_grid(30, 19, 1.0)
    domain, params = GridDomain(grid), ModelParameters()
    window = Window(2, 12, 25, 16)  # wraps around the periodic seam
    stepper = Stepper(domain, params, Numerics(scheme="euler"), 0.7)
    a, b = 1 / 0.7 + params.mobility * stepper.scheme.stabilisation, params.diffusivity
    nodes = domain.window_dofs(window)
    block = stepper.system(1 / 0.7, stepper.scheme.stabilisation)[0][nodes][:, nodes]
    basis = tensor_basis(block, window, grid, a, b)
    rhs = np.asfortranarray(np.random.default_rng(3).random((nodes.size, 5)))
    solver = basis.solver(a, b)
    double, single = solver.solve(rhs), solver.solve(rhs.astype(np.float32))  # the stepper's working copy
    assert double.dtype == np.float64 and single.dtype == np.float32 and single.shape == rhs.shape
    error = np.abs(single - double).max() / np.abs(double).max()
    assert 1e-12 < error < 1e-5  # single precision's rounding, not double's, and not worse


def test_the_row_shift_of_float32_fields_rounds_like_single_precision():
    rng = np.random.default_rng(4)
    fields, shifts = rng.random((3, 6, 24)), rng.uniform(-0.5, 0.5, (3, 6))
    double, working = shift_rows(fields, shifts), fields.astype(np.float32)
    for single in (shift_rows(working, shifts), shift_rows(working, None, row_phases(shifts, 24, True))):
        assert single.dtype == np.float32
        assert 1e-12 < np.abs(single - double).max() < 1e-5


def test_mixed_precision_follows_double_under_flow():
    runs = {}
    for precision in ("mixed", "double"):
        domain, state = small_system([[13.0, 19.0], [26.0, 22.0]])
        stepper = Stepper(domain, ModelParameters(), Numerics(precision=precision), 2.0, linear_shear(1.0, 40.0),
                          state.radii)
        assert stepper.single_precision == (precision == "mixed")
        for _ in range(10):
            stepper.step(state)
        runs[precision] = state.global_fields()
    difference = np.abs(runs["mixed"] - runs["double"]).max()
    # single-precision rounding, damped by the relaxation: far below the default scheme's
    # time error (~1e-2 in φ) and not zero (the single path ran); the state stays double
    assert 1e-12 < difference < 2e-5  # 2.0e-6 when written
    assert all(field.dtype == np.float64 for field in state.fields)


def test_single_precision_only_where_it_applies():
    shear = linear_shear(1.0, 40.0)
    domain, state = small_system([[20.0, 20.0]])
    for scheme, flow, single in (("adaptive", shear, True), ("euler", shear, True), ("adaptive", None, False),
                                 ("fd-heun", shear, False)):  # the FD reference stays double
        stepper = Stepper(domain, ModelParameters(), Numerics(scheme=scheme), 0.1, flow, state.radii)
        assert stepper.single_precision == single, scheme
    mesh = MeshDomain.from_mesh(*structured_channel(40.0, 40.0, 1.0))
    # batched CG solves and explicit advection (the meshes' default) have single-precision
    # paths; per-box LU and Padé solves are double only
    assert Stepper(mesh, ModelParameters(), Numerics(), 1.0, shear, state.radii).single_precision
    for solver in ("direct", "amg"):
        assert not Stepper(mesh, ModelParameters(), Numerics(solver=solver), 1.0, shear,
                           state.radii).single_precision


def test_mixed_precision_on_a_mesh_follows_double_under_flow(monkeypatch):
    from femphase.fem import kernels

    products = []
    original = sp.csr_matrix.__matmul__

    def counted(matrix, vector):
        products.append((matrix.dtype, vector.dtype))
        return original(matrix, vector)

    cg_pass, advection_pass, start_pass = (kernels.window_conjugate_gradient, kernels.taylor_galerkin,
                                           kernels.residual_start)

    def counted_start(*args):  # the CG's starting residual: its matrix's entries and the guess
        products.append((args[2].dtype, args[5].dtype))
        return start_pass(*args)

    def counted_cg(*args):  # the CG's compiled pass: its matrix's entries and its solution
        products.append((args[2].dtype, args[5].dtype))
        return cg_pass(*args)

    def counted_advection(*args):  # the advection's: its two matrices' entries, and φ
        products.extend([(args[2].dtype, args[5].dtype), (args[3].dtype, args[5].dtype)])
        return advection_pass(*args)

    runs = {}
    for precision in ("mixed", "double"):
        domain = straight(40.0, 40.0)
        state = discs(domain, [[12.0, 14.0], [27.0, 26.0]])
        stepper = Stepper(domain, PARAMS, Numerics(precision=precision), 10.0, poiseuille(0.5, 40.0), state.radii)
        assert stepper.single_precision == (precision == "mixed")
        stepper.step(state)  # the first call estimates the advection's frequency, in double
        products.clear()
        monkeypatch.setattr(sp.csr_matrix, "__matmul__", counted)
        monkeypatch.setattr(kernels, "window_conjugate_gradient", counted_cg)
        monkeypatch.setattr(kernels, "taylor_galerkin", counted_advection)
        monkeypatch.setattr(kernels, "residual_start", counted_start)
        for _ in range(4):
            stepper.step(state)
        monkeypatch.undo()
        kinds = {np.dtype(np.float32 if precision == "mixed" else np.float64)}
        # every sparse product of the solves and the advection in the step's precision: a
        # float64 operand would promote it to double
        assert products and {np.dtype(a) for a, b in products} == kinds == {np.dtype(b) for a, b in products}
        runs[precision] = state.global_fields()
        assert all(field.dtype == np.float64 for field in state.fields)  # the state stays double
    difference = np.abs(runs["mixed"] - runs["double"]).max()
    assert 1e-9 < difference < 2e-5  # 7.5e-7 when written


def test_an_unknown_precision_is_refused_by_name():
    with pytest.raises(SceneError, match=r"numerics\.precision.*single.*mixed.*double"):
        Numerics(precision="single")


def test_tight_adaptive_tolerances_step_in_double_under_mixed_precision():
    # below SINGLE_PRECISION_TOLERANCE single precision's rounding would set the error
    domain, state = small_system([[13.0, 19.0]])
    single = {}
    for tolerance in (1e-3, Numerics.SINGLE_PRECISION_TOLERANCE, 1e-5):
        numerics = Numerics(scheme="adaptive", tolerance_t=tolerance)
        single[tolerance] = Stepper(domain, ModelParameters(), numerics, 2.0, linear_shear(1.0, 40.0),
                                    state.radii).single_precision
    assert single == {1e-3: True, Numerics.SINGLE_PRECISION_TOLERANCE: True, 1e-5: False}
    assert not Numerics(scheme="adaptive", tolerance_t=1e-5, precision="double").single_precision_allowed("adaptive")
    assert Numerics(scheme="sav2", tolerance_t=1e-5).single_precision_allowed("sav2")  # fixed dt: the user's choice
    # the scheme the stepper runs decides, not the scene's (a method override)
    assert Numerics(scheme="adaptive", tolerance_t=1e-5).single_precision_allowed("sav2")
