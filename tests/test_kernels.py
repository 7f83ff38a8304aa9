"""The compiled kernels (the channel's window scans, the overlap sums, the Jacobi correction,
the radix sort of a box's dofs) against numpy."""

import numpy as np
import pytest

from femphase.domains.grid.kernels import occupied_boxes, others_squared


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_occupied_boxes_match_numpy(dtype):
    rng = np.random.default_rng(3)
    threshold = dtype(0.01)
    shapes = rng.integers(1, 30, size=(40, 2))
    fields = []
    for k, (ny, nx) in enumerate(shapes):
        phi = np.zeros((ny, nx), dtype=dtype)
        if k % 7:  # every 7th window empty
            r0, c0 = rng.integers(0, ny), rng.integers(0, nx)
            r1, c1 = rng.integers(r0, ny) + 1, rng.integers(c0, nx) + 1
            phi[r0:r1, c0:c1] = rng.uniform(0.0, 0.05, size=(r1 - r0, c1 - c0))  # about half above
        if k % 5 == 0:
            phi.flat[rng.integers(0, phi.size)] = threshold  # equal: not above
        if k % 11 == 3:
            phi.flat[rng.integers(0, phi.size)] = np.nan  # never above, as in numpy
        fields.append(phi.ravel())
    offsets = np.concatenate([[0], np.cumsum([f.size for f in fields])])
    corners = np.stack([np.zeros(len(shapes)), shapes[:, 0], np.zeros(len(shapes)), shapes[:, 1]], axis=1)
    boxes = occupied_boxes(np.concatenate(fields), offsets, corners.astype(np.int64), threshold)
    assert boxes.shape == (len(fields), 4) and boxes.dtype == np.int64
    empty = 0
    for box, field, (ny, nx) in zip(boxes, fields, shapes):
        with np.errstate(invalid="ignore"):
            rows, columns = np.nonzero(field.reshape(ny, nx) > threshold)
        if rows.size == 0:
            assert box.tolist() == [-1, -1, -1, -1]
            empty += 1
        else:
            assert box.tolist() == [rows.min(), rows.max(), columns.min(), columns.max()]
    assert 0 < empty < len(fields)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_others_squared_is_bincount_through_the_dof_table(dtype):
    """The kernel's sums equal np.bincount over every position's dof, bitwise: windows that
    overlap, cross the periodic seam, span the whole width or touch the walls."""
    rng = np.random.default_rng(5)
    lattice_ny, lattice_nx = 30, 24
    corners = [(0, 8, 20, 9), (3, 10, 0, lattice_nx), (22, 8, 17, 7), (10, 12, 5, 11), (12, 6, 8, 16)]
    corners += [(int(iy0), int(ny), int(rng.integers(0, lattice_nx)), int(nx))
                for iy0, ny, nx in zip(rng.integers(0, 20, 20), rng.integers(1, 11, 20), rng.integers(1, lattice_nx, 20))]
    corners = np.array(corners, dtype=np.int64)
    sizes = corners[:, 1] * corners[:, 3]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    squares = rng.uniform(0.0, 1.0, offsets[-1]).astype(dtype)
    dofs = np.concatenate([((iy0 + np.arange(ny))[:, None] * lattice_nx + (ix0 + np.arange(nx)) % lattice_nx).ravel()
                           for iy0, ny, ix0, nx in corners])
    expected = np.bincount(dofs, weights=squares).astype(dtype)[dofs] - squares
    result = others_squared(squares, offsets, corners, lattice_ny, lattice_nx)
    assert result.dtype == dtype and np.array_equal(result, expected)
    from femphase.fem.kernels import others_squared as any_layouts  # a mesh's, by dof table alone

    result = any_layouts(squares, dofs, lattice_ny * lattice_nx)
    assert result.dtype == dtype and np.array_equal(result, expected)
    assert (np.bincount(dofs) > 1).any() and (corners[:, 2] + corners[:, 3] > lattice_nx).any()


def test_a_jacobi_correction_is_numpys_expression_to_the_bit():
    from femphase.fem import kernels as block_kernels

    rng = np.random.default_rng(4)
    z, y, product = (rng.standard_normal(1000) for _ in range(3))
    inverse = rng.uniform(0.5, 2.0, 1000)
    expected = z + (y - product) * inverse
    block_kernels.jacobi_correction(z, y, product, inverse)
    np.testing.assert_array_equal(z, expected)


@pytest.mark.parametrize("passes, digit_bits", [(1, 11), (2, 8), (3, 5)])
def test_the_radix_sort_of_a_boxs_dofs_is_numpys_sort(passes, digit_bits):
    # one pass (meshes below 2¹¹ dofs), two (the examples') and an odd count above one
    from femphase.domains.mesh.kernels import _sort_indices

    rng = np.random.default_rng(passes)
    values = rng.integers(0, 2 ** (passes * digit_bits), 3000)
    values[:40] = values[40:80]  # repeated dofs keep their multiplicity
    expected = np.sort(values)
    scratch, counts = np.empty(values.size + 7, dtype=values.dtype), np.empty(2**digit_bits + 1, dtype=np.int64)
    _sort_indices(values, scratch, counts, passes, digit_bits)
    np.testing.assert_array_equal(values, expected)

