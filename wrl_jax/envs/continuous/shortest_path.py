"""Exact any-angle shortest paths of the robot's disc through a layout (CONTINUOUS_SPEC.md "The yardstick").

The disc's centre moves in the plane minus the solid squares (shelves, and every cell outside the map,
which is the wall) grown by the radius ``R``. For ``R < 1/2`` a shortest path bends only around the
grid points where exactly one of the four cells meeting there is solid: around each lies a quarter
circle of radius ``R``, facing away from that cell, and nothing else of the grown boundary is convex
(two solid cells along an edge give a flat side, diagonal or three solid cells a concave corner,
which no shortest path touches; and every point of a quarter lies ``1 - R > R`` from any other square,
so the quarters are free and disjoint). So every shortest path is made of straight segments tangent to
those quarter circles and arcs of them, and Dijkstra over the tangent graph finds the exact length:
nodes are the terminals and the tangent points (terminal to circle, and the four common tangents of
each pair of circles), joined by the segments that keep the disc clear, with consecutive points on
each quarter circle joined by their arcs.

Floating point: every test errs towards "free" (a clearance of ``R - 1e-9`` passes, a tangent point
``1e-9`` rad past its quarter still counts), so the true shortest path is in the graph and the value
is never above the true length by more than float64 rounding: a lower bound, and exact to ~1e-9 m.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

TOLERANCE = 1e-9
"""Metres (clearance) and radians (quarter ends) by which a test leans towards "free"."""
CHUNK = 4096
"""Segments tested against all squares at once (bounds the memory of large layouts)."""
HALF_PI = np.pi / 2


@dataclasses.dataclass(frozen=True)
class TangentGraph:
    """The tangent graph of one layout, radius and terminal list (see the module docstring).

    ``xy[n]`` is node ``n``'s point; nodes ``0 .. T-1`` are the terminals; ``circle[n]`` is the
    quarter circle a tangent point lies on (-1 for a terminal), ``angle[n]`` its angle there.
    """

    radius: float
    centres: np.ndarray  # (C, 2) grid points (x, y) that carry a quarter circle
    xy: np.ndarray  # (N, 2)
    circle: np.ndarray  # (N,) int
    angle: np.ndarray  # (N,) radians, relative to the quarter's first direction, in [0, pi/2]
    first: np.ndarray  # (C,) the first direction of each quarter (radians)
    matrix: sp.csr_matrix  # (N, N) undirected edge lengths, one triangle stored
    num_terminals: int


def quarter_circles(solid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid points ``(C, 2)`` as (x, y) with exactly one solid cell around them, and each quarter's first angle.

    ``solid[row, col]`` is the cell ``x in [col, col+1], y in [row, row+1]``; cells outside the map count as
    solid. The free quarter is the one opposite the solid cell: a solid cell at ``(+x, +y)`` of the point
    leaves the directions ``[pi, 3 pi / 2]``.
    """
    padded = np.pad(np.asarray(solid, bool), 1, constant_values=True)
    # Around grid point (x=c, y=r): cells (r-1, c-1), (r-1, c), (r, c-1), (r, c) = padded[r + i, c + j].
    low_low, low_high = padded[:-1, :-1], padded[:-1, 1:]  # (-x, -y), (+x, -y)
    high_low, high_high = padded[1:, :-1], padded[1:, 1:]  # (-x, +y), (+x, +y)
    count = low_low.astype(int) + low_high + high_low + high_high
    rows, cols = np.nonzero(count == 1)
    first = np.select([low_low[rows, cols], low_high[rows, cols], high_low[rows, cols]],
                      [0.0, HALF_PI, -HALF_PI], default=np.pi)
    return np.stack([cols, rows], axis=1).astype(np.float64), first


def segment_clearance(a: np.ndarray, b: np.ndarray, lows: np.ndarray) -> np.ndarray:
    """Distance ``(N,)`` from each segment ``a[n] b[n]`` to the nearest unit square with lower corner in ``lows``.

    Zero where a segment crosses a square (a slab test); otherwise the distance of two disjoint convex
    sets, attained at a vertex of one of them: the segment's ends against the squares, the squares'
    corners against the segment.
    """
    if lows.shape[0] == 0:
        return np.full(a.shape[0], np.inf)
    lo, hi = lows[None, :, :], lows[None, :, :] + 1.0  # (1, S, 2)
    p, d = a[:, None, :], (b - a)[:, None, :]  # (N, 1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - p) / d, (hi - p) / d
    parallel = d == 0
    inside = (p >= lo) & (p <= hi)
    t_in = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_out = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    crosses = np.maximum(t_in.max(axis=2), 0.0) <= np.minimum(t_out.min(axis=2), 1.0)  # (N, S)

    def to_squares(q):
        gap = np.maximum(np.maximum(lo - q, q - hi), 0.0)
        return np.hypot(gap[..., 0], gap[..., 1])

    best = np.minimum(to_squares(p), to_squares(b[:, None, :]))
    length2 = np.maximum((d * d).sum(axis=2), 1e-300)  # (N, 1)
    corners = (lo, hi, np.concatenate([lo[..., :1], hi[..., 1:]], -1), np.concatenate([hi[..., :1], lo[..., 1:]], -1))
    for corner in corners:
        t = np.clip(((corner - p) * d).sum(axis=2) / length2, 0.0, 1.0)
        gap = p + t[..., None] * d - corner
        best = np.minimum(best, np.hypot(gap[..., 0], gap[..., 1]))
    return np.where(crosses, 0.0, best).min(axis=1)


def _tangents(terminals: np.ndarray, centres: np.ndarray, radius: float):
    """Candidate segments: ``(a, b, circle_a, circle_b)``, circle -1 at a terminal (ends listed as points)."""
    parts = []
    num_t, num_c = len(terminals), len(centres)
    ti, tj = np.triu_indices(num_t, 1)
    none = -np.ones(len(ti), int)
    parts.append((terminals[ti], terminals[tj], none, none, ti, tj))
    if num_c:
        # Terminal to circle: the two tangent points at angle phi +- acos(R / d) seen from the centre.
        t, c = (g.ravel() for g in np.meshgrid(np.arange(num_t), np.arange(num_c), indexing="ij"))
        offset = terminals[t] - centres[c]
        phi = np.arctan2(offset[:, 1], offset[:, 0])
        beta = np.arccos(np.clip(radius / np.hypot(offset[:, 0], offset[:, 1]), -1.0, 1.0))
        for sign in (-1.0, 1.0):
            angle = phi + sign * beta
            touch = centres[c] + radius * np.stack([np.cos(angle), np.sin(angle)], axis=1)
            parts.append((terminals[t], touch, -np.ones(len(t), int), c, t, -np.ones(len(t), int)))
        # Circle to circle (equal radii, at least 1 apart): two outer and two inner tangents.
        ci, cj = np.triu_indices(num_c, 1)
        gap = centres[cj] - centres[ci]
        dist = np.hypot(gap[:, 0], gap[:, 1])
        phi = np.arctan2(gap[:, 1], gap[:, 0])
        normal = np.stack([-gap[:, 1], gap[:, 0]], axis=1) / dist[:, None]
        minus = -np.ones(len(ci), int)
        for sign in (-1.0, 1.0):
            shift = sign * radius * normal
            parts.append((centres[ci] + shift, centres[cj] + shift, ci, cj, minus, minus))
            angle = phi + sign * np.arccos(np.clip(2 * radius / dist, -1.0, 1.0))
            arm = radius * np.stack([np.cos(angle), np.sin(angle)], axis=1)
            parts.append((centres[ci] + arm, centres[cj] - arm, ci, cj, minus, minus))
    return [np.concatenate(column) for column in zip(*parts)]


def tangent_graph(solid: np.ndarray, terminals: np.ndarray, radius: float) -> TangentGraph:
    """The tangent graph of ``solid`` ``(H, W)`` bool for ``terminals`` ``(T, 2)`` points (x, y) and ``radius``.

    Raises:
        ValueError: a radius outside ``(0, 1/2)`` (the quarter circles would meet) or a terminal whose
            disc does not fit where it stands.
    """
    solid = np.asarray(solid, bool)
    terminals = np.asarray(terminals, np.float64).reshape(-1, 2)
    if not 0.0 < radius < 0.5:
        raise ValueError(f"the path radius must lie in (0, 0.5) so that the disc fits a cell, got {radius!r}")
    height, width = solid.shape
    lows = np.stack(np.nonzero(solid)[::-1], axis=1).astype(np.float64)  # (S, 2) lower corners (x, y)
    clear = segment_clearance(terminals, terminals, lows)
    inside = np.all((terminals >= radius) & (terminals <= np.array([width, height]) - radius), axis=1)
    for index in np.nonzero((clear < radius - TOLERANCE) | ~inside)[0]:
        raise ValueError(f"terminal {index} at {tuple(terminals[index])} leaves no room for a disc of radius {radius}")
    centres, first = quarter_circles(solid)
    a, b, circle_a, circle_b, term_a, term_b = _tangents(terminals, centres, radius)

    lookup_centres, lookup_first = (centres, first) if len(centres) else (np.zeros((1, 2)), np.zeros(1))

    def on_quarter(point, circle):  # whether a tangent end lies on its quarter, and its angle there
        safe = np.maximum(circle, 0)
        offset = point - lookup_centres[safe]
        rel = np.mod(np.arctan2(offset[:, 1], offset[:, 0]) - lookup_first[safe] + np.pi, 2 * np.pi) - np.pi
        ok = (circle < 0) | ((rel >= -TOLERANCE) & (rel <= HALF_PI + TOLERANCE))
        return ok, np.clip(rel, 0.0, HALF_PI)

    ok_a, rel_a = on_quarter(a, circle_a)
    ok_b, rel_b = on_quarter(b, circle_b)
    limit = np.array([width, height]) - radius + TOLERANCE
    walls = np.all((np.minimum(a, b) >= radius - TOLERANCE) & (np.maximum(a, b) <= limit), axis=1)
    keep = ok_a & ok_b & walls
    keep[keep] = np.concatenate([segment_clearance(a[keep][i:i + CHUNK], b[keep][i:i + CHUNK], lows)
                                 for i in range(0, int(keep.sum()), CHUNK)] or [np.zeros(0)]) >= radius - TOLERANCE
    a, b, circle_a, circle_b, rel_a, rel_b = (x[keep] for x in (a, b, circle_a, circle_b, rel_a, rel_b))
    term_a, term_b = term_a[keep], term_b[keep]
    # Nodes: the terminals, then one per tangent end on a circle.
    num_t, num_seg = len(terminals), len(a)
    node_a = np.where(circle_a < 0, term_a, num_t + np.arange(num_seg))
    node_b = np.where(circle_b < 0, term_b, num_t + num_seg + np.arange(num_seg))
    xy = np.concatenate([terminals, a, b])
    circle = np.concatenate([-np.ones(num_t, int), circle_a, circle_b])
    angle = np.concatenate([np.zeros(num_t), rel_a, rel_b])
    lengths = np.hypot(*(b - a).T)
    rows, cols, weights = [node_a], [node_b], [lengths]
    # Arcs: consecutive points on each quarter circle (sorted by angle; a quarter never wraps).
    order = np.lexsort((angle, circle))
    order = order[circle[order] >= 0]
    same = circle[order[1:]] == circle[order[:-1]]
    rows.append(order[:-1][same])
    cols.append(order[1:][same])
    weights.append(radius * (angle[order[1:]] - angle[order[:-1]])[same])
    size = len(xy)
    matrix = sp.csr_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size))
    return TangentGraph(radius=float(radius), centres=centres, xy=xy, circle=circle, angle=angle, first=first,
                        matrix=matrix, num_terminals=num_t)


def distances_from(graph: TangentGraph, source: int) -> tuple[np.ndarray, np.ndarray]:
    """Shortest lengths from terminal ``source`` to every terminal ``(T,)`` and the predecessor of every node."""
    dist, pred = dijkstra(graph.matrix, directed=False, indices=source, return_predecessors=True)
    return dist[:graph.num_terminals], pred


def route(graph: TangentGraph, pred: np.ndarray, source: int, target: int, arc_step: float = np.pi / 8) -> np.ndarray:
    """The polyline ``(n, 2)`` from terminal ``source`` to ``target`` (``pred`` from :func:`distances_from`).

    Arcs become polylines that lie outside their circle (never inside the grown shelf): the tangent
    lines at angles ``arc_step`` apart, cut where neighbours meet (at radius ``R / cos(step / 2)``).
    """
    nodes = [target]
    while pred[nodes[-1]] >= 0:
        nodes.append(int(pred[nodes[-1]]))
    if nodes[-1] != source:
        raise ValueError(f"terminal {target} cannot be reached from terminal {source}")
    nodes.reverse()
    points = [graph.xy[nodes[0]]]
    for u, v in zip(nodes[:-1], nodes[1:]):
        circle = graph.circle[u]
        if circle >= 0 and circle == graph.circle[v] and graph.angle[u] != graph.angle[v]:
            a0, a1 = graph.angle[u], graph.angle[v]
            pieces = int(np.ceil(abs(a1 - a0) / arc_step))
            step = (a1 - a0) / pieces
            middles = graph.first[circle] + a0 + step * (np.arange(pieces) + 0.5)
            reach = graph.radius / np.cos(step / 2)
            points.extend(graph.centres[circle] + reach * np.stack([np.cos(middles), np.sin(middles)], axis=1))
        points.append(graph.xy[v])
    return np.asarray(points)


def polyline_length(points: np.ndarray) -> float:
    """Sum of the segment lengths of ``points`` ``(n, 2)``."""
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def item_legs(shelves: np.ndarray, start: np.ndarray, goal: np.ndarray, items: np.ndarray, radius: float,
              with_routes: bool = False, arc_step: float = np.pi / 8):
    """Exact shortest lengths start -> item ``(I,)`` and item -> goal ``(I,)`` for a disc of ``radius``.

    With ``with_routes`` also the polylines of both legs per item (``[(to_item, to_goal), ...]``).

    Raises:
        ValueError: from :func:`tangent_graph`, or an item the disc cannot reach.
    """
    terminals = np.concatenate([np.reshape(start, (1, 2)), np.reshape(goal, (1, 2)), np.reshape(items, (-1, 2))])
    graph = tangent_graph(shelves, terminals, radius)
    from_start, pred_start = distances_from(graph, 0)
    from_goal, pred_goal = distances_from(graph, 1)
    to_item, to_goal = from_start[2:], from_goal[2:]
    for index in np.nonzero(~np.isfinite(to_item + to_goal))[0]:
        raise ValueError(f"item {index} at {tuple(items[index])} cannot be reached by a disc of radius {radius}")
    if not with_routes:
        return to_item, to_goal
    routes = [(route(graph, pred_start, 0, 2 + i, arc_step), route(graph, pred_goal, 1, 2 + i, arc_step)[::-1])
              for i in range(len(items))]
    return to_item, to_goal, routes
