import math

import numpy as np
import pytest

from safeswitch.sim.collision import rectangle_separation, rectangles_overlap

L, W = 4.0, 2.0


def overlap(ca, ya, cb, yb):
    return bool(rectangles_overlap(np.array(ca, float), ya, L, W, np.array(cb, float), yb, L, W))


@pytest.mark.parametrize(
    ("cb", "yb", "expected"),
    [
        ((4.0, 0.0), 0.0, True),  # nose to tail, touching
        ((4.0001, 0.0), 0.0, False),  # just apart
        ((3.0, 1.0), 0.0, True),  # overlapping
        ((0.0, 2.0), 0.0, True),  # side by side, touching
        ((0.0, 2.01), 0.0, False),
        ((0.0, 2.5), math.pi / 2, True),  # a T: b's end pokes into a's side
        ((0.0, 3.01), math.pi / 2, False),
        # Rotated by 45°: its corner reaches (2 + 1)·cos 45° ≈ 2.12 m from its centre along x.
        ((2.0 + 2.0, 0.0), math.pi / 4, True),
        ((2.0 + 2.2, 0.0), math.pi / 4, False),
    ],
)
def test_hand_placed_pairs(cb, yb, expected):
    assert overlap((0.0, 0.0), 0.0, cb, yb) is expected
    assert overlap(cb, yb, (0.0, 0.0), 0.0) is expected  # symmetric


def test_separation_is_the_gap_for_aligned_boxes():
    gap = rectangle_separation(np.array([0.0, 0.0]), 0.0, L, W, np.array([7.5, 0.0]), 0.0, L, W)
    assert gap == pytest.approx(3.5)
    depth = rectangle_separation(np.array([0.0, 0.0]), 0.0, L, W, np.array([3.0, 0.0]), 0.0, L, W)
    assert depth == pytest.approx(-1.0)


def test_crossing_at_right_angles_in_the_middle_overlaps_even_with_no_corner_inside():
    # Two long thin boxes forming a plus sign: no corner of either lies in the other.
    assert bool(
        rectangles_overlap(np.zeros(2), 0.0, 10.0, 1.0, np.zeros(2), math.pi / 2, 10.0, 1.0)
    )


def test_batched_equals_one_by_one():
    rng = np.random.default_rng(3)
    ca, cb = rng.uniform(-5, 5, (500, 2)), rng.uniform(-5, 5, (500, 2))
    ya, yb = rng.uniform(-3, 3, 500), rng.uniform(-3, 3, 500)
    batched = rectangles_overlap(ca, ya, L, W, cb, yb, L, W)
    single = [overlap(ca[i], ya[i], cb[i], yb[i]) for i in range(500)]
    np.testing.assert_array_equal(batched, single)
    assert 0 < batched.sum() < 500
