"""Pictures of procedural warehouses: a layout as a small image, an episode as frames (for the notebooks).

:func:`layout_image` draws one cell per pixel block in the warehouse palette
(:data:`wrl_jax.envs.warehouse.render.COLORS`, plus a darker grey for the
off-grid padding around a floor smaller than the padded shape).
:func:`render_frame` draws a :class:`~wrl_jax.envs.procedural.types.ProceduralState`
with the warehouse's :func:`~wrl_jax.envs.warehouse.render.render_frame` (the
same robot, item, goal and timer), and :func:`record_episode` runs one greedy
episode in a jitted ``lax.scan`` and renders every state in one ``vmap``.
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.procedural.layout import PaddedLayout, in_bounds_mask
from wrl_jax.envs.warehouse import render as warehouse_render

OFF_GRID = (70, 70, 70)
"""RGB of off-grid cells in :func:`layout_image`."""


def layout_image(layout: PaddedLayout, cell_size: int = 8) -> np.ndarray:
    """``uint8 (H * c, W * c, 3)``: floor, shelves, off-grid, the start (robot colour), goal and every real item."""
    if int(cell_size) < 1:
        raise ValueError(f"cell_size must be a positive number of pixels, got {cell_size}")
    layout = jax.tree.map(np.asarray, layout)
    colors = warehouse_render.COLORS
    image = np.empty((*layout.blocked.shape, 3), dtype=np.uint8)
    image[...] = colors["floor"]
    image[layout.blocked] = colors["shelf"]
    image[~np.asarray(in_bounds_mask(layout.height, layout.width, layout.max_shape))] = OFF_GRID
    for row, col in layout.items[: int(layout.num_items)]:
        image[row, col] = colors["item"]
    image[tuple(layout.goal)] = colors["goal"]
    image[tuple(layout.start)] = colors["robot"]
    return np.repeat(np.repeat(image, int(cell_size), axis=0), int(cell_size), axis=1)


def render_frame(env, state, params, cell_size: int = warehouse_render.DEFAULT_CELL_SIZE) -> jax.Array:
    """An RGB frame of one procedural state (jittable with ``env`` and ``cell_size`` static).

    The padded floor is drawn square (side ``max(H, W)``); off-grid cells are drawn as shelves.
    """
    blocked = env.blocked(state)
    side = max(blocked.shape)
    square = jnp.ones((side, side), dtype=bool).at[: blocked.shape[0], : blocked.shape[1]].set(blocked)
    scene = SimpleNamespace(shelves=square, goal=state.goal, max_steps=params.max_steps)
    return warehouse_render.render_frame(state, scene, cell_size)


def record_episode(env, params, policy: Callable[[jax.Array], jax.Array], layout_index: int, item_index: int,
                   cell_size: int = 16) -> dict[str, Any]:
    """One episode of ``policy(obs) -> action`` on pool slot ``layout_index``, item ``item_index``, rendered.

    Runs ``params.max_steps`` transitions in one jitted scan (states after the
    delivery are cut off), then renders the states in one ``vmap``. Returns
    ``frames`` ``(T + 1, h, w, 3)`` uint8, ``steps``, ``delivered``, ``optimal``
    (the BFS optimum of the episode) and ``collisions``.
    """
    num_steps = int(params.max_steps)

    @jax.jit
    def run(params):
        obs, state = env.reset_to(layout_index, item_index, params)

        def one(carry, _):
            obs, state, done = carry
            action = policy(obs)
            next_obs, next_state, _, terminated, truncated, info = env.transition(None, state, action, params)
            def keep(new, old):  # freeze the episode after its end
                return jnp.where(done, old, new)

            state = jax.tree.map(keep, next_state, state)
            collision = info["collision"] & ~done
            return (keep(next_obs, obs), state, done | terminated | truncated), (state, collision, done)

        (_, last, _), (states, collisions, done_before) = jax.lax.scan(one, (obs, state, jnp.bool_(False)), None,
                                                                       length=num_steps)
        states = jax.tree.map(lambda first, rest: jnp.concatenate([first[None], rest]), state, states)
        frames = jax.vmap(lambda s: render_frame(env, s, params, cell_size))(states)
        return frames, last, jnp.sum(collisions), jnp.sum(~done_before)

    frames, last, collisions, steps = run(params)
    steps = int(steps)
    return {"frames": np.asarray(frames)[: steps + 1], "steps": steps,
            "delivered": bool(last.carrying & np.all(np.asarray(last.pos) == np.asarray(last.goal))),
            "optimal": int(last.optimal), "collisions": int(collisions)}
