"""Issue 11: how small is the signal that separates a shortest route from the rest?

Value iteration on Warehouse-12x12-v0's MDP (SPEC.md's rewards x 0.01, the PPO default's reward scale;
gamma 0.95) per item, over (cell, carrying). For every state on a shortest route it takes the gap between
the best Q of an action that stays on a shortest route and the best Q of any other action, and prints the
smallest gap per item. ``python bench/investigations/action_gap_value_iteration.py`` (NumPy, seconds).
Output: bench/results/ppo_default_robustness/action_gap_value_iteration.txt (docs/ppo.md cites it).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from wrl_jax.envs.warehouse.maps import WAREHOUSE_12X12

ROWS = [line.split() for line in WAREHOUSE_12X12.strip().splitlines()]
SIZE = len(ROWS)
SHELF = np.array([[token == "#" for token in row] for row in ROWS])
ITEMS = "0123456789abcdefghij"
MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # up, down, left, right
GAMMA, SCALE, SWEEPS = 0.95, 0.01, 400
STEP, BUMP, SHAPING, PICKUP, DELIVERY = -0.5, -10.0, 2.0, 50.0, 200.0  # SPEC.md's rewards (shaping per Manhattan step)


def find(token: str) -> tuple[int, int]:
    return next((r, c) for r in range(SIZE) for c in range(SIZE) if ROWS[r][c] == token)


def move(cell: tuple[int, int], action: int) -> tuple[tuple[int, int], float]:
    """The next cell and the bump penalty: off the map the robot stays (no penalty), into a shelf it stays (-10)."""
    target = (cell[0] + MOVES[action][0], cell[1] + MOVES[action][1])
    if not (0 <= target[0] < SIZE and 0 <= target[1] < SIZE):
        return cell, 0.0
    if SHELF[target]:
        return cell, BUMP
    return target, 0.0


def action_values(item: tuple[int, int], goal: tuple[int, int]) -> np.ndarray:
    """``Q[stage, r, c, a]`` (scaled) after value iteration; stage 0 fetches ``item``, stage 1 delivers to ``goal``.

    The transitions are tabulated once (reward, next stage and cell, terminal); each sweep is then array
    arithmetic. Shelf cells keep -1e9 (never reached: a bump stays where it was).
    """
    reward = np.full((2, SIZE, SIZE, 4), -1e9)
    next_stage = np.zeros((2, SIZE, SIZE, 4), int)
    next_row, next_col = np.zeros((2, SIZE, SIZE, 4), int), np.zeros((2, SIZE, SIZE, 4), int)
    goes_on = np.zeros((2, SIZE, SIZE, 4))  # 0 where the transition ends the episode
    for stage, target in ((0, item), (1, goal)):
        distance = lambda cell: abs(cell[0] - target[0]) + abs(cell[1] - target[1])  # noqa: E731
        for cell in ((r, c) for r in range(SIZE) for c in range(SIZE) if not SHELF[r, c]):
            for action in range(4):
                nxt, penalty = move(cell, action)
                index = (stage, *cell, action)
                reward[index] = penalty + SHAPING * (distance(cell) - distance(nxt))
                next_row[index], next_col[index] = nxt
                if stage == 0 and nxt == item:
                    reward[index] += STEP + PICKUP
                    next_stage[index], goes_on[index] = 1, 1.0
                elif stage == 1 and nxt == goal:
                    reward[index] += DELIVERY
                else:
                    reward[index] += STEP
                    next_stage[index], goes_on[index] = stage, 1.0
    values = np.zeros((2, SIZE, SIZE))
    for _ in range(SWEEPS):
        values = (reward + GAMMA * goes_on * values[next_stage, next_row, next_col]).max(-1)
    return (reward + GAMMA * goes_on * values[next_stage, next_row, next_col]) * SCALE


def bfs(source: tuple[int, int]) -> np.ndarray:
    """Steps from ``source`` to every cell (1e6 where unreachable)."""
    distance = np.full((SIZE, SIZE), 10**6)
    distance[source] = 0
    queue = deque([source])
    while queue:
        cell = queue.popleft()
        for action in range(4):
            nxt, _ = move(cell, action)
            if nxt != cell and distance[nxt] > distance[cell] + 1:
                distance[nxt] = distance[cell] + 1
                queue.append(nxt)
    return distance


def smallest_gap(item_token: str, start: tuple[int, int], goal: tuple[int, int]) -> float:
    """The smallest gap, over the states of every shortest route, between the best on-route and off-route Q."""
    item = find(item_token)
    q = action_values(item, goal)
    from_start, from_item, from_goal = bfs(start), bfs(item), bfs(goal)
    gaps = []
    for stage, (to_target, end) in enumerate(((from_item, item), (from_goal, goal))):
        for cell in ((r, c) for r in range(SIZE) for c in range(SIZE) if not SHELF[r, c]):
            on_route = (from_start[cell] + from_item[cell] == from_start[item] if stage == 0
                        else from_item[cell] + from_goal[cell] == from_item[goal])
            if not on_route or cell == end:
                continue
            good = [a for a in range(4) if move(cell, a)[0] != cell and to_target[move(cell, a)[0]] == to_target[cell] - 1]
            other = [a for a in range(4) if a not in good]
            gaps.append(q[stage][cell][good].max() - q[stage][cell][other].max())
    return min(gaps)


def main() -> None:
    start, goal = find("S"), find("G")
    gaps = [smallest_gap(token, start, goal) for token in ITEMS]
    print(f"gamma {GAMMA}: min action gap on shortest routes (scaled return units):")
    print("  " + " ".join(f"{index}:{gap:.3f}" for index, gap in enumerate(gaps)))


if __name__ == "__main__":
    main()
