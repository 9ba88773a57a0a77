import numpy as np
import pytest

from safeswitch.core.arrays import _each1, _each2, _each3, _each4, clamp, columns, each, flat, jit


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


@jit
def _twice(x, k):
    return 2.0 * x + k


@jit
def _square(x, k):
    return x * x + k


def test_each_runs_the_function_it_is_given_and_is_never_served_from_the_disk_cache():
    x = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert each(_twice, 0.5, x).tolist() == [[2.5, 4.5], [6.5, 8.5]]
    assert each(_square, 0.5, x).tolist() == [[1.5, 4.5], [9.5, 16.5]]  # same signature
    # numba keys a cached specialisation on the function argument's object, which another
    # function can take over in a later process: the loops that take a function compile in
    # each process instead (a stale entry once fed a campaign the wrong throttle).
    for loop in (_each1, _each2, _each3, _each4):
        assert type(loop._cache).__name__ == "NullCache"


def test_put_rows_writes_back_what_take_rows_took_nested_and_optional_parts_too():
    from dataclasses import dataclass

    from safeswitch.core.arrays import put_rows, take_rows

    @dataclass
    class Inner:
        b: np.ndarray

    @dataclass
    class Batch:
        a: np.ndarray
        inner: Inner
        optional: Inner | None = None

    batch = Batch(np.arange(5.0), Inner(np.arange(10.0).reshape(5, 2)))
    rows = np.array([3, 1])
    part = take_rows(batch, rows)
    part.a *= -1
    part.inner.b *= -1
    put_rows(batch, rows, part)
    np.testing.assert_array_equal(batch.a, [0, -1, 2, -3, 4])
    np.testing.assert_array_equal(batch.inner.b[[1, 3]], -np.array([[2, 3], [6, 7]]))
    np.testing.assert_array_equal(batch.inner.b[[0, 2, 4]], [[0, 1], [4, 5], [8, 9]])
    assert batch.optional is None
