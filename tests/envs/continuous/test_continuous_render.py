"""Rendering the continuous warehouse: every element where the state puts it, rays ending at their
distance, vmapped frames equal to single ones, recorded episodes and their GIFs.

The recorded episodes share one compiled episode (``open5``: 60 steps); single frames go through one jitted
``render`` (the cell size static).
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import wrl_jax
from wrl_jax.envs.continuous.geometry import PI, wrap
from wrl_jax.envs.continuous.geometry import lidar as exact_lidar
from wrl_jax.envs.continuous.registration import make_continuous
from wrl_jax.envs.continuous.render import (
    COLORS,
    frame_shape,
    lidar_from_obs,
    record_episode,
    render_frame,
    to_pixel,
)
from wrl_jax.envs.warehouse.render import COLORS as GRID_COLORS
from wrl_jax.envs.warehouse.render import save_gif

CELL = 16
render = jax.jit(render_frame, static_argnums=3)
lidar = jax.jit(exact_lidar, static_argnums=2)

OPEN_5X5 = """
S . . . .
. . . . .
. . 0 . .
. . . . .
. . . . G
"""


def colour(frame, point, cell_size: int = CELL) -> tuple[int, ...]:
    return tuple(int(v) for v in np.asarray(frame)[to_pixel(point, cell_size)])


def near(frame, point, cell_size: int = CELL) -> set[tuple[int, ...]]:
    """Colours of the 3 x 3 pixels round the point (clipped to the frame)."""
    row, col = to_pixel(point, cell_size)
    frame = np.asarray(frame)
    patch = frame[max(row - 1, 0):row + 2, max(col - 1, 0):col + 2].reshape(-1, 3)
    return {tuple(int(v) for v in pixel) for pixel in patch}


def toward_target(params):
    """Turn to the target (the item, then the goal) and drive at it: enough on an open floor."""

    def policy(obs, state):
        target = jnp.where(state.carrying, params.goal, state.item)
        offset = target - state.pos
        error = wrap(jnp.arctan2(offset[1], offset[0]) - state.theta)
        turn = jnp.clip(error / (params.w_max * params.dt), -1.0, 1.0)
        distance = jnp.sqrt(jnp.sum(offset * offset))
        speed = jnp.where(jnp.abs(error) < 0.3, jnp.clip(distance / (params.v_max * params.dt), 0.0, 1.0), 0.0)
        return jnp.stack([speed, turn])

    return policy


@pytest.fixture(scope="module")
def dynamic12():
    env, params = wrl_jax.make("Continuous-Warehouse-12x12-Dynamic-v0")
    obs, state = jax.jit(env.reset)(jax.random.key(0), params)
    return env, params, obs, state


@pytest.fixture(scope="module")
def open5():
    env, params = make_continuous(OPEN_5X5, max_steps=60)
    return env, params, toward_target(params)


def test_palette_extends_the_grid_renderers():
    assert len(set(COLORS.values())) == len(COLORS)
    assert all(COLORS[name] == rgb for name, rgb in GRID_COLORS.items())


def test_frame_shape_and_dtype(dynamic12):
    env, params, obs, state = dynamic12
    frame = render(state, params, lidar_from_obs(obs, params, env.num_rays), CELL)
    assert frame.dtype == jnp.uint8 and frame.shape == frame_shape(params, CELL) == (12 * CELL, 12 * CELL, 3)
    assert render(state, params, None, 8).shape == (96, 96, 3)
    wide = params.replace(shelves=jnp.zeros((3, 5), bool))  # the renderer takes H != W as it comes
    assert render(state.replace(obstacle_pos=state.obstacle_pos[:0]), wide, None, 8).shape == (24, 40, 3)
    with pytest.raises(ValueError, match="cell_size"):
        render_frame(state, params, None, 4)


def test_elements_have_their_colours(dynamic12):
    _, params, obs, state = dynamic12
    frame = render(state, params, None, CELL)
    assert colour(frame, state.pos) == COLORS["robot"]  # the start, (0.5, 0.5): the top-left cell
    assert to_pixel(state.pos, CELL) == (CELL // 2, CELL // 2)
    assert colour(frame, params.goal) == COLORS["goal"]
    assert colour(frame, state.item) == COLORS["item"]
    for row, col in [(3, 1), (3, 8), (6, 3), (9, 7)]:  # shelves of the ASCII map: row 3 is drawn 3 cells down
        assert colour(frame, (col + 0.5, row + 0.5)) == COLORS["shelf"]
    assert colour(frame, (9.5, 3.5)) == COLORS["floor"]
    for centre in np.asarray(state.obstacle_pos):
        assert colour(frame, centre) == COLORS["obstacle"]
        assert colour(frame, centre + np.array([0.25, 0.0])) == COLORS["obstacle"]
        assert colour(frame, centre + np.array([0.0, 0.36])) != COLORS["obstacle"]
    moved = state.replace(obstacle_pos=state.obstacle_pos.at[0].set(jnp.array([9.5, 3.5])))
    assert colour(render(moved, params, None, CELL), (9.5, 3.5)) == COLORS["obstacle"]


def test_carrying_robot_holds_the_item(dynamic12):
    _, params, _, state = dynamic12
    carrying = state.replace(pos=jnp.array([5.5, 4.5]), carrying=jnp.bool_(True), theta=jnp.float32(PI / 2))
    frame = render(carrying, params, None, CELL)
    assert colour(frame, carrying.pos) == COLORS["item"]
    assert colour(frame, carrying.pos + jnp.array([-0.2, 0.0])) == COLORS["robot_carrying"]
    assert colour(frame, state.item) == COLORS["floor"]  # picked up: no longer on the floor
    empty = render(carrying.replace(carrying=jnp.bool_(False)), params, None, CELL)
    assert colour(empty, carrying.pos) == COLORS["robot"]
    assert colour(empty, state.item) == COLORS["item"]


@pytest.mark.parametrize("theta", [0.0, PI / 2, -PI / 2, 3.0])
def test_heading_line_points_where_the_robot_faces(dynamic12, theta):
    _, params, _, state = dynamic12
    pos = jnp.array([5.5, 4.5])
    ahead = lambda angle: pos + 0.22 * jnp.array([np.cos(angle), np.sin(angle)])  # noqa: E731
    frame = render(state.replace(pos=pos, theta=jnp.float32(theta)), params, None, CELL)
    assert colour(frame, pos) == COLORS["robot"]
    assert colour(frame, ahead(theta)) == COLORS["heading"]
    for other in (theta + PI / 2, theta + PI, theta - PI / 2):
        assert colour(frame, ahead(other)) == COLORS["robot"]
    if theta == PI / 2:  # +y is down the picture, as the map's rows
        row, col = to_pixel(pos, CELL)
        assert tuple(np.asarray(frame)[row + 3, col]) == COLORS["heading"]
        assert tuple(np.asarray(frame)[row - 3, col]) == COLORS["robot"]


def check_rays(frame, pos, theta, ranges, params):
    """Each ray is drawn just before its end (3 x 3 pixels) and not past it, where that is decidable."""
    num_rays = ranges.shape[0]
    checked = 0
    for k in range(num_rays):
        angle = float(theta) + 2 * np.pi * k / num_rays
        direction = np.array([np.cos(angle), np.sin(angle)])
        d = min(float(ranges[k]), float(params.lidar_range))
        if d < 1.0:  # near the robot neighbouring rays lie within a few pixels of each other
            continue
        assert COLORS["ray"] in near(frame, pos + (d - 1.5 / CELL) * direction), f"ray {k} ends early"
        beyond = pos + (d + 2.5 / CELL) * direction
        if np.all(beyond > 0) and np.all(beyond < np.array(params.shelves.shape[::-1])):
            assert COLORS["ray"] not in near(frame, beyond), f"ray {k} runs past {d:.3f} m"
        checked += 1
    return checked


def test_lidar_rays_end_at_their_distance(dynamic12):
    env, params, _, state = dynamic12
    state = state.replace(obstacle_pos=state.obstacle_pos[:0])  # the shelves and walls alone
    for pos, theta in [(state.pos, state.theta), (jnp.array([4.2, 5.1]), jnp.float32(0.4))]:
        state = state.replace(pos=pos, theta=theta)
        ranges = lidar(pos, theta, env.num_rays, params.shelves, state.obstacle_pos, params.obstacle_radius)
        frame = render(state, params, ranges, CELL)
        assert check_rays(np.asarray(frame), np.asarray(pos), theta, np.asarray(ranges), params) >= 10
    # Drawn distances as given: along +x from a pixel centre the last ray pixel is 3 m away.
    flat = state.replace(pos=jnp.array([0.5 + 0.5 / CELL, 0.5 + 0.5 / CELL]), theta=jnp.float32(0.0))
    ranges = jnp.array([3.0, 9.0, 9.0, 9.0])  # four rays, the range clips the long ones to 4 m
    frame = np.asarray(render(flat, params, ranges, CELL))
    row, col = to_pixel(flat.pos, CELL)
    drawn = np.nonzero(np.all(frame[row] == COLORS["ray"], axis=-1))[0]
    assert abs(drawn.max() - (col + 3 * CELL)) <= 1
    down = np.nonzero(np.all(frame[:, col] == COLORS["ray"], axis=-1))[0]
    assert abs(down.max() - (row + 4 * CELL)) <= 1  # ray 1 faces +y: clipped at lidar_range
    # No lidar, no rays.
    assert not np.any(np.all(np.asarray(render(flat, params, None, CELL)) == COLORS["ray"], axis=-1))


def test_ray_stops_at_an_obstacle(dynamic12):
    _, params, _, state = dynamic12
    pos, theta = jnp.array([9.5, 4.5]), jnp.float32(PI)
    obstacles = state.obstacle_pos.at[0].set(jnp.array([7.5, 4.5]))
    moved = state.replace(pos=pos, theta=theta, obstacle_pos=obstacles)
    ranges = lidar(pos, theta, 32, params.shelves, obstacles, params.obstacle_radius)
    assert float(ranges[0]) == pytest.approx(1.7, abs=1e-4)
    frame = render(moved, params, ranges, CELL)
    assert colour(frame, (7.85, 4.5 + 0.5 / CELL)) == COLORS["ray"]
    assert colour(frame, (7.75, 4.5 + 0.5 / CELL)) == COLORS["obstacle"]


def test_lidar_from_obs_reads_the_rays_alone_when_the_target_follows_them():
    """With ``observe_target`` the target's 5 values follow the rays: they are not drawn as rays."""
    plain, params = make_continuous(OPEN_5X5, max_steps=60, num_rays=8)
    target, _ = make_continuous(OPEN_5X5, max_steps=60, num_rays=8, observe_target=True)
    # Both resets in one program (eagerly they compile op by op).
    (obs, _), (seen, _) = jax.jit(lambda k: (plain.reset(k, params), target.reset(k, params)))(jax.random.key(1))
    assert seen.shape == (11 + 8 + 5,)
    rays = lidar_from_obs(seen, params, target.num_rays)
    np.testing.assert_array_equal(rays, lidar_from_obs(obs, params, plain.num_rays))
    np.testing.assert_allclose(rays, obs[11:] * params.lidar_range)


def test_vmapped_frames_equal_single_frames(dynamic12):
    _, params, obs, state = dynamic12
    rng = np.random.default_rng(0)
    states = [state.replace(pos=jnp.asarray(rng.uniform(0.5, 11.5, 2), jnp.float32),
                            theta=jnp.float32(rng.uniform(-PI, PI)), carrying=jnp.bool_(t % 2 == 1),
                            obstacle_pos=state.obstacle_pos + 0.1 * t, time=jnp.int32(7 * t)) for t in range(4)]
    batch = jax.tree.map(lambda *leaves: jnp.stack(leaves), *states)
    ranges = jnp.asarray(rng.uniform(0.0, 5.0, (4, obs.shape[0] - 11)), jnp.float32)
    frames = jax.jit(jax.vmap(render_frame, in_axes=(0, None, 0, None)), static_argnums=3)(batch, params, ranges, CELL)
    assert frames.shape == (4, 12 * CELL, 12 * CELL, 3)
    for i, single in enumerate(states):
        np.testing.assert_array_equal(frames[i], render(single, params, ranges[i], CELL))
    assert not np.array_equal(frames[0], frames[1])


def test_record_episode_delivers_and_writes_a_gif(open5, tmp_path):
    env, params, policy = open5
    recording = record_episode(env, params, policy, jax.random.key(0), item_index=0, cell_size=CELL)
    assert recording.delivered and recording.collisions == 0 and recording.item_index == 0
    assert 0 < recording.length < 60
    assert recording.frames.shape == (recording.length + 1, 5 * CELL, 5 * CELL, 3)
    assert recording.frames.dtype == np.uint8
    assert colour(recording.frames[0], params.start) == COLORS["robot"]
    assert colour(recording.frames[-1], params.items[0]) != COLORS["item"]  # picked up
    rows, cols = np.nonzero(np.all(recording.frames[-1] == COLORS["robot_carrying"], axis=-1))
    centre = np.array([cols.mean() + 0.5, rows.mean() + 0.5]) / CELL  # about the robot's centre
    assert np.linalg.norm(centre - np.asarray(params.goal)) < float(params.reach_radius) + 0.1  # delivered there
    assert recording.total_return > 200
    path = tmp_path / "episode.gif"
    assert save_gif(recording.frames, path, fps=5) == str(path)
    assert os.listdir(tmp_path) == ["episode.gif"]
    with Image.open(path) as gif:
        assert gif.n_frames == len(recording.frames) and gif.size == (5 * CELL, 5 * CELL)
        first = np.asarray(gif.convert("RGB"))
    np.testing.assert_array_equal(first, recording.frames[0])


def test_record_episode_cap_item_draw_and_checks(open5):
    """``max_steps`` caps the recording below the episode's limit. The cap is the limit of ``open5`` (60 steps), so
    the recording is the delivering test's compiled episode; here the limit is 100 and the robot ten times slower
    (both params, not program settings), so the episode runs on past the cap without delivering."""
    env, params, policy = open5
    slow = params.replace(max_steps=jnp.int32(100), v_max=params.v_max / 10)
    short = record_episode(env, slow, policy, jax.random.key(0), item_index=0, max_steps=60, cell_size=CELL)
    assert short.length == 60 and not short.delivered and short.frames.shape[0] == 61
    drawn = record_episode(env, params, policy, jax.random.key(3), max_steps=60, cell_size=CELL)
    assert drawn.item_index == 0  # the layout has one item
    with pytest.raises(ValueError, match="out of range"):
        record_episode(env, params, policy, jax.random.key(0), item_index=1)
    with pytest.raises(ValueError, match="max_steps"):
        record_episode(env, params, policy, jax.random.key(0), max_steps=0)
