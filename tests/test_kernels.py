"""The compiled window scans (femphase/kernels.py) against numpy on random window fields."""

import numpy as np
import pytest

from femphase.kernels import occupied_boxes


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
    boxes = occupied_boxes(np.concatenate(fields), offsets, shapes, threshold)
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
