"""A plain NumPy reference of FLEET_SPEC.md, written from the contract, for bit parity with the JAX fleet.

Nothing here is shared with :mod:`wrl_jax.envs.fleet.env`: the reference
computes its own BFS distances, loops over robots and conflict rounds in
Python, and adds the float32 reward terms one by one in the contract's
order. It does no random draws: like the JAX core it takes each
transition's drawn tasks (``item``, ``station``: one candidate per robot) as
inputs, so a test draws them once with :func:`wrl_jax.envs.fleet.dynamics.draw_tasks`
and feeds both.

It is slow by design (clarity over speed): use it for tests and tiny runs.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from typing import Any

import numpy as np

DELTAS = {0: (-1, 0), 1: (1, 0), 2: (0, -1), 3: (0, 1), 4: (0, 0)}
"""Action -> (d_row, d_col): up, down, left, right, wait."""

REWARD_NAMES = ("step_penalty", "obstacle_penalty", "wall_penalty", "block_penalty", "shaping_coef",
                "pickup_reward", "delivery_reward")


@dataclasses.dataclass
class RefState:
    """The reference's state: the same fields as ``FleetState``, as NumPy arrays."""

    pos: np.ndarray  # (K, 2) int32
    item: np.ndarray  # (K,) int32
    station: np.ndarray  # (K,) int32
    carrying: np.ndarray  # (K,) bool
    time: int

    def copy(self) -> RefState:
        return RefState(self.pos.copy(), self.item.copy(), self.station.copy(), self.carrying.copy(), self.time)


def bfs(shelves: np.ndarray, source: tuple[int, int]) -> np.ndarray:
    """Free-cell shortest path lengths from ``source`` (-1 where unreachable)."""
    size = shelves.shape[0]
    dist = np.full(shelves.shape, -1, dtype=np.int64)
    dist[source] = 0
    queue = deque([source])
    while queue:
        row, col = queue.popleft()
        for d_row, d_col in list(DELTAS.values())[:4]:
            nr, nc = row + d_row, col + d_col
            if 0 <= nr < size and 0 <= nc < size and not shelves[nr, nc] and dist[nr, nc] < 0:
                dist[nr, nc] = dist[row, col] + 1
                queue.append((nr, nc))
    return dist


class FleetReference:
    """The fleet MDP, one robot and one round at a time."""

    def __init__(self, shelves: np.ndarray, starts: np.ndarray, items: np.ndarray, stations: np.ndarray, *,
                 max_steps: int, rewards: dict[str, float], manhattan: bool = False, view_radius: int = 2):
        self.shelves = np.asarray(shelves, dtype=bool)
        self.size = self.shelves.shape[0]
        self.starts = np.asarray(starts, dtype=np.int32)
        self.items = np.asarray(items, dtype=np.int32)
        self.stations = np.asarray(stations, dtype=np.int32)
        self.num_robots = len(self.starts)
        self.max_steps = int(max_steps)
        self.rewards = {name: np.float32(rewards[name]) for name in REWARD_NAMES}
        self.manhattan = bool(manhattan)
        self.view_radius = int(view_radius)
        self.item_dist = [bfs(self.shelves, (int(r), int(c))) for r, c in self.items]
        self.station_dist = [bfs(self.shelves, (int(r), int(c))) for r, c in self.stations]

    @classmethod
    def from_params(cls, params: Any, view_radius: int = 2) -> FleetReference:
        """A reference for the layout and constants of JAX ``FleetParams`` (read as NumPy; unbatched)."""
        num_items, num_stations = int(params.num_items), int(params.num_stations)
        return cls(np.asarray(params.shelves), np.asarray(params.starts), np.asarray(params.items)[:num_items],
                   np.asarray(params.stations)[:num_stations], max_steps=int(params.max_steps),
                   rewards={name: float(getattr(params, name)) for name in REWARD_NAMES},
                   manhattan=bool(params.manhattan_shaping), view_radius=view_radius)

    # ------------------------------------------------------------------ helpers
    def target(self, state: RefState, robot: int) -> tuple[int, int]:
        cell = self.stations[state.station[robot]] if state.carrying[robot] else self.items[state.item[robot]]
        return int(cell[0]), int(cell[1])

    def distance(self, state: RefState, robot: int, cell: tuple[int, int]) -> int:
        """``d(cell, t_robot)`` with the robot's target in ``state``."""
        target = self.target(state, robot)
        if self.manhattan:
            return abs(cell[0] - target[0]) + abs(cell[1] - target[1])
        table = self.station_dist[state.station[robot]] if state.carrying[robot] else self.item_dist[state.item[robot]]
        return int(table[cell])

    def observe(self, state: RefState) -> np.ndarray:
        radius, side = self.view_radius, 2 * self.view_radius + 1
        scale = np.float32(self.size - 1)
        rows = []
        for i in range(self.num_robots):
            row, col = int(state.pos[i, 0]), int(state.pos[i, 1])
            target = self.target(state, i)
            scalars = [np.float32(row) / scale, np.float32(col) / scale, np.float32(target[0]) / scale,
                       np.float32(target[1]) / scale, np.float32(1.0 if state.carrying[i] else 0.0)]
            window = np.zeros((3, side, side), dtype=np.float32)
            for a in range(side):
                for b in range(side):
                    r, c = row - radius + a, col - radius + b
                    if not (0 <= r < self.size and 0 <= c < self.size) or self.shelves[r, c]:
                        window[0, a, b] = 1.0
                    if any(j != i and state.pos[j, 0] == r and state.pos[j, 1] == c for j in range(self.num_robots)):
                        window[1, a, b] = 1.0
                    if (r, c) == target:
                        window[2, a, b] = 1.0
            rows.append(np.concatenate([np.array(scalars, dtype=np.float32), window.reshape(-1)]))
        return np.stack(rows).astype(np.float32)

    # ------------------------------------------------------------------ MDP
    def reset(self, item: np.ndarray, station: np.ndarray) -> tuple[np.ndarray, RefState]:
        state = RefState(self.starts.copy(), np.asarray(item, np.int32).copy(), np.asarray(station, np.int32).copy(),
                         np.zeros(self.num_robots, dtype=bool), 0)
        return self.observe(state), state

    def resolve(self, pos: list[tuple[int, int]], q: list[tuple[int, int]]) -> tuple[set[int], list[bool]]:
        """Step 3 literally: rounds removing every blocked mover at once; returns the final movers and blocks."""
        k = self.num_robots
        movers = {i for i in range(k) if q[i] != pos[i]}
        block = [False] * k
        while True:
            f = [q[j] if j in movers else pos[j] for j in range(k)]
            blocked = set()
            for i in movers:
                for j in range(k):
                    if j == i:
                        continue
                    if f[j] == q[i] and (j not in movers or j < i):
                        blocked.add(i)
                    if j in movers and q[j] == pos[i] and q[i] == pos[j]:
                        blocked.add(i)
            if not blocked:
                return movers, block
            for i in blocked:
                block[i] = True
            movers -= blocked

    def transition(self, state: RefState, action: np.ndarray, item: np.ndarray, station: np.ndarray):
        """Steps 1-8 without reset: ``(obs, next_state, reward (K,), terminated, truncated, info)``."""
        k, n = self.num_robots, self.size
        action = [int(a) for a in np.asarray(action)]
        if len(action) != k or any(a not in DELTAS for a in action):
            raise ValueError(f"expected {k} actions in 0..4, got {action}")
        pos = [(int(r), int(c)) for r, c in state.pos]
        flags = {name: np.zeros(k, dtype=bool) for name in
                 ("shelf_hit", "wall_bump", "robot_block", "picked_up", "delivered", "waited")}
        q = []
        for i in range(k):
            d_row, d_col = DELTAS[action[i]]
            cell = (pos[i][0] + d_row, pos[i][1] + d_col)
            flags["waited"][i] = action[i] == 4
            if not (0 <= cell[0] < n and 0 <= cell[1] < n):
                flags["wall_bump"][i], cell = True, pos[i]
            elif self.shelves[cell]:
                flags["shelf_hit"][i], cell = True, pos[i]
            q.append(cell)
        movers, block = self.resolve(pos, q)
        flags["robot_block"][:] = block
        new_pos = [q[i] if i in movers else pos[i] for i in range(k)]

        nxt = state.copy()
        nxt.pos = np.array(new_pos, dtype=np.int32).reshape(k, 2)
        reward = np.zeros(k, dtype=np.float32)
        c = self.rewards
        for i in range(k):
            at_target = new_pos[i] == self.target(state, i)
            flags["picked_up"][i] = at_target and not state.carrying[i]
            flags["delivered"][i] = at_target and bool(state.carrying[i])
            r = c["step_penalty"]
            if flags["shelf_hit"][i]:
                r = np.float32(r + c["obstacle_penalty"])
            if flags["wall_bump"][i]:
                r = np.float32(r + c["wall_penalty"])
            if flags["robot_block"][i]:
                r = np.float32(r + c["block_penalty"])
            diff = self.distance(state, i, pos[i]) - self.distance(state, i, new_pos[i])
            r = np.float32(r + np.float32(c["shaping_coef"] * np.float32(diff)))
            if flags["picked_up"][i]:
                r = np.float32(r + c["pickup_reward"])
                nxt.carrying[i] = True
            if flags["delivered"][i]:
                r = np.float32(r + c["delivery_reward"])
                nxt.carrying[i] = False
                nxt.item[i], nxt.station[i] = int(item[i]), int(station[i])
            reward[i] = r
        nxt.time = state.time + 1
        truncated = nxt.time >= self.max_steps
        return self.observe(nxt), nxt, reward, False, truncated, flags

    def step(self, state: RefState, action: np.ndarray, tasks: tuple[np.ndarray, np.ndarray],
             reset_tasks: tuple[np.ndarray, np.ndarray]):
        """A transition, then the auto-reset on truncation.

        ``info["final_obs"]`` is the reached observation (the contract's);
        ``info["final_state"]`` the reached state (the reference's extra, for tests).
        """
        obs, nxt, reward, terminated, truncated, info = self.transition(state, action, *tasks)
        info = {**info, "final_obs": obs, "final_state": nxt}
        if terminated or truncated:
            obs, nxt = self.reset(*reset_tasks)
        return obs, nxt, reward, terminated, truncated, info
