"""The free-space explorer of ``bench/investigations/procedural_explorer.py``: the yardstick for what a window costs.

Its numbers explain the procedural policy's excess (docs/procedural.md), so they must be right: a
robot that sees the whole floor walks the BFS optimum; one that sees a little walks into a dead end
exactly as far as the free-space assumption says; without memory it can loop, and is cut.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def explorer():
    spec = importlib.util.spec_from_file_location("procedural_explorer", ROOT / "bench" / "investigations" / "procedural_explorer.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _floor(rows: list[str]) -> np.ndarray:
    return np.array([[cell == "#" for cell in row] for row in rows])


def test_a_robot_that_sees_everything_walks_the_optimum(explorer):
    floor = _floor([
        "......",
        ".####.",
        ".#..#.",
        ".#.##.",
        "......",
    ])
    start, item, goal = (2, 2), (0, 5), (4, 0)
    optimal = explorer.bfs(~floor, item)[start] + explorer.bfs(~floor, goal)[item]
    assert optimal == 9 + 9  # out of the pocket through (3, 2), round the right side; back over the top
    for memory in (True, False):
        assert explorer.explore(floor, start, item, goal, view_radius=5, memory=memory) == optimal


CLOSED_CORRIDOR = [
    "........",
    ".######.",
    "......#.",  # the robot starts at (2, 0); the corridor toward the target (2, 7) is closed at (2, 6)
    "########",
]


def test_the_free_space_assumption_walks_into_a_dead_end_it_cannot_see(explorer):
    """Straight on looks 7 steps long, the way over the top is 11: it tries the corridor until it sees the wall."""
    floor = _floor(CLOSED_CORRIDOR)
    start, item = (2, 0), (2, 7)
    optimal = explorer.bfs(~floor, item)[start]
    assert optimal == 2 + 7 + 2
    # Radius 1: it sees (2, 6) from (2, 5), walks the 5 cells back and goes over the top.
    assert explorer.explore(floor, start, item, item, view_radius=1, memory=True) == 5 + 5 + optimal
    # Radius 2: it sees the wall from (2, 4).
    assert explorer.explore(floor, start, item, item, view_radius=2, memory=True) == 4 + 4 + optimal
    # Seeing the whole floor it goes over the top at once.
    assert explorer.explore(floor, start, item, item, view_radius=8, memory=True) == optimal


def test_without_memory_it_loops_and_is_cut(explorer):
    """Back at (2, 4) a robot without memory no longer sees the wall at (2, 6) and walks in again, forever."""
    floor = _floor(CLOSED_CORRIDOR)
    assert explorer.explore(floor, (2, 0), (2, 7), (2, 7), view_radius=1, memory=False) is None
    with pytest.raises(ValueError, match="view_radius must be at least 1"):
        explorer.explore(floor, (2, 0), (2, 7), (2, 7), view_radius=0, memory=True)
