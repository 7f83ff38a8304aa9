"""All windows solved at once (femphase.fem.blocks): the block-diagonal matrix is the windows'
principal submatrices, the Krylov solves reach their tolerance, and a mesh relaxation with
them agrees with per-window LU to within what the tolerance allows."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from test_unstructured import PARAMS, discs, straight

from femphase.config import Numerics
from femphase.domains.base import window_block
from femphase.fem.blocks import BlockPattern, KrylovError, aligned_data, conjugate_gradient
from femphase.timestepping.stepper import Stepper


@pytest.fixture(scope="module")
def sheared():
    """Two discs on a 40 × 40 Delaunay channel, their layout and a Poiseuille flow."""
    domain = straight(40.0, 40.0)
    state = discs(domain, [[12.0, 14.0], [27.0, 26.0]])
    layout, phi = state.flat()
    return domain, state, layout, phi


def reference_blocks(matrix, domain, layout):
    """scipy's block_diag of every window's principal submatrix, window by window."""
    blocks = []
    for group, (key, members, start, stop, size) in enumerate(layout.groups):
        block = window_block(matrix, domain.window_dofs(layout.representative(group)))
        blocks += [block] * members.size
    return sp.block_diag(blocks, format="csr")


@pytest.mark.parametrize("order", ["ascending", "shuffled"])
def test_a_windows_block_is_the_principal_submatrix_in_canonical_order(sheared, order):
    """Entry (p, q) of a window's block is the pattern's (dofs[p], dofs[q]), each row's
    columns ascending, whatever order the window numbers its dofs in."""
    domain, _, layout, _ = sheared
    pattern = domain.block_pattern
    dofs = domain.window_dofs(layout.representative(0)).copy()
    if order == "shuffled":
        np.random.default_rng(3).shuffle(dofs)
    other = domain.window_dofs(layout.representative(1))  # a second window after it
    block = BlockPattern(pattern, np.concatenate([dofs, other]), np.array([0, dofs.size, dofs.size + other.size]))
    rebuilt = sp.csr_matrix((np.ones(block.indices.size), block.indices, block.indptr), shape=block.shape)
    expected = sp.block_diag([pattern[dofs][:, dofs], pattern[other][:, other]]).toarray()
    assert np.array_equal(rebuilt.toarray(), expected)
    assert all(np.all(np.diff(block.indices[a:b]) > 0) for a, b in zip(block.indptr[:-1], block.indptr[1:]))
    # source: where each entry sits among the full pattern's stored entries
    node_index = np.concatenate([dofs, other])
    rows = np.repeat(np.arange(node_index.size), np.diff(block.indptr))
    assert np.all((pattern.indptr[node_index[rows]] <= block.source)
                  & (block.source < pattern.indptr[node_index[rows] + 1]))
    assert np.array_equal(pattern.indices[block.source], node_index[block.indices])


def test_the_block_diagonal_matrix_holds_every_windows_principal_submatrix(sheared):
    domain, _, layout, _ = sheared
    for matrix in (domain.operators.stiffness, domain.operators.mass):
        ours = domain.window_blocks(layout).block(domain.aligned(matrix))
        reference = reference_blocks(matrix, domain, layout)
        assert ours.shape == reference.shape == (layout.offsets[-1],) * 2
        assert abs(ours - reference).max() == 0
        assert ours.has_sorted_indices


def test_a_matrix_outside_the_pattern_is_refused(sheared):
    domain = sheared[0]
    n = domain.n_dofs
    far = sp.csr_matrix(([1.0], ([0], [n // 2])), shape=(n, n))
    if domain.block_pattern[0, n // 2] == 0:
        with pytest.raises(ValueError, match="outside the block pattern"):
            aligned_data(far, domain.block_pattern)


@pytest.mark.parametrize("tolerance", [1e-4, 1e-8, 1e-12])
def test_cg_reaches_its_tolerance_on_the_window_systems(sheared, tolerance):
    domain, _, layout, phi = sheared
    stiffness = domain.window_operator(layout, "stiffness")
    matrix = (sp.diags(layout.mass / 3.3) + 0.12 * stiffness).tocsr()  # a substep of 3.3
    rhs = layout.mass * phi
    exact = spla.spsolve(matrix.tocsc(), rhs)
    solution, iterations, _ = conjugate_gradient(matrix, layout.offsets, 1.0 / matrix.diagonal(), rhs,
                                                 np.zeros_like(rhs), tolerance)
    assert iterations.shape == (2,) and 0 < iterations.min() and iterations.max() < 60
    # the stopping rule bounds the preconditioned residual; the error is that times κ (a few)
    assert np.abs(solution - exact).max() <= 10 * tolerance * np.abs(rhs / matrix.diagonal()).max()
    assert np.abs(solution - exact).max() > 1e-3 * tolerance * np.abs(exact).max() or tolerance == 1e-12


def test_cg_moves_a_field_whose_change_is_below_its_tolerance(sheared):
    # a small substep's system: the change of the field, ∝ dt, fell inside the goal
    # tolerance × max|D⁻¹ rhs|, ∝ 1, so CG returned its start and the relaxation stood still
    # (a mesh run in an oscillating shear at phase dt 0.5 took substeps of 0.005, 21 % off)
    from femphase.fem.blocks import RESIDUAL_REDUCTION

    domain, _, layout, phi = sheared
    stiffness = domain.window_operator(layout, "stiffness")
    matrix = (sp.diags(layout.mass / 0.005) + 0.12 * stiffness).tocsr()
    rhs = layout.mass * phi / 0.005
    exact = spla.spsolve(matrix.tocsc(), rhs)
    change = np.abs(exact - phi).max()
    assert change < 1e-3 * np.abs(rhs / matrix.diagonal()).max()  # the case: inside the goal at 1e-3
    solution, iterations, _ = conjugate_gradient(matrix, layout.offsets, 1.0 / matrix.diagonal(), rhs, phi, 1e-3)
    assert iterations.min() >= 1
    assert np.abs(solution - exact).max() <= 2 * RESIDUAL_REDUCTION * change


def test_cg_with_a_zero_right_hand_side_returns_near_zero():
    # the goal was tolerance × max|D⁻¹ rhs| floored at the smallest double: from a non-zero
    # guess CG iterated into underflow and divided by zero
    n = 200
    chain = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tolil()
    chain[0, -1] = chain[-1, 0] = -1
    matrix = (sp.identity(n) + 0.12 * chain.tocsr()).tocsr()
    guess = np.full(n, 1e-3)
    whole = [0, n]  # one block: any matrix
    solution, iterations, _ = conjugate_gradient(matrix, whole, 1.0 / matrix.diagonal(), np.zeros(n), guess, 1e-3)
    assert 1 <= iterations[0] <= 3 and np.abs(solution).max() <= 1e-4
    assert conjugate_gradient(matrix, whole, 1.0 / matrix.diagonal(), np.zeros(n), np.zeros(n), 1e-3)[1][0] == 0


def test_a_krylov_solve_that_cannot_converge_says_so(sheared):
    domain, _, layout, phi = sheared
    stiffness = domain.window_operator(layout, "stiffness")
    with pytest.raises(KrylovError, match="did not reach"):
        conjugate_gradient(stiffness, layout.offsets, 1.0 / (stiffness.diagonal() + 1e-300), layout.mass * phi,
                           np.zeros_like(phi), 1e-14, maxiter=3)


def relaxing_run(numerics: Numerics, steps: int = 6):
    """Two discs of R/2 relaxing on a 40 × 40 Delaunay channel (no flow: the advection is
    per solver kind, :meth:`MeshDomain.advection`, and compared in test_mesh_advection.py)."""
    domain = straight(40.0, 40.0)
    state = discs(domain, [[12.0, 14.0], [27.0, 26.0]], initial_radius=4.0,
                  mesh_windows="boxes" if numerics.solver == "direct" else numerics.mesh_windows)
    step = Stepper(domain, PARAMS, numerics, 3.0, None, state.radii)
    for _ in range(steps):
        step.step(state)
    return state, step


def test_batched_solves_agree_with_per_window_lu_within_their_tolerance(monkeypatch):
    # on the same windows, boxes (per-window solvers serve boxes only)
    direct, _ = relaxing_run(Numerics(solver="direct"))
    differences = {}
    for fraction in (1e-4, 1e-6, 1e-8):
        monkeypatch.setattr(Numerics, "KRYLOV_FRACTION", fraction)
        monkeypatch.setattr(Numerics, "PREDICTOR_KRYLOV_FRACTION", fraction)
        batched, step = relaxing_run(Numerics(mesh_windows="boxes"))
        assert step.batched and not step._solvers  # nothing kept per window
        differences[fraction] = np.abs(batched.flat()[1] - direct.flat()[1]).max()
    # the difference follows the Krylov tolerance (fraction × tolerance_t 0.1), far below it
    assert differences[1e-8] < differences[1e-6] < differences[1e-4] < 1e-3
    assert differences[1e-8] < 1e-7


def test_the_predictors_looser_solve_saves_iterations_and_moves_the_step_far_less_than_its_tolerance(
        monkeypatch):
    """The predictor's solve stops at PREDICTOR_KRYLOV_FRACTION of the substep's tolerance
    (Numerics.predictor_krylov_tolerance): fewer CG iterations than at the other solves'
    tolerance, and fields that differ from those by less than that looser tolerance."""
    numerics = Numerics()
    still = numerics.substep_tolerance(True)
    assert numerics.predictor_krylov_tolerance(True) == pytest.approx(Numerics.PREDICTOR_KRYLOV_FRACTION * still)
    assert numerics.predictor_krylov_tolerance(True) > numerics.krylov_tolerance(True)
    assert Numerics(scheme="sav2").predictor_krylov_tolerance(False) == Numerics(scheme="sav2").tolerance
    looser = numerics.predictor_krylov_tolerance(True)
    loose, loose_step = relaxing_run(numerics)
    monkeypatch.setattr(Numerics, "PREDICTOR_KRYLOV_FRACTION", Numerics.KRYLOV_FRACTION)
    tight, tight_step = relaxing_run(Numerics())
    assert loose_step.krylov_iterations < tight_step.krylov_iterations
    difference = np.abs(loose.flat()[1] - tight.flat()[1]).max()
    assert 0.0 < difference < looser


def test_the_grid_can_batch_its_solves_too():
    from helpers import small_system

    runs = []
    for numerics in (Numerics(scheme="sav2"), Numerics(scheme="sav2", solver="batched")):
        disc, state = small_system([[20, 20]], length=40, width=40, initial_radius=4.0)
        step = Stepper(disc, PARAMS, numerics, 1.0, None, state.radii)
        assert step.batched == (numerics.solver == "batched")
        for _ in range(5):
            step.step(state)
        runs.append(state.flat()[1])
    assert np.abs(runs[0] - runs[1]).max() < 1e-8


def test_a_batched_solve_starts_from_its_guess():
    domain = straight(40.0, 40.0)
    state = discs(domain, [[12.0, 14.0]], initial_radius=4.0)
    layout, phi = state.flat()
    step = Stepper(domain, PARAMS, Numerics(), 3.0, None, state.radii)
    nodal = np.sin(np.arange(phi.size))
    solution = step.solve(nodal, phi, layout, 1.0 / 3.0, 0.0)
    used = step.krylov_iterations
    again = step.solve(nodal, phi, layout, 1.0 / 3.0, 0.0, guess=solution)
    # started at the solution: a few iterations reduce its residual tenfold (RESIDUAL_REDUCTION),
    # against ten from the field before, and the field stays within the tolerance's reach
    assert 0 < step.krylov_iterations - used <= used // 3
    assert np.abs(again - solution).max() < 1e-3 * np.abs(solution).max()


def test_energies_on_meshes_use_the_layouts_block_diagonal_stiffness_within_the_budget():
    # every box is its own window key on a mesh: per-key blocks were rebuilt for almost every
    # layout; the layout's block-diagonal K (the window solves') gives the same products
    domain = straight(40.0, 40.0)
    domain.caches.limit = 2 * 2**20
    for shift in range(6):  # boxes moved along x: new window keys each time
        moved = discs(domain, [[12.0 + shift, 14.0], [27.0 + shift, 26.0]])
        layout, phi = moved.flat()
        product = domain.stiffness_apply(layout)(phi)
        expected = np.concatenate([window_block(domain.operators.stiffness, domain.window_dofs(w)) @ phi[start:stop]
                                   for w, start, stop in zip([layout.windows[i] for i in layout.order],
                                                             layout.offsets[:-1], layout.offsets[1:])])
        np.testing.assert_array_equal(product, expected)
        assert len(domain._stiffness_blocks) == 0 and domain.caches.used <= domain.caches.limit


def test_a_new_layout_drops_every_block_kept_for_the_ones_before():
    # the window solves keep a system per substep size: kept under names no later layout
    # asks for, they stayed until the budget dropped them (100 MB more on a mesh run)
    domain = straight(40.0, 40.0)
    step = Stepper(domain, PARAMS, Numerics(solver="batched"), 1.0)
    for shift in range(3):
        layout, phi = discs(domain, [[12.0 + shift, 14.0], [27.0 + shift, 26.0]]).flat()
        for dt in (1.0 + shift, 2.0 + shift):  # substep sizes differ from layout to layout
            step.solve(phi, phi, layout, 1.0 / dt, 0.0)
        kept = domain._layout_blocks.items()  # the map, two systems and their diagonals
        assert len(kept) == 5 and all(entry[0] is layout for _, entry in kept)


def test_cg_started_with_the_product_of_its_guess_spares_that_product(sheared, monkeypatch):
    from femphase.fem import kernels

    domain, _, layout, phi = sheared
    system = (domain.window_operator(layout, "stiffness") + sp.diags(np.full(phi.size, 2.0))).tocsr()
    rhs, guess = np.cos(np.arange(phi.size)), 0.5 * phi
    multiplied = []
    start = kernels.residual_start
    monkeypatch.setattr(kernels, "residual_start", lambda *args: multiplied.append(args[-1]) or start(*args))

    plain = conjugate_gradient(system, layout.offsets, 1.0 / system.diagonal(), rhs, guess, 1e-8)
    spared = conjugate_gradient(system, layout.offsets, 1.0 / system.diagonal(), rhs, guess, 1e-8,
                                guess_product=system @ guess)
    assert multiplied == [True, False]  # the start's product, then none
    # the same start to the rounding of the products' sums, so the same iterations
    np.testing.assert_allclose(spared[0], plain[0], rtol=0, atol=1e-12)
    assert np.array_equal(plain[1], spared[1])
    assert np.allclose(plain[2], rhs - system @ plain[0], atol=1e-10)  # the final residual
    # and the product given is the one used: a wrong one gives another solution
    wrong = conjugate_gradient(system, layout.offsets, 1.0 / system.diagonal(), rhs, guess, 1e-8,
                               guess_product=1.5 * (system @ guess))
    assert np.abs(wrong[0] - plain[0]).max() > 1e-3


def test_each_window_runs_its_own_cg_to_the_common_goal(sheared):
    """Window 0 starts solved and takes no iteration while window 1 iterates; each ends
    within the goal, one bound for the whole vector, and equal to its own solve alone."""
    from femphase.fem.blocks import RESIDUAL_REDUCTION

    domain, _, layout, phi = sheared
    system = (sp.diags(layout.mass / 3.3) + 0.12 * domain.window_operator(layout, "stiffness")).tocsr()
    inverse = 1.0 / system.diagonal()
    guess = phi.copy()
    rhs = system @ phi
    second = slice(layout.offsets[1], layout.offsets[2])
    rhs[second] += layout.mass[second] * np.sin(np.arange(rhs[second].size))
    solution, iterations, residual = conjugate_gradient(system, layout.offsets, inverse, rhs, guess, 1e-10)
    assert iterations[0] == 0 and iterations[1] > 3
    goal = min(1e-10 * np.abs(inverse * rhs).max(), RESIDUAL_REDUCTION * np.abs(inverse * (rhs - system @ guess)).max())
    assert np.abs(inverse * (rhs - system @ solution)).max() <= 1.01 * goal
    first = slice(layout.offsets[0], layout.offsets[1])
    assert np.array_equal(solution[first], phi[first])
    alone = sp.csr_matrix(system[second][:, second])
    # the same goal for the window alone: its own CG, whatever the other windows do
    tolerance = goal / np.abs(inverse[second] * rhs[second]).max()
    by_itself = conjugate_gradient(alone, [0, alone.shape[0]], inverse[second], rhs[second], guess[second], tolerance)
    assert by_itself[1][0] == iterations[1]
    np.testing.assert_allclose(by_itself[0], solution[second], rtol=0, atol=1e-12)


@pytest.mark.parametrize("scheme, substep", [("adaptive", 10.0 / 3), ("sav2", 10.0)])
def test_the_midpoint_solve_starts_from_the_predictors_residual(monkeypatch, scheme, substep):
    """Under flow the midpoint solve takes A·2φ̄ from the predictor's final residual, its
    stabilisation taken off (none at the adaptive default's substeps, some at sav2's 10),
    instead of a product: the same fields as with the product (within the solves'
    tolerance), where a wrong start would move the solution by itself."""
    from femphase.flows import flow_from_spec
    from femphase.timestepping import stepper as stepper_module

    def run():
        domain = straight(40.0, 40.0)
        state = discs(domain, [[12.0, 14.0], [27.0, 26.0]], initial_radius=6.0)
        step = Stepper(domain, PARAMS, Numerics(scheme=scheme, precision="double"), 10.0,
                       flow_from_spec({"type": "shear", "rate": 0.5}, domain), state.radii)
        assert step.batched and (step.scheme.predictor_stabilisation(substep) > 0.0) == (scheme == "sav2")
        for _ in range(3):
            step.step(state)
        return state.flat()[1]

    spared = run()
    original = stepper_module.conjugate_gradient
    monkeypatch.setattr(stepper_module, "conjugate_gradient",
                        lambda *args, guess_product=None, **kwargs: original(*args, **kwargs))
    multiplied = run()
    assert 0.0 < np.abs(spared - multiplied).max() < 1e-6
