"""Does a better route field close the gap between the route rule and the pursuit controller? (issue 34)

SAC's default takes as many steps per item as the hand-written rule that follows the observed route
(``continuous_route_rule.py``: 96.4 on 12x12, pursuit 95.2). Three changes to the field the route is read
from, each timed by that rule on every item of both study maps, with and without the safety stop:

- ``exact``: the lattice's 16-connected distances replaced by exact any-angle lengths (the tangent graph of
  ``shortest_path.py`` for the route's radius, then from each lattice point the best of the straight line to
  the target and the tangents to every quarter circle, the arc to a graph node and that node's distance);
- ``spare``: the route's clearance beyond the robot's radius (``geodesic.SPARE``, 0.1 m) made smaller;
- ``lookahead``: the rule aims at the point reached by following the field for ``ahead`` metres (as pure
  pursuit aims ahead on its path) instead of along the local slope.

``python bench/investigations/continuous_route_field.py`` (about 3 minutes). Recorded in
bench/results/continuous/NOTES.md ("A better route field for the rule").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy.sparse.csgraph import dijkstra

from wrl_jax.envs.continuous import evaluation, geodesic
from wrl_jax.envs.continuous import shortest_path as paths
from wrl_jax.envs.continuous.registration import make_named

LATTICE_FIELDS = geodesic.distance_fields
CHUNK = 4096


def _clear(a: np.ndarray, b: np.ndarray, lows: np.ndarray, radius: float) -> np.ndarray:
    return np.concatenate([paths.segment_clearance(a[i:i + CHUNK], b[i:i + CHUNK], lows)
                           for i in range(0, len(a), CHUNK)] or [np.zeros(0)]) >= radius - paths.TOLERANCE


def exact_fields(shelves: np.ndarray, targets: np.ndarray, margin: float,
                 resolution: int = geodesic.RESOLUTION) -> np.ndarray:
    """``distance_fields`` with exact any-angle lengths on the routes (points off them filled as there)."""
    shelves, targets = np.asarray(shelves, bool), np.asarray(targets, np.float64)
    height, width = shelves.shape
    free = geodesic.free_lattice(shelves, margin, resolution)
    ys, xs = np.meshgrid(np.arange(free.shape[0]) / resolution, np.arange(free.shape[1]) / resolution, indexing="ij")
    on_routes = np.nonzero(free.ravel())[0]
    points = np.stack([xs.ravel(), ys.ravel()], 1)[on_routes]
    graph = paths.tangent_graph(shelves, targets, margin)
    lows = np.stack(np.nonzero(shelves)[::-1], axis=1).astype(np.float64)
    from_target = dijkstra(graph.matrix, directed=False, indices=np.arange(len(targets)))  # (K, nodes)
    best = np.stack([np.where(_clear(points, np.broadcast_to(t, points.shape), lows, margin),
                              np.hypot(*(points - t).T), np.inf) for t in targets])
    limit = np.array([width, height]) - margin + paths.TOLERANCE
    for circle, centre in enumerate(graph.centres):
        nodes = np.nonzero(graph.circle == circle)[0]
        if not len(nodes):
            continue
        offset = points - centre
        distance = np.hypot(offset[:, 0], offset[:, 1])
        beta = np.arccos(np.clip(margin / np.maximum(distance, 1e-12), -1.0, 1.0))
        for sign in (-1.0, 1.0):
            angle = np.arctan2(offset[:, 1], offset[:, 0]) + sign * beta
            touch = centre + margin * np.stack([np.cos(angle), np.sin(angle)], 1)
            rel = np.mod(angle - graph.first[circle] + np.pi, 2 * np.pi) - np.pi
            ok = (distance >= margin) & (rel >= -paths.TOLERANCE) & (rel <= paths.HALF_PI + paths.TOLERANCE)
            ok &= np.all((np.minimum(points, touch) >= margin - paths.TOLERANCE)
                         & (np.maximum(points, touch) <= limit), axis=1)
            index = np.nonzero(ok)[0]
            index = index[_clear(points[index], touch[index], lows, margin)]
            arc = margin * np.abs(np.clip(rel[index], 0, paths.HALF_PI)[:, None] - graph.angle[nodes][None, :])
            segment = np.hypot(*(points[index] - touch[index]).T)
            for k in range(len(targets)):
                via = segment + np.min(arc + from_target[k, nodes][None, :], axis=1)
                best[k, index] = np.minimum(best[k, index], via)
    fields = np.full((len(targets), free.size), np.inf)
    fields[:, on_routes] = best
    fields = geodesic._fill_off_routes(fields.reshape((len(targets),) + free.shape), free, resolution)
    return np.minimum(fields, geodesic.UNREACHABLE).astype(np.float32)


def _slope(field: jax.Array, pos: jax.Array) -> jax.Array:
    step = geodesic.ROUTE_STEP
    down = jnp.stack([geodesic.read_field(field, pos - jnp.array([step, 0.0]))
                      - geodesic.read_field(field, pos + jnp.array([step, 0.0])),
                      geodesic.read_field(field, pos - jnp.array([0.0, step]))
                      - geodesic.read_field(field, pos + jnp.array([0.0, step]))])
    length = jnp.sqrt(jnp.sum(down * down))
    return jnp.where(length > 0, down / jnp.maximum(length, 1e-12), 0.0)


def rule(env, params, ahead: float, pieces: int = 10):
    """The route rule (turn to the aim, drive at the cosine of the error), aiming ``ahead`` metres down the field."""
    size = jnp.array([env.width, env.height], jnp.float32)

    def act(obs, state):
        pos = obs[0:2] * size
        field = geodesic.target_field(params, obs[8:10] * size, obs[10] > 0.5)
        if ahead > 0:
            aim, _ = jax.lax.scan(lambda p, _: (p + (ahead / pieces) * _slope(field, p), None), pos, None,
                                  length=pieces)
            offset = aim - pos
        else:  # the observed route: the slope where the robot stands
            offset = _slope(field, pos)
        forward = offset[0] * obs[2] + offset[1] * obs[3]
        left = offset[1] * obs[2] - offset[0] * obs[3]
        error = jnp.arctan2(left, forward)
        return jnp.stack([jnp.clip(jnp.cos(error), 0.0, 1.0), jnp.clip(2.0 * error, -1.0, 1.0)])

    return act


def run(field: str, spare: float, ahead: float, stop: bool) -> str:
    geodesic.distance_fields = exact_fields if field == "exact" else LATTICE_FIELDS
    geodesic.SPARE = spare
    parts = []
    for name in ("8x8", "12x12"):
        env, params = make_named(name, shaping="geodesic", observe_route=True, safety_stop=stop)
        act = rule(env, params, ahead)
        result = jax.jit(lambda p: evaluation.evaluate_episodes(act, env, p))(params)
        valid = np.asarray(result.valid)
        delivered = np.asarray(result.delivered)[valid]
        steps = np.asarray(result.steps)[valid][delivered]
        parts.append(f"{name} {delivered.mean():.0%} delivered, {int(np.asarray(result.collisions)[valid].sum())} "
                     f"contacts, {steps.mean():.2f} steps")
    return f"{field:7s} spare {spare:.2f} ahead {ahead:.2f} {'stop   ' if stop else 'no stop'}: " + "; ".join(parts)


def main() -> None:
    spare = geodesic.SPARE
    both, stop_only = (False, True), (True,)
    for field, spare_, ahead, stops in (("lattice", spare, 0.0, both), ("exact", spare, 0.0, both),
                                        ("exact", 0.08, 0.0, both), ("exact", 0.06, 0.0, both),
                                        ("lattice", spare, 0.3, both), ("lattice", spare, 0.5, both),
                                        ("exact", spare, 0.3, stop_only), ("exact", 0.12, 0.5, stop_only),
                                        ("exact", 0.15, 0.5, stop_only), ("exact", 0.15, 0.7, stop_only)):
        for stop in stops:
            print(run(field, spare_, ahead, stop), flush=True)

if __name__ == "__main__":
    main()
