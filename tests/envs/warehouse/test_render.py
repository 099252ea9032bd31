"""Rendering: frames, ASCII maps, recorded episodes and GIFs."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import wrl_jax
from wrl_jax.envs.warehouse.layout import optimal_route_lengths
from wrl_jax.envs.warehouse.registration import spec
from wrl_jax.envs.warehouse.render import (
    COLORS,
    cell_center,
    frame_shape,
    oracle_policy,
    record_episode,
    render_ascii,
    render_frame,
    save_gif,
)

CELL = 16
render = jax.jit(render_frame, static_argnums=2)


def colour_at(frame, cell, dy: int = 0, dx: int = 0, cell_size: int = CELL):
    y, x = cell_center(cell, cell_size)
    return tuple(int(v) for v in np.asarray(frame)[y + dy, x + dx])


@pytest.fixture(scope="module")
def warehouse8():
    return wrl_jax.make("Warehouse-8x8-v0")


def test_palette_colours_are_distinct():
    assert len(set(COLORS.values())) == len(COLORS)


@pytest.mark.parametrize("name, cell_size", [("Warehouse-8x8-v0", 16), ("Warehouse-12x12-v0", 8)])
def test_frame_shape_and_dtype(name, cell_size):
    env, params = wrl_jax.make(name)
    _, state = env.reset_to_item(0, params)
    frame = render(state, params, cell_size)
    assert frame.dtype == jnp.uint8
    assert frame.shape == frame_shape(env.size, cell_size) == (env.size * cell_size, env.size * cell_size, 3)


def test_elements_have_their_colours(warehouse8):
    env, params = warehouse8
    _, state = env.reset_to_item(3, params)  # item 3 at (3, 3)
    frame = render(state, params, CELL)
    assert colour_at(frame, (0, 0)) == COLORS["robot"]  # start
    assert colour_at(frame, (3, 3)) == COLORS["item"]
    assert colour_at(frame, (7, 7)) == COLORS["goal"]
    for shelf in [(2, 1), (2, 2), (2, 3), (5, 4), (5, 5)]:
        assert colour_at(frame, shelf) == COLORS["shelf"]
    assert colour_at(frame, (4, 4)) == COLORS["floor"]
    # Other items' cells are plain floor: only this episode's item is drawn.
    assert colour_at(frame, (0, 6)) == COLORS["floor"]
    # Thin grid lines on every cell's top-left edge, and the outer border.
    y, x = cell_center((4, 4), CELL)
    assert tuple(frame[4 * CELL, x]) == COLORS["grid"]
    assert tuple(frame[y, 4 * CELL]) == COLORS["grid"]
    assert tuple(frame[y, 8 * CELL - 1]) == COLORS["grid"]
    assert tuple(frame[y, 4 * CELL + 1]) == COLORS["floor"]


def test_carrying_robot_is_drawn_differently(warehouse8):
    env, params = warehouse8
    _, state = env.reset_to_item(3, params)
    carrying = state.replace(pos=jnp.array([4, 2], dtype=jnp.int32), carrying=jnp.array(True))
    frame = render(carrying, params, CELL)
    # The robot turns purple and holds the orange item at its centre.
    assert colour_at(frame, (4, 2)) == COLORS["item"]
    ring = int(0.3 * CELL)  # inside the disc, outside the carried item
    assert colour_at(frame, (4, 2), dx=-ring) == COLORS["robot_carrying"]
    # The item is no longer on the floor.
    assert colour_at(frame, (3, 3)) == COLORS["floor"]
    # Not carrying, the same pixels differ.
    empty = render(carrying.replace(carrying=jnp.array(False)), params, CELL)
    assert colour_at(empty, (4, 2)) == COLORS["robot"]
    assert colour_at(empty, (4, 2), dx=-ring) == COLORS["robot"]
    assert colour_at(empty, (3, 3)) == COLORS["item"]


def test_robot_on_goal_keeps_goal_visible(warehouse8):
    env, params = warehouse8
    _, state = env.reset_to_item(0, params)
    on_goal = state.replace(pos=params.goal, carrying=jnp.array(True))
    frame = render(on_goal, params, CELL)
    assert colour_at(frame, (7, 7)) == COLORS["item"]
    corner = CELL // 2 - 2  # near the cell's corner, outside the robot disc, inside the grid lines
    assert colour_at(frame, (7, 7), dy=-corner, dx=-corner) == COLORS["goal"]


def test_frames_change_when_the_robot_moves(warehouse8):
    env, params = warehouse8
    _, state = env.reset_to_item(3, params)
    _, moved, *_ = env.transition(None, state, 1, params)  # down to (1, 0)
    before, after = np.asarray(render(state, params, CELL)), np.asarray(render(moved, params, CELL))
    changed = np.any(before != after, axis=-1)
    assert colour_at(after, (1, 0)) == COLORS["robot"]
    assert colour_at(after, (0, 0)) == COLORS["floor"]
    # Only the two robot cells and the timer bar along the top edge changed.
    rows, cols = np.nonzero(changed)
    in_robot_cells = (cols < CELL) & (rows < 2 * CELL)
    in_timer = rows < max(1, CELL // 10)
    assert np.all(in_robot_cells | in_timer)


def test_timer_bar_tells_a_blocked_step_from_the_state_before(warehouse8):
    env, params = warehouse8
    _, state = env.reset_to_item(3, params)
    _, bumped, *_ = env.transition(None, state, 0, params)  # up from (0, 0): a wall bump, the robot stays
    assert np.array_equal(bumped.pos, state.pos)
    # With the frame at least max_steps = 150 pixels wide, every step grows the bar.
    frames = [np.asarray(render(state.replace(time=jnp.int32(t)), params, 32)) for t in range(151)]
    assert np.array_equal(frames[1], np.asarray(render(bumped, params, 32)))
    assert all(not np.array_equal(a, b) for a, b in zip(frames[:-1], frames[1:]))
    assert np.all(frames[-1][0] == COLORS["timer"])
    # Narrower frames still show any progress at all.
    assert not np.array_equal(np.asarray(render(state, params, 8)), np.asarray(render(bumped, params, 8)))


def test_render_is_vmappable(warehouse8):
    env, params = warehouse8
    states = [env.reset_to_item(i, params)[1] for i in range(4)]
    batch = jax.tree.map(lambda *leaves: jnp.stack(leaves), *states)
    frames = jax.jit(jax.vmap(render_frame, in_axes=(0, None, None)), static_argnums=2)(batch, params, CELL)
    assert frames.shape == (4, 8 * CELL, 8 * CELL, 3)
    for i, state in enumerate(states):
        assert np.array_equal(frames[i], render(state, params, CELL))


@pytest.mark.parametrize("ascii_map", ["S 0\n. G", "S . # .\n. # 0 .\n. . . .\n1 # . G"])
def test_any_grid_size(ascii_map):
    env, params = wrl_jax.make_from_layout(ascii_map, max_steps=10)
    _, state = env.reset_to_item(0, params)
    frame = render(state, params, 8)
    assert frame.shape == (env.size * 8, env.size * 8, 3)
    assert colour_at(frame, tuple(params.goal), cell_size=8) == COLORS["goal"]
    assert colour_at(frame, tuple(params.items[0]), cell_size=8) == COLORS["item"]


def test_bad_cell_size_is_rejected(warehouse8):
    env, params = warehouse8
    _, state = env.reset_to_item(0, params)
    with pytest.raises(ValueError, match="cell_size"):
        render_frame(state, params, 2)
    with pytest.raises(ValueError, match="cell_size"):
        render_frame(state, params, 8.5)


def test_render_ascii(warehouse8):
    env, params = warehouse8
    _, state = env.reset_to_item(3, params)
    text = render_ascii(state, params)
    lines = text.splitlines()
    assert lines[0] == "step 0/150, fetching item 3"
    grid = [line.split() for line in lines[1:]]
    assert len(grid) == 8 and all(len(row) == 8 for row in grid)
    assert grid[0][0] == "R" and grid[3][3] == "3" and grid[7][7] == "G" and grid[2][1] == "#"
    carrying = state.replace(pos=jnp.array([4, 4], dtype=jnp.int32), carrying=jnp.array(True), time=jnp.int32(9))
    text = render_ascii(carrying, params)
    assert text.splitlines()[0] == "step 9/150, carrying the item"
    grid = [line.split() for line in text.splitlines()[1:]]
    assert grid[4][4] == "C" and grid[3][3] == "." and grid[0][0] == "."


@pytest.mark.parametrize("name, item_index", [("Warehouse-8x8-v0", 3), ("Warehouse-12x12-v0", 11)])
def test_record_episode_with_the_oracle_delivers(name, item_index):
    env, params = wrl_jax.make(name)
    recording = record_episode(env, params, oracle_policy(params), item_index, cell_size=8)
    optimum = int(optimal_route_lengths(spec(name).layout)[item_index])
    assert recording.delivered and recording.collisions == 0
    assert recording.length == optimum
    assert recording.frames.shape == (optimum + 1, env.size * 8, env.size * 8, 3)
    assert recording.frames.dtype == np.uint8
    # The last frame is the delivery: the carrying robot on the goal.
    assert colour_at(recording.frames[-1], tuple(params.goal), cell_size=8) == COLORS["item"]
    assert colour_at(recording.frames[0], tuple(params.start), cell_size=8) == COLORS["robot"]
    if name == "Warehouse-8x8-v0":
        assert recording.total_return == pytest.approx(278.5 - 0.5 * optimum)


def test_record_episode_stops_at_truncation():
    env, params = wrl_jax.make("Warehouse-8x8-v0", max_steps=12)
    always_up = lambda obs, state: jnp.int32(0)  # noqa: E731  bumps the top wall forever
    recording = record_episode(env, params, always_up, 0, cell_size=8)
    assert recording.length == 12 and not recording.delivered
    assert recording.frames.shape[0] == 13
    assert recording.total_return == pytest.approx(-0.5 * 12)
    # Every frame differs from the one before (the timer bar advances).
    diffs = [np.any(a != b) for a, b in zip(recording.frames[:-1], recording.frames[1:])]
    assert all(diffs)


@pytest.fixture(scope="module")
def oracle8(warehouse8):
    """One oracle policy object, so every recording below shares one compiled episode."""
    return oracle_policy(warehouse8[1])


def test_record_episode_draws_the_item_from_a_key(warehouse8, oracle8):
    env, params = warehouse8
    a = record_episode(env, params, oracle8, key=jax.random.key(3), cell_size=8)
    b = record_episode(env, params, oracle8, key=jax.random.key(3), cell_size=8)
    assert a.item_index == b.item_index and np.array_equal(a.frames, b.frames)
    items = {record_episode(env, params, oracle8, key=jax.random.key(k), cell_size=8).item_index for k in range(8)}
    assert len(items) > 1
    with pytest.raises(ValueError, match="item_index or a PRNG key"):
        record_episode(env, params, oracle8)
    with pytest.raises(ValueError, match="out of range"):
        record_episode(env, params, oracle8, 10)


def test_save_gif_round_trip(tmp_path, warehouse8, oracle8):
    env, params = warehouse8
    recording = record_episode(env, params, oracle8, 0, cell_size=8)
    path = tmp_path / "episode.gif"
    assert save_gif(recording.frames, path, fps=10) == str(path)
    assert os.listdir(tmp_path) == ["episode.gif"]  # no temp file left behind
    with Image.open(path) as gif:
        assert gif.n_frames == len(recording.frames)
        assert gif.size == (8 * 8, 8 * 8)
        gif.seek(0)
        first = np.asarray(gif.convert("RGB"))
        assert gif.info["duration"] == 100
    assert np.array_equal(first, recording.frames[0])  # few colours: the GIF palette is exact


def test_save_gif_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="T, H, W, 3"):
        save_gif(np.zeros((4, 4, 3), dtype=np.uint8), tmp_path / "a.gif")
    with pytest.raises(ValueError, match="uint8"):
        save_gif(np.zeros((2, 4, 4, 3), dtype=np.float32), tmp_path / "a.gif")
    with pytest.raises(ValueError, match="does not exist"):
        save_gif(np.zeros((2, 4, 4, 3), dtype=np.uint8), tmp_path / "missing" / "a.gif")
    assert os.listdir(tmp_path) == []
