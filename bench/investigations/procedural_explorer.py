"""What a window of radius V costs a robot that plans perfectly: the free-space explorer on held-out layouts.

Why this exists: issue 13 asks a learned policy for at most 5 % mean excess over the BFS optimum on
held-out layouts, and the policy sees the floor through a ``(2V+1) x (2V+1)`` window. Part of any
excess is the price of not seeing the floor, not of learning badly. This measures that price with
the classical answer to navigating an unknown grid, the *free-space assumption* (plan as if every
cell not yet seen were free, move one step along the plan, look, replan; Koenig and Likhachev's
D* Lite setting), written plainly in NumPy:

* ``memory``: the robot remembers every cell its windows have shown it (the known floor grows);
* ``no memory``: it plans on its current window only (what a feed-forward policy without a map sees;
  it can loop, and an episode is cut at the env's 300 steps like the policy's).

Each step: a BFS from the current target over the cells not known to be blocked (off-grid cells of
the padded grid and anything outside it are blocked; a window shows them), then the move to the
neighbour closest to the target (ties: up, down, left, right, the action order). The target is the
item, then the goal (SPEC.md's two stages; the window keeps what it saw across the pickup). Episodes:
every real (layout, item) of the final report's held-out set (``layout_sets.heldout_set`` of the
default generator, the same 1,024 layouts and 4,630 episodes), so its excess (over delivered
episodes, as a fraction of their mean optimum, like the final report's) compares with the policy's.
Run from the repository root::

    .venv/bin/python bench/investigations/procedural_explorer.py --json bench/results/procedural_explorer.json
    .venv/bin/python bench/investigations/procedural_explorer.py --layouts 64   # quick
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from wrl_jax.envs.warehouse.layout import bfs_distances  # noqa: E402

MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))
"""Up, down, left, right: the action order, which breaks ties."""
MAX_STEPS = 300
FAR = 1 << 20


def bfs(passable: np.ndarray, source: tuple[int, int]) -> np.ndarray:
    """Steps from ``source`` to every cell over ``passable`` cells (4-neighbour), ``FAR`` where unreachable."""
    dist = bfs_distances(~passable, tuple(int(x) for x in source)).astype(np.int64)
    return np.where(dist < 0, FAR, dist)


def explore(blocked: np.ndarray, start, item, goal, view_radius: int, memory: bool) -> int | None:
    """Steps the free-space explorer takes from ``start`` to ``item`` then ``goal``; ``None`` if over MAX_STEPS."""
    if view_radius < 1:  # the window must show the four neighbours: the explorer never steps into a shelf
        raise ValueError(f"view_radius must be at least 1, got {view_radius}")
    height, width = blocked.shape
    known_blocked = np.zeros_like(blocked)
    pos = tuple(int(x) for x in start)
    targets = [tuple(int(x) for x in item), tuple(int(x) for x in goal)]
    stage, steps = 0, 0
    while steps < MAX_STEPS:
        if not memory:
            known_blocked[:] = False
        rows = slice(max(pos[0] - view_radius, 0), pos[0] + view_radius + 1)
        cols = slice(max(pos[1] - view_radius, 0), pos[1] + view_radius + 1)
        known_blocked[rows, cols] = blocked[rows, cols]
        if pos == targets[stage]:
            if stage == 1:
                return steps
            stage = 1
            continue
        dist = bfs(~known_blocked, targets[stage])
        best, move = dist[pos], None
        for d_row, d_col in MOVES:
            r, c = pos[0] + d_row, pos[1] + d_col
            if 0 <= r < height and 0 <= c < width and dist[r, c] < best:
                best, move = dist[r, c], (r, c)
        if move is None:  # nothing closer is passable as far as it knows: the target is walled off (never here)
            return None
        pos = move
        steps += 1
    return None


def run(layouts: int | None, view_radii: list[int]) -> dict:
    import jax

    from wrl_jax.envs.procedural import layout_sets
    from wrl_jax.envs.procedural.generators import GeneratorConfig

    generator = GeneratorConfig()
    heldout, _ = layout_sets.heldout_set(generator, np.zeros(0, np.uint64), layouts)
    lay = jax.tree.map(np.asarray, heldout.layouts)
    episodes = [(index, item) for index in range(lay.blocked.shape[0]) for item in range(int(lay.num_items[index]))]
    optimal = []
    for index, item in episodes:
        passable = ~lay.blocked[index]
        to_item = bfs(passable, tuple(lay.items[index, item]))
        to_goal = bfs(passable, tuple(lay.goal[index]))
        optimal.append(int(to_item[tuple(lay.start[index])] + to_goal[tuple(lay.items[index, item])]))
    optimal = np.asarray(optimal)
    rows = []
    for radius in view_radii:
        for memory in (True, False):
            begin = time.perf_counter()
            taken = [explore(lay.blocked[i], lay.start[i], lay.items[i, k], lay.goal[i], radius, memory)
                     for i, k in episodes]
            delivered = np.array([t is not None for t in taken])
            steps = np.array([t if t is not None else MAX_STEPS for t in taken])
            excess = (steps - optimal)[delivered]
            rows.append({
                "view_radius": radius, "memory": memory, "episodes": len(episodes),
                "delivered_rate": float(delivered.mean()),
                "optimal_rate": float((excess == 0).sum() / len(episodes)),
                "mean_excess_steps": float(excess.mean()),
                "excess_fraction": float(excess.mean() / optimal[delivered].mean()),
                "seconds": time.perf_counter() - begin,
            })
            row = rows[-1]
            print(f"V={radius} {'memory' if memory else 'no memory':9s}: delivered {row['delivered_rate']:.1%}, "
                  f"at optimum {row['optimal_rate']:.1%}, excess {row['mean_excess_steps']:.2f} steps "
                  f"({row['excess_fraction']:.1%}), {row['seconds']:.0f} s", flush=True)
    return {"set": heldout.description, "layouts": int(lay.blocked.shape[0]), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--layouts", type=int, default=None, help="held-out layouts (default: the final report's)")
    parser.add_argument("--view-radius", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    result = run(args.layouts, args.view_radius)
    result["command"] = " ".join(["python", *sys.argv])
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
