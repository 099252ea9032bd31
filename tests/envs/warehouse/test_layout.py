"""Map parsing: the built-in maps match SPEC.md; bad maps fail with clear errors."""

import numpy as np
import pytest

from wrl_jax.envs.warehouse import maps
from wrl_jax.envs.warehouse.layout import Layout, bfs_distances, optimal_route_lengths, parse


def test_8x8_matches_spec():
    layout = parse(maps.WAREHOUSE_8X8)
    assert layout.size == 8
    assert tuple(layout.start) == (0, 0) and tuple(layout.goal) == (7, 7)
    assert sorted(map(tuple, np.argwhere(layout.shelves))) == [(2, 1), (2, 2), (2, 3), (5, 4), (5, 5)]
    expected_items = [(0, 6), (1, 3), (3, 1), (3, 3), (4, 5), (4, 0), (6, 2), (6, 5), (7, 1), (2, 6)]
    assert list(map(tuple, layout.items)) == expected_items
    assert optimal_route_lengths(layout).tolist() == [14] * 10


def test_12x12_matches_spec():
    layout = parse(maps.WAREHOUSE_12X12)
    assert layout.size == 12
    assert tuple(layout.start) == (0, 0) and tuple(layout.goal) == (11, 11)
    shelves = {(3, c) for c in range(1, 9)} | {(6, c) for c in range(3, 11)} | {(9, c) for c in range(1, 8)}
    assert set(map(tuple, np.argwhere(layout.shelves))) == shelves and len(shelves) == 23
    expected_items = [(0, 4), (2, 1), (4, 0), (4, 5), (5, 2), (0, 10), (2, 7), (3, 10), (5, 6), (5, 11),
                      (6, 1), (8, 4), (10, 0), (10, 3), (11, 5), (7, 9), (8, 6), (9, 10), (10, 7), (11, 9)]
    assert list(map(tuple, layout.items)) == expected_items
    assert optimal_route_lengths(layout).tolist() == [22] * 20


@pytest.mark.parametrize("ascii_map", [maps.WAREHOUSE_8X8, maps.WAREHOUSE_12X12])
def test_ascii_round_trip(ascii_map):
    layout = parse(ascii_map)
    again = parse(layout.to_ascii())
    for field in ("shelves", "start", "goal", "items"):
        np.testing.assert_array_equal(getattr(layout, field), getattr(again, field))


def test_compact_format_parses():
    layout = parse("S.0\n.#.\n..G")
    assert layout.size == 3 and tuple(layout.items[0]) == (0, 2)


@pytest.mark.parametrize(
    "ascii_map, message",
    [
        ("", "empty map"),
        ("S.0\n.#\n..G", "ragged map: row 1 has 2 cells"),
        ("S.0.\n.#..\n...G", "must be square"),
        ("..0\n.#.\n..G", "no start"),
        ("S.0\n.#.\n...", "no goal"),
        ("S.0\nS#.\n..G", r"2 of start 'S', at cells \[\(0, 0\), \(1, 0\)\]"),
        ("S.0\n.#G\n..G", "2 of goal 'G'"),
        ("S..\n.#.\n..G", "no items"),
        ("S.0\n.?.\n..G", r"unknown character '\?' at cell \(1, 1\)"),
        ("S.0\n.#0\n..G", r"item marker '0' appears twice: at \(0, 2\) and at \(1, 2\)"),
        ("S.0\n.#2\n..G", "'1' is missing"),
        ("S#0\n##.\n..G", r"goal at cell \(2, 2\) is unreachable"),
        ("S.#\n.#0\n#.G", r"goal at cell \(2, 2\) is unreachable"),
        ("S..\n..#\n.#0\n#..\n", "square"),
        ("S..G\n....\n..##\n..#0", r"item 0 at cell \(3, 3\) is unreachable"),
    ],
)
def test_bad_maps_raise_clear_errors(ascii_map, message):
    with pytest.raises(ValueError, match=message):
        parse(ascii_map)


def test_array_layout_item_on_shelf_is_rejected():
    shelves = np.zeros((3, 3), dtype=bool)
    shelves[1, 1] = True
    with pytest.raises(ValueError, match=r"item 0 at cell \(1, 1\) is on a shelf"):
        Layout(shelves=shelves, start=np.array([0, 0]), goal=np.array([2, 2]), items=np.array([[1, 1]]))


def test_array_layout_shared_cell_is_rejected():
    shelves = np.zeros((3, 3), dtype=bool)
    with pytest.raises(ValueError, match=r"item 0 and goal share cell \(2, 2\)"):
        Layout(shelves=shelves, start=np.array([0, 0]), goal=np.array([2, 2]), items=np.array([[2, 2]]))


def test_array_layout_out_of_grid_is_rejected():
    shelves = np.zeros((3, 3), dtype=bool)
    with pytest.raises(ValueError, match=r"item 0 at cell \(3, 0\) lies outside the 3x3 grid"):
        Layout(shelves=shelves, start=np.array([0, 0]), goal=np.array([2, 2]), items=np.array([[3, 0]]))


def test_bfs_distances_route_around_shelves():
    layout = parse("S#0\n.#.\n..G")
    dist = bfs_distances(layout.shelves, (0, 0))
    assert dist[0, 2] == 6 and dist[2, 2] == 4 and dist[0, 1] == -1
