import numpy as np
import pytest

from safeswitch.core.arrays import clamp, columns, flat


def test_flat_broadcasts_scalars_and_rows_and_reuses_contiguous_memory():
    shape = (3, 2)
    assert flat(1.5, shape).tolist() == [1.5] * 6
    assert flat(np.array([1.0, 2.0]), shape).tolist() == [1.0, 2.0] * 3
    own = np.arange(6, dtype=np.float64).reshape(shape)
    view = flat(own, shape)
    assert np.shares_memory(view, own)  # no copy for what the compiled loops read as is
    strided = np.arange(12, dtype=np.float64).reshape(3, 4)[:, ::2]
    assert flat(strided, shape).tolist() == [0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
    assert flat(np.array([1, 2]), (2,)).dtype == np.float64


def test_flat_refuses_shapes_that_do_not_broadcast():
    with pytest.raises(ValueError):
        flat(np.ones(3), (2, 2))


def test_clamp_and_columns():
    assert clamp(np.array([-2.0, 0.5, 3.0]), 0.0, 1.0).tolist() == [0.0, 0.5, 1.0]
    out = columns(np.array([1.0, 2.0]), np.array([3.0, 4.0]))
    assert out.tolist() == [[1.0, 3.0], [2.0, 4.0]]
