"""Batched overlap tests between oriented rectangles (separating axis theorem)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from safeswitch.core.arrays import broadcast_flat, jit

FloatArray = NDArray[np.float64]


def rectangle_separation(
    center_a: ArrayLike,
    yaw_a: ArrayLike,
    length_a: ArrayLike,
    width_a: ArrayLike,
    center_b: ArrayLike,
    yaw_b: ArrayLike,
    length_b: ArrayLike,
    width_b: ArrayLike,
) -> FloatArray:
    """Largest gap between two oriented rectangles over the four candidate separating axes.

    For two convex polygons the separating axis theorem says they are disjoint exactly when the
    projections on one of the edge normals are disjoint. The returned value is the largest such
    gap: positive means apart (and is a lower bound on their distance), zero means touching, and
    a negative value is minus the smallest overlap over the four axes (how far they interpenetrate
    along the best axis).

    Args:
        center_a: Centres of the first rectangles, shape ``[..., 2]`` [m].
        yaw_a: Orientation of their long side [rad], shape ``[...]``.
        length_a: Extent along the long side [m].
        width_a: Extent across [m].
        center_b, yaw_b, length_b, width_b: The same for the second rectangles.

    Returns:
        The separation, shape ``[...]`` [m].
    """
    ca, cb = np.asarray(center_a, dtype=np.float64), np.asarray(center_b, dtype=np.float64)
    ya, yb = np.asarray(yaw_a, dtype=np.float64), np.asarray(yaw_b, dtype=np.float64)
    return separation_from_axes(
        cb[..., 0] - ca[..., 0],
        cb[..., 1] - ca[..., 1],
        np.cos(ya),
        np.sin(ya),
        length_a,
        width_a,
        np.cos(yb),
        np.sin(yb),
        length_b,
        width_b,
    )


def separation_from_axes(
    dx: FloatArray,
    dy: FloatArray,
    cos_a: FloatArray,
    sin_a: FloatArray,
    length_a: ArrayLike,
    width_a: ArrayLike,
    cos_b: FloatArray,
    sin_b: FloatArray,
    length_b: ArrayLike,
    width_b: ArrayLike,
) -> FloatArray:
    """:func:`rectangle_separation` from the centre offset ``(dx, dy)`` = b − a [m] and each
    rectangle's heading as a unit vector (no trigonometry: the simulator's hot path)."""
    shape, f = broadcast_flat(
        dx, dy, cos_a, sin_a, length_a, width_a, cos_b, sin_b, length_b, width_b
    )
    out = np.empty(shape)
    _map_separation(
        f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8], f[9], out.reshape(-1)
    )  # fmt: skip
    return out


@jit
def separation(
    dx: float, dy: float, cos_a: float, sin_a: float, length_a: float, width_a: float,
    cos_b: float, sin_b: float, length_b: float, width_b: float,
) -> float:  # fmt: skip
    """:func:`separation_from_axes` for one pair."""
    ha_l, ha_w = 0.5 * length_a, 0.5 * width_a
    hb_l, hb_w = 0.5 * length_b, 0.5 * width_b
    # |cos(ya - yb)| and |sin(ya - yb)| give every cross projection of the half extents.
    c = abs(cos_a * cos_b + sin_a * sin_b)
    s = abs(sin_a * cos_b - cos_a * sin_b)
    gap_a_long = abs(dx * cos_a + dy * sin_a) - ha_l - (hb_l * c + hb_w * s)
    gap_a_short = abs(-dx * sin_a + dy * cos_a) - ha_w - (hb_l * s + hb_w * c)
    gap_b_long = abs(dx * cos_b + dy * sin_b) - hb_l - (ha_l * c + ha_w * s)
    gap_b_short = abs(-dx * sin_b + dy * cos_b) - hb_w - (ha_l * s + ha_w * c)
    return max(max(gap_a_long, gap_a_short), max(gap_b_long, gap_b_short))


@jit
def _map_separation(
    dx: FloatArray, dy: FloatArray, cos_a: FloatArray, sin_a: FloatArray, length_a: FloatArray,
    width_a: FloatArray, cos_b: FloatArray, sin_b: FloatArray, length_b: FloatArray,
    width_b: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    for i in range(out.shape[0]):
        out[i] = separation(
            dx[i], dy[i], cos_a[i], sin_a[i], length_a[i], width_a[i],
            cos_b[i], sin_b[i], length_b[i], width_b[i],
        )  # fmt: skip


def rectangles_overlap(
    center_a: ArrayLike,
    yaw_a: ArrayLike,
    length_a: ArrayLike,
    width_a: ArrayLike,
    center_b: ArrayLike,
    yaw_b: ArrayLike,
    length_b: ArrayLike,
    width_b: ArrayLike,
) -> NDArray[np.bool_]:
    """Whether two oriented rectangles touch or overlap (touching counts: conservative).

    Arguments as in :func:`rectangle_separation`.
    """
    return (
        rectangle_separation(center_a, yaw_a, length_a, width_a, center_b, yaw_b, length_b, width_b)
        <= 0.0
    )
