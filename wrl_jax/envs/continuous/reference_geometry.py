"""The NumPy reference's geometry (docs/CONTINUOUS_SPEC.md): float32 arithmetic as the contract writes
it, the disc's overlap tests, and the lidar as a slab test against every shelf square, the map and
each obstacle disc: a different method from the JAX grid traversal, on purpose.
"""

from __future__ import annotations

import numpy as np

from wrl_jax.envs.continuous.reference_types import ContinuousLayout, ContinuousParams

F32 = np.float32
PI = F32(np.pi)
TWO_PI = F32(2.0 * np.pi)


def wrap(t: np.float32) -> np.float32:
    """``t - 2pi floor((t + pi) / (2pi))`` in float32, one rounding per operation."""
    t = F32(t)
    return F32(t - F32(TWO_PI * F32(np.floor(F32(F32(t + PI) / TWO_PI)))))


def cos32(t: np.float32) -> np.float32:
    return F32(np.cos(np.float64(t)))


def sin32(t: np.float32) -> np.float32:
    return F32(np.sin(np.float64(t)))


def norm(ux: np.float32, uy: np.float32) -> np.float32:
    """``sqrt(ux*ux + uy*uy)`` in float32."""
    return F32(np.sqrt(F32(F32(ux * ux) + F32(uy * uy))))


def read_action(action) -> tuple[np.ndarray, bool]:
    """Step 1: clip to [-1, 1] (+-inf to +-1), NaN read as 0; returns ``(a, invalid)``."""
    raw = np.asarray(action)
    if raw.shape != (2,):
        raise ValueError(f"action must have shape (2,), got shape {raw.shape}")
    raw = raw.astype(F32)
    nan = np.isnan(raw)
    return np.where(nan, F32(0), np.clip(raw, F32(-1), F32(1))).astype(F32), bool(nan.any())


def collision_flags(q: np.ndarray, layout: ContinuousLayout, params: ContinuousParams,
                    obstacle_pos: np.ndarray) -> tuple[bool, bool, bool]:
    """Step 3's three strict overlap tests of the disc at ``q``: ``(hit_shelf, hit_wall, hit_obstacle)``."""
    qx, qy = F32(q[0]), F32(q[1])
    rr = F32(params.robot_radius)
    rr2 = F32(rr * rr)
    hit_shelf = False
    for row, col in np.argwhere(layout.shelves):
        dx = F32(min(max(qx, F32(col)), F32(col + 1)) - qx)
        dy = F32(min(max(qy, F32(row)), F32(row + 1)) - qy)
        hit_shelf |= bool(F32(F32(dx * dx) + F32(dy * dy)) < rr2)
    hit_wall = bool(F32(qx - rr) < 0 or F32(qx + rr) > F32(layout.width)
                    or F32(qy - rr) < 0 or F32(qy + rr) > F32(layout.height))
    reach = F32(rr + F32(params.obstacle_radius))
    hit_obstacle = any(norm(F32(qx - o[0]), F32(qy - o[1])) < reach for o in obstacle_pos)
    return hit_shelf, hit_wall, bool(hit_obstacle)


def ray_distance(origin, direction, layout: ContinuousLayout, params: ContinuousParams,
                 obstacle_pos: np.ndarray) -> np.float32:
    """Distance along ``origin + t * direction``, ``t >= 0``, to the first closed shelf square,
    the map boundary or obstacle disc (tangent hits), in multiples of ``|direction|``.

    Squares and the map use the slab test (an axis with a zero component spans all t when the
    origin lies in the closed slab). Discs solve ``|f + t d|^2 = r^2`` (``f = origin - o``) as
    ``t = (-b - sqrt(a r^2 - h^2)) / a`` with ``a = d.d``, ``b = f.d`` and ``h = f x d``: the
    cross product keeps the tangency decision exact where ``b^2 - a(f.f - r^2)`` would cancel
    two large numbers. An origin inside or on a disc reads 0 (no reachable state has one).
    """
    ox, oy = F32(origin[0]), F32(origin[1])
    dx, dy = F32(direction[0]), F32(direction[1])
    inf = F32(np.inf)

    def slab(o: np.float32, d: np.float32, lo: np.float32, hi: np.float32) -> tuple:
        if d == 0:
            return (-inf, inf) if lo <= o <= hi else (inf, -inf)
        t1, t2 = F32(F32(lo - o) / d), F32(F32(hi - o) / d)
        return min(t1, t2), max(t1, t2)

    best = inf
    with np.errstate(over="ignore"):
        # Boundary: the origin is inside the map; the ray leaves it at the nearer exit of the two slabs.
        _, exit_x = slab(ox, dx, F32(0), F32(layout.width))
        _, exit_y = slab(oy, dy, F32(0), F32(layout.height))
        best = min(best, exit_x, exit_y)
        for row, col in np.argwhere(layout.shelves):
            ex, xx = slab(ox, dx, F32(col), F32(col + 1))
            ey, xy = slab(oy, dy, F32(row), F32(row + 1))
            enter, leave = max(ex, ey), min(xx, xy)
            if enter <= leave and leave >= 0:
                best = min(best, max(enter, F32(0)))
    r = F32(params.obstacle_radius)
    a = F32(F32(dx * dx) + F32(dy * dy))
    for o in obstacle_pos:
        fx, fy = F32(ox - o[0]), F32(oy - o[1])
        if F32(F32(fx * fx) + F32(fy * fy)) <= F32(r * r):
            return F32(0)
        b = F32(F32(fx * dx) + F32(fy * dy))
        h = F32(F32(fx * dy) - F32(fy * dx))
        disc = F32(F32(a * F32(r * r)) - F32(h * h))
        if disc >= 0:
            t = F32(F32(F32(-b) - F32(np.sqrt(disc))) / a)
            if t >= 0:
                best = min(best, t)
    return F32(best)


def lidar_distances(pos, theta, layout: ContinuousLayout, params: ContinuousParams,
                    obstacle_pos: np.ndarray) -> np.ndarray:
    """Raw distances ``t`` (L,) of the rays from ``pos``: ray k at ``theta + ((2pi * k) / L)``."""
    out = np.empty(params.num_rays, F32)
    for k in range(params.num_rays):
        angle = F32(F32(theta) + F32(F32(TWO_PI * F32(k)) / F32(params.num_rays)))
        out[k] = ray_distance(pos, (cos32(angle), sin32(angle)), layout, params, obstacle_pos)
    return out


def lidar_values(t: np.ndarray, params: ContinuousParams, noise=None, drop=None) -> np.ndarray:
    """``min(t, R) / R``; with draws, ``clip(t + noise, 0, R)`` then a dropped ray reads ``R``
    (zero noise and no drop give the plain value, since ``t >= 0``)."""
    big = F32(params.lidar_range)
    noise = np.zeros_like(t) if noise is None else np.asarray(noise, F32)
    drop = np.zeros(t.shape, bool) if drop is None else np.asarray(drop, bool)
    read = np.clip((t + noise).astype(F32), F32(0), big).astype(F32)
    read = np.where(drop, big, read).astype(F32)
    return (read / big).astype(F32)
