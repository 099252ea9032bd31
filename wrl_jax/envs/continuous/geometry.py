"""Exact geometry of the continuous warehouse: the robot disc against shelves, walls and obstacles,
and the lidar as a grid traversal.

The lidar walks each ray through the grid cell by cell (Amanatides and Woo's traversal, "DDA"): a
fixed ``H + W`` iterations under ``jit``, every ray at once, so a ray costs ``H + W`` table lookups
and its distance is the exact parameter at which it enters the first shelf square (or leaves the
map), not a marched approximation. Squares are closed: where a ray crosses a grid corner exactly,
the three cells that meet there are all tested, and a ray running along a grid line tests the
cells on both sides of it. Obstacles are discs, met by the analytic
ray-circle intersection. Every quantity is float32, one rounding per written operation, in the
order CONTINUOUS_SPEC.md writes it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

TWO_PI = np.float32(2.0 * np.pi)
PI = np.float32(np.pi)


def wrap(angle: jax.Array) -> jax.Array:
    """``t - 2 pi floor((t + pi) / (2 pi))``: an angle in ``[-pi, pi)``."""
    return angle - TWO_PI * jnp.floor((angle + PI) / TWO_PI)


def norm(u: jax.Array) -> jax.Array:
    """``sqrt(ux * ux + uy * uy)`` over the last axis (the contract's written form)."""
    return jnp.sqrt(u[..., 0] * u[..., 0] + u[..., 1] * u[..., 1])


def hits_shelf(q: jax.Array, radius: jax.Array, shelves: jax.Array) -> jax.Array:
    """Whether the disc at ``q`` overlaps a shelf square (strictly: touching is allowed).

    A square the disc overlaps holds a point within ``radius < 1`` of ``q``, so only the 3 x 3 cells
    around ``q``'s own cell can: 9 tests instead of one per shelf.
    """
    height, width = shelves.shape
    col0 = jnp.floor(q[0]).astype(jnp.int32)
    row0 = jnp.floor(q[1]).astype(jnp.int32)
    offsets = jnp.arange(-1, 2, dtype=jnp.int32)
    rows = (row0 + offsets)[:, None]
    cols = (col0 + offsets)[None, :]
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    shelf = inside & shelves[jnp.clip(rows, 0, height - 1), jnp.clip(cols, 0, width - 1)]
    c, r = cols.astype(jnp.float32), rows.astype(jnp.float32)
    dx = jnp.clip(q[0], c, c + 1.0) - q[0]
    dy = jnp.clip(q[1], r, r + 1.0) - q[1]
    return jnp.any(shelf & (dx * dx + dy * dy < radius * radius))


def hits_wall(q: jax.Array, radius: jax.Array, width: int, height: int) -> jax.Array:
    """Whether the disc at ``q`` crosses the map boundary (strict, as written)."""
    return (q[0] - radius < 0) | (q[0] + radius > width) | (q[1] - radius < 0) | (q[1] + radius > height)


def ray_grid(origin: jax.Array, angles: jax.Array, shelves: jax.Array) -> jax.Array:
    """Distance from ``origin`` along each angle ``(L,)`` to the first shelf square or the boundary."""
    height, width = shelves.shape
    x, y = origin[0], origin[1]
    dx, dy = jnp.cos(angles), jnp.sin(angles)
    inf = jnp.float32(jnp.inf)
    col = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, width - 1) + jnp.zeros_like(angles, dtype=jnp.int32)
    row = jnp.clip(jnp.floor(y).astype(jnp.int32), 0, height - 1) + jnp.zeros_like(angles, dtype=jnp.int32)
    step_col = jnp.where(dx > 0, 1, -1).astype(jnp.int32)
    step_row = jnp.where(dy > 0, 1, -1).astype(jnp.int32)
    delta_x = jnp.where(dx != 0, 1.0 / jnp.abs(dx), inf)
    delta_y = jnp.where(dy != 0, 1.0 / jnp.abs(dy), inf)
    next_x = jnp.where(dx > 0, (col.astype(jnp.float32) + 1.0 - x) / dx,
                       jnp.where(dx < 0, (col.astype(jnp.float32) - x) / dx, inf))
    next_y = jnp.where(dy > 0, (row.astype(jnp.float32) + 1.0 - y) / dy,
                       jnp.where(dy < 0, (row.astype(jnp.float32) - y) / dy, inf))
    wall_x = jnp.where(dx > 0, (width - x) / dx, jnp.where(dx < 0, (0.0 - x) / dx, inf))
    wall_y = jnp.where(dy > 0, (height - y) / dy, jnp.where(dy < 0, (0.0 - y) / dy, inf))
    wall = jnp.minimum(wall_x, wall_y)
    # A ray along a grid line touches the closed squares on both sides of it: the row (column) below
    # is tested too, where the traversal alone would only walk the row (column) the origin is in.
    along_row = (dy == 0) & (y == jnp.floor(y))
    along_col = (dx == 0) & (x == jnp.floor(x))

    def shelf_at(r, c):
        inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
        return inside & shelves[jnp.clip(r, 0, height - 1), jnp.clip(c, 0, width - 1)]

    def visit(_, carry):
        row, col, next_x, next_y, hit, done = carry
        t = jnp.minimum(next_x, next_y)
        across_x = next_x <= t  # the ray enters the next column here (both at a corner)
        across_y = next_y <= t
        new_col = col + jnp.where(across_x, step_col, 0)
        new_row = row + jnp.where(across_y, step_row, 0)
        shelf = ((across_x & shelf_at(row, new_col)) | (across_y & shelf_at(new_row, col))
                 | shelf_at(new_row, new_col) | (across_x & along_row & shelf_at(row - 1, new_col))
                 | (across_y & along_col & shelf_at(new_row, col - 1)))
        found = ~done & shelf & (t <= wall)
        hit = jnp.where(found, t, hit)
        left = (new_col < 0) | (new_col >= width) | (new_row < 0) | (new_row >= height)
        done = done | found | left
        next_x = jnp.where(across_x, next_x + delta_x, next_x)
        next_y = jnp.where(across_y, next_y + delta_y, next_y)
        return new_row, new_col, next_x, next_y, hit, done

    start = (row, col, next_x, next_y, jnp.full_like(angles, inf), jnp.zeros_like(angles, dtype=bool))
    hit = jax.lax.fori_loop(0, height + width, visit, start)[4]
    return jnp.minimum(hit, wall)


def ray_discs(origin: jax.Array, angles: jax.Array, centres: jax.Array, radius: jax.Array) -> jax.Array:
    """Distance along each angle ``(L,)`` to the nearest disc of ``centres`` ``(M, 2)`` ahead (inf if none).

    ``|f + t d| = R`` with ``f = origin - centre`` and a unit ``d``: ``t = -b - sqrt(R^2 - h^2)``,
    ``b = f.d`` and ``h = f x d`` the ray's distance from the centre. Written with the cross product,
    the tangency test ``h^2 <= R^2`` does not cancel two large numbers as ``b^2 - (f.f - R^2)`` would.
    A tangent ray hits; a disc behind the origin does not.
    """
    if centres.shape[0] == 0:
        return jnp.full_like(angles, jnp.inf)
    dx, dy = jnp.cos(angles)[:, None], jnp.sin(angles)[:, None]  # (L, 1)
    fx, fy = (origin[0] - centres[:, 0])[None, :], (origin[1] - centres[:, 1])[None, :]  # (1, M)
    b = fx * dx + fy * dy
    h = fx * dy - fy * dx
    disc = radius * radius - h * h
    t = -b - jnp.sqrt(jnp.maximum(disc, 0.0))
    ahead = (disc >= 0) & (t >= 0)
    return jnp.min(jnp.where(ahead, t, jnp.inf), axis=-1)


def ray_angles(theta: jax.Array, num_rays: int) -> jax.Array:
    """The contract's ray directions ``theta + 2 pi k / L``, ``(L,)`` float32, rounded as the contract writes them."""
    return theta + (TWO_PI * jnp.arange(num_rays, dtype=jnp.float32)) / np.float32(num_rays)


def lidar(origin: jax.Array, theta: jax.Array, num_rays: int, shelves: jax.Array, obstacles: jax.Array,
          obstacle_radius: jax.Array) -> jax.Array:
    """Distances ``(L,)`` of the rays leaving ``origin`` at ``theta + 2 pi k / L`` (no range clip, no noise)."""
    angles = ray_angles(theta, num_rays)
    return jnp.minimum(ray_grid(origin, angles, shelves), ray_discs(origin, angles, obstacles, obstacle_radius))
