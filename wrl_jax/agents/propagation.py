"""A network that plans: value propagation over the map in the observation.

A multilayer perceptron sees a map as 768 unrelated numbers, and what it learns about
one floor's shelves does not carry over to another floor's (docs/procedural.md, run 16:
the full map made a 128x128 MLP worse). Planning is the same small rule applied at
every cell, so a network that generalizes over floors applies one small learned rule
at every cell too. This is the idea of value iteration networks (Tamar et al., 2016)
and of value propagation networks (Nardelli et al., 2019), written here in the min-plus
form of a shortest path with learned costs:

- a **cost map**: ``c = softplus(s (w * blocked + b))`` on free cells, with ``w`` a 3x3 kernel over
  the map's blocked channel (shelves and off-grid, and one cell of off-grid around the padded map),
  ``b`` a bias and ``s`` = :data:`COST_PARAMETER_SCALE`: what it costs to leave each cell. Learned;
  at initialization ``c = 1`` everywhere. Blocked cells are walls (cost :data:`BIG`: no path crosses
  them), the environment's rule built in: a learned finite shelf cost only grows as dear as the
  training floors' detours need, and on floors with longer detours the field then ran through walls;
- **propagation** from the target: ``u = 0`` on the target cell, ``-BIG`` elsewhere, then
  ``u <- max(u, max over the 4 neighbours of u - c)`` until nothing changes (or ``rounds`` times):
  ``u(s)`` is minus the cheapest cost of a path from ``s`` to the target, however long (``-BIG`` when
  there is none): a learned distance field, computed inside the network from the observed map;
- **features at the robot**: for each action, the value of the cell it leads to minus
  the best of the four (``0`` for the best move, clipped at ``-CLIP``; ``-BIG`` off the
  padded map), and the robot's own value (clipped, scaled). They join the rest of the
  observation (the window, the memory) as the input of the actor's and the critic's
  MLP, and the actor adds them to its logits with a learned weight (``prior``): a
  policy that can follow the learned field from its first update.

The observation has no distance field: only the map, the robot's and the target's cells.
The distance is the network's own computation, with learned costs, from the same
parameters on every floor. The actor owns the propagation; the critic reads the same
features (the value loss teaches the costs too). Gradients reach the costs along every
cell's path of best moves (:func:`propagate`'s custom backward pass, 7-14x cheaper than
autodiff through the rounds). The values depend only on the map and the target, fixed for
a leg of an episode, so callers propagate once per leg: :func:`map_features_by_run` (a
minibatch in time order) and :func:`map_features_cached` (a rollout or an evaluation).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from wrl_jax.core.grid import MOVES

BIG = 1.0e4
"""Minus the value of a cell no path joins to the target, and the cost of a blocked cell."""

CLIP = 16.0
"""The action features' floor: a move more than this much dearer than the best reads as ``-CLIP``."""

VALUE_SCALE = 64.0
"""The robot's own value enters the MLPs clipped at ``-VALUE_SCALE`` and divided by it."""

NUM_FEATURES = len(MOVES) + 1
"""What the propagation adds to an MLP's input: one feature per action, then the robot's value."""

COST_PARAMETER_SCALE = 5.0
"""The cost map's logit is this times its kernel and bias: the ten cost parameters learn this many times
faster under Adam (whose steps have about the learning rate's size whatever the gradient's) than the MLPs
(chosen when shelves' costs were learned too: at 1 they had grown too slowly, docs/procedural.md)."""

COST_RANGE = (0.01, 16.0)
"""Where a learned cost may lie. Above zero by a margin: a cost below a value's float32 spacing would
make two neighbours' values equal, and the backward pass's best moves could then run in a circle.
Bounded: a path of up to 256 cells then stays far above ``-BIG / 2``, the reached test."""

_UNIT_COST_BIAS = math.log(math.e - 1.0) / COST_PARAMETER_SCALE  # softplus = 1: every cell costs one move at first


def init_propagation() -> dict[str, jax.Array]:
    """The propagation's parameters: the 3x3 cost kernel, its bias, and the weight of the actor's prior
    (the action features added to its logits)."""
    return {
        "kernel": jnp.zeros((3, 3), jnp.float32),
        "bias": jnp.asarray(_UNIT_COST_BIAS, jnp.float32),
        "prior": jnp.asarray(1.0, jnp.float32),
    }


def shifted(x: jax.Array, d_row: int, d_col: int, fill: float) -> jax.Array:
    """``x`` read at ``(r + d_row, c + d_col)`` for every cell ``(r, c)`` of its last two axes; ``fill`` outside."""
    height, width = x.shape[-2:]
    padded = _bordered(x, fill)
    return padded[..., 1 + d_row : 1 + d_row + height, 1 + d_col : 1 + d_col + width]


def cost_map(params: dict[str, jax.Array], blocked: jax.Array, walls: bool = True) -> jax.Array:
    """``(..., H, W)`` float32 > 0: the learned cost of leaving each free cell, within ``COST_RANGE``;
    :data:`BIG` on blocked cells (shelves and off the map), which no path crosses. ``walls=False``: blocked
    cells get learned costs too (the encoder as it first was; docs/procedural.md has why it is not kept)."""
    logit = params["bias"]
    for i in range(3):
        for j in range(3):
            logit = logit + params["kernel"][i, j] * shifted(blocked, i - 1, j - 1, 1.0)
    cost = jnp.clip(jax.nn.softplus(COST_PARAMETER_SCALE * logit), *COST_RANGE)
    return jnp.where(blocked > 0.5, BIG, cost) if walls else cost


def neighbour(x: jax.Array, d_row: int, d_col: int) -> jax.Array:
    """``x`` read at ``(r + d_row, c + d_col)`` (one step, ``|d| <= 1``), its edge cells repeated outside.

    For the loops, on arrays with a border of their own (:func:`propagate` pads once): written
    as a concatenation, which XLA's CPU backend as the commands configure it
    (``--xla_cpu_use_fusion_emitters=false``) runs about 3x faster than a pad and a slice.
    """
    if d_row:
        inner = x[..., :-1, :] if d_row < 0 else x[..., 1:, :]
        edge = x[..., :1, :] if d_row < 0 else x[..., -1:, :]
        return jnp.concatenate([edge, inner] if d_row < 0 else [inner, edge], axis=-2)
    if d_col:
        inner = x[..., :-1] if d_col < 0 else x[..., 1:]
        edge = x[..., :1] if d_col < 0 else x[..., -1:]
        return jnp.concatenate([edge, inner] if d_col < 0 else [inner, edge], axis=-1)
    return x


def _bordered(x: jax.Array, fill: float) -> jax.Array:
    return jnp.pad(x, [(0, 0)] * (x.ndim - 2) + [(1, 1), (1, 1)], constant_values=fill)


def _repeat(step, x: jax.Array, rounds: int) -> jax.Array:
    """``step`` applied ``rounds`` times, or (``rounds == 0``) until ``x`` stops changing.

    Both loops here stop changing exactly: a round's output is a deterministic function of
    its input, so once a round leaves ``x`` as it was every later round would too. With
    positive costs a shortest path visits each cell once, so the values settle within
    the cells' number of rounds, the loop's bound.
    """
    if rounds:
        return jax.lax.fori_loop(0, rounds, lambda _, value: step(value), x)
    limit = x.shape[-2] * x.shape[-1]

    def again(carry):
        _, changed, count = carry
        return changed & (count < limit)

    def body(carry):
        value, _, count = carry
        new = step(value)
        return new, jnp.any(new != value), count + 1

    return jax.lax.while_loop(again, body, (x, jnp.array(True), jnp.int32(0)))[0]


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def propagate(cost: jax.Array, target: jax.Array, rounds: int = 0) -> jax.Array:
    """``(..., H, W)``: minus the cheapest cost of a path to the target (``-BIG``: none).

    ``rounds == 0``: until the values converge (every cell that has a path gets its
    value, however long the path); ``rounds > 0``: paths of at most ``rounds`` moves.
    Differentiable in ``cost`` (not in ``target``) by :func:`_propagate_backward`.
    """
    values, _ = _propagate_forward(cost, target, rounds)
    return values[..., 1:-1, 1:-1]


def _propagate_forward(cost: jax.Array, target: jax.Array, rounds: int) -> tuple[jax.Array, jax.Array]:
    """The values and the costs with a border of one cell (``-BIG`` and ``BIG``: never on a path)."""
    cost = _bordered(cost, BIG)
    values = _bordered(jnp.where(target > 0.5, 0.0, -BIG), -BIG)

    def one_round(values):
        best = neighbour(values, *MOVES[0])
        for d_row, d_col in MOVES[1:]:
            best = jnp.maximum(best, neighbour(values, int(d_row), int(d_col)))
        return jnp.maximum(values, best - cost)

    return _repeat(one_round, values, rounds), cost


def _propagate_fwd(cost, target, rounds):
    values, _ = _propagate_forward(cost, target, rounds)
    return values[..., 1:-1, 1:-1], (values, target)


def _cost_cotangent(values: jax.Array, target: jax.Array, cotangent: jax.Array, rounds: int) -> jax.Array:
    """The gradient of the values in the costs, by following every cell's best move.

    A reached cell's value is its best neighbour's minus its own cost, so it is minus the
    sum of the costs along the path of best moves from it to the target: ``d values(s) /
    d cost(x)`` is ``-1`` for each cell ``x`` on that path other than the target (``s``
    included), else ``0``. So ``cost``'s cotangent at ``x`` is minus the sum of
    ``cotangent(s)`` over the cells ``s`` whose path passes through ``x``: accumulated by
    pushing each cell's sum one move along its best move, round after round, until the
    sums stop changing (or for ``rounds`` rounds when the forward pass had that many).
    Autodiff through the forward loop instead (a scan storing every round) measured
    7-14x slower (``bench/propagation_speed.py``). Ties take the first best move in
    ``MOVES`` order (a subgradient). ``values`` bordered; the result is not.
    """
    candidates = jnp.stack([neighbour(values, int(r), int(c)) for r, c in MOVES])  # (4, ..., H + 2, W + 2)
    best_move = jnp.argmax(candidates, axis=0)
    on_a_path = (values > -BIG / 2) & (_bordered(target, 0.0) <= 0.5)  # reached, and not the target itself
    moving = [(best_move == a) & on_a_path for a in range(len(MOVES))]
    cotangent = _bordered(cotangent, 0.0)

    def one_round(through):
        total = cotangent
        for a, (d_row, d_col) in enumerate(MOVES):  # cell s moving by d hands its sum to s + d
            total = total + neighbour(jnp.where(moving[a], through, 0.0), -int(d_row), -int(d_col))
        return total

    through = _repeat(one_round, cotangent, rounds)
    return -jnp.where(on_a_path, through, 0.0)[..., 1:-1, 1:-1]


def _propagate_backward(rounds, residuals, cotangent):
    values, target = residuals
    return _cost_cotangent(values, target, cotangent, rounds), jnp.zeros_like(target)


propagate.defvjp(_propagate_fwd, _propagate_backward)


def _chunks(body, count: jax.Array, chunk: int, carry):
    """``body(start, carry)`` for ``start = 0, chunk, 2 chunk, ...`` while ``start < count``."""
    def again(state):
        return state[0] < count

    def step(state):
        start, carry = state
        return start + chunk, body(start, carry)

    return jax.lax.while_loop(again, step, (jnp.int32(0), carry))[1]


@functools.partial(jax.custom_vjp, nondiff_argnums=(3,))
def propagate_first(cost: jax.Array, target: jax.Array, count: jax.Array, chunk: int) -> jax.Array:
    """:func:`propagate` (until converged) of the first ``count`` maps of ``(N, H, W)``, ``chunk`` maps at a time.

    The rows from ``count`` on are left at ``-BIG`` (and get no gradient) unless they share a
    chunk with the last counted rows. ``N`` must be a multiple of ``chunk``. Differentiable in
    ``cost``: the backward pass runs chunk by chunk too. For batches where many rows share a
    map and a target (one leg of an episode), the caller propagates each distinct one once.
    """
    return _first_forward(cost, target, count, chunk)[..., 1:-1, 1:-1]


def _first_forward(cost, target, count, chunk):
    number, height, width = cost.shape
    if number % chunk:
        raise ValueError(f"propagate_first: {number} maps are not a multiple of the chunk {chunk}")

    def body(start, values):
        rows, _ = _propagate_forward(jax.lax.dynamic_slice_in_dim(cost, start, chunk),
                                     jax.lax.dynamic_slice_in_dim(target, start, chunk), 0)
        return jax.lax.dynamic_update_slice_in_dim(values, rows, start, 0)

    return _chunks(body, count, chunk, jnp.full((number, height + 2, width + 2), -BIG, cost.dtype))


def _first_fwd(cost, target, count, chunk):
    values = _first_forward(cost, target, count, chunk)
    return values[..., 1:-1, 1:-1], (values, target, count)


def _first_bwd(chunk, residuals, cotangent):
    values, target, count = residuals

    def body(start, grads):
        rows = _cost_cotangent(jax.lax.dynamic_slice_in_dim(values, start, chunk),
                               jax.lax.dynamic_slice_in_dim(target, start, chunk),
                               jax.lax.dynamic_slice_in_dim(cotangent, start, chunk), 0)
        return jax.lax.dynamic_update_slice_in_dim(grads, rows, start, 0)

    return _chunks(body, count, chunk, jnp.zeros_like(cotangent)), jnp.zeros_like(target), None


propagate_first.defvjp(_first_fwd, _first_bwd)


def robot_features(values: jax.Array, robot: jax.Array) -> jax.Array:
    """``(..., NUM_FEATURES)``: per action, the value it leads to relative to the best (in ``[-CLIP, 0]``),
    then the robot's own value (in ``[-1, 0]``). ``robot``: the map's one-hot channel of the robot's cell."""
    neighbours = jnp.stack(
        [(shifted(values, int(d_row), int(d_col), -BIG) * robot).sum(axis=(-2, -1)) for d_row, d_col in MOVES],
        axis=-1,
    )
    relative = jnp.clip(neighbours - neighbours.max(axis=-1, keepdims=True), -CLIP, 0.0)
    own = jnp.clip((values * robot).sum(axis=(-2, -1)), -VALUE_SCALE, 0.0) / VALUE_SCALE
    return jnp.concatenate([relative, own[..., None]], axis=-1)


def split_map(obs: jax.Array, layout: tuple[int, int, int]) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """``(rest, blocked, robot, target)``: the observation without its map, and the map's three channels.

    ``layout = (offset, H, W)``: the map's place in the observation, 3 channels of ``H x W``
    (blocked, the robot, the target), channel-major (``env.map_observation()``).
    """
    offset, height, width = layout
    end = offset + 3 * height * width
    grid = obs[..., offset:end].reshape(*obs.shape[:-1], 3, height, width)
    rest = jnp.concatenate([obs[..., :offset], obs[..., end:]], axis=-1)
    return rest, grid[..., 0, :, :], grid[..., 1, :, :], grid[..., 2, :, :]


def leg_key(obs: jax.Array, layout: tuple[int, int, int]) -> jax.Array:
    """``(..., 2 H W)``: what the values depend on, the blocked and target channels. Equal keys, equal
    values: within one leg of an episode (a map and a target) the propagation need not run again."""
    offset, height, width = layout
    cells = height * width
    return jnp.concatenate([obs[..., offset : offset + cells], obs[..., offset + 2 * cells : offset + 3 * cells]], -1)


def map_features(params: dict[str, jax.Array], obs: jax.Array, layout: tuple[int, int, int], rounds: int = 0,
                 walls: bool = True):
    """``(..., D - 3 H W + NUM_FEATURES)``: the MLPs' input, the observation without its map, then
    :func:`robot_features` of the values propagated over it with ``params``' costs (:func:`cost_map`)."""
    rest, blocked, robot, target = split_map(obs, layout)
    values = propagate(cost_map(params, blocked, walls), target, rounds)
    return jnp.concatenate([rest, robot_features(values, robot)], axis=-1)


def map_features_by_run(params: dict[str, jax.Array], obs: jax.Array, layout: tuple[int, int, int],
                        chunk: int = 16, walls: bool = True) -> jax.Array:
    """:func:`map_features` (converged) of ``(N, D)`` observations, one propagation per run of
    consecutive rows with the same :func:`leg_key`: a minibatch ordered by environment and time holds
    a few legs, not ``N`` maps. Equal to :func:`map_features` row by row, gradient included."""
    number = obs.shape[0]
    rest, blocked, robot, target = split_map(obs, layout)
    key = leg_key(obs, layout)
    starts = jnp.concatenate([jnp.ones((1,), bool), jnp.any(key[1:] != key[:-1], axis=-1)])
    run = jnp.cumsum(starts) - 1  # each row's run
    padded = -(-number // chunk) * chunk
    first = jnp.nonzero(starts, size=padded, fill_value=0)[0]  # each run's first row
    values = propagate_first(cost_map(params, blocked[first], walls), target[first], run[-1] + 1, chunk)
    return jnp.concatenate([rest, robot_features(values[run], robot)], axis=-1)


def init_leg_cache(obs: jax.Array, layout: tuple[int, int, int]) -> tuple[jax.Array, jax.Array]:
    """An empty cache for :func:`map_features_cached`: no row's key matches (the blocked channel is 0/1)."""
    _, height, width = layout
    key = jnp.full(leg_key(obs, layout).shape, -1.0, obs.dtype)
    return key, jnp.full((*obs.shape[:-1], height, width), -BIG, jnp.float32)


def map_features_cached(params: dict[str, jax.Array], obs: jax.Array, layout: tuple[int, int, int],
                        cache: tuple[jax.Array, jax.Array], chunk: int = 8, walls: bool = True):
    """``(features, cache)``: :func:`map_features` (converged) of ``(E, D)`` observations, propagating
    only the rows whose leg changed since the cache was made (``chunk`` at a time). For rollouts and
    evaluation, where a row is one environment over time: a leg lasts many steps. Not differentiable."""
    number = obs.shape[0]
    rest, blocked, robot, target = split_map(obs, layout)
    key = leg_key(obs, layout)
    cached_key, values = cache
    stale = jnp.any(key != cached_key, axis=-1)
    padded = -(-number // chunk) * chunk
    rows = jnp.nonzero(stale, size=padded, fill_value=number)[0]  # ``number``: no row (dropped)

    def body(start, values):
        index = jax.lax.dynamic_slice_in_dim(rows, start, chunk)
        safe = jnp.minimum(index, number - 1)
        fresh = propagate(cost_map(params, blocked[safe], walls), target[safe])
        return values.at[index].set(fresh, mode="drop")

    values = _chunks(body, jnp.sum(stale, dtype=jnp.int32), chunk, values)
    return jnp.concatenate([rest, robot_features(values, robot)], axis=-1), (key, values)


def action_features(inputs: jax.Array) -> jax.Array:
    """``(..., 4)``: the per-action features inside :func:`map_features`' output (the actor's prior)."""
    return inputs[..., -NUM_FEATURES:-1]


def propagation_forward_flops(height: int, width: int, rounds: int) -> int:
    """Floating-point operations of :func:`map_features` for one observation. The rounds dominate: per
    cell and round, the best of 4 neighbours (3 maxima), minus the cost, kept if better (5); then the
    cost map (9 multiply-adds and a softplus per cell) and the features (4 neighbours x a product and a sum)."""
    cells = height * width
    return cells * (rounds * 5 + 9 * 2 + 4 * 2 + 2)


def check_map_layout(layout: tuple[int, int, int] | None, env_name: str, obs_size: int) -> tuple[int, int, int]:
    """The environment's ``(offset, H, W)``, checked; a ``ValueError`` naming the env if it has no map."""
    if layout is None:
        raise ValueError(
            f"PPO encoder='propagation' plans over a map in the observation; {env_name} observes none "
            f"(Procedural-Warehouse-v0 with observe_map=True does: --observe-map True)"
        )
    offset, height, width = (int(v) for v in layout)
    if offset < 0 or offset + 3 * height * width > obs_size:
        raise ValueError(f"{env_name}'s map ({offset}, {height}, {width}) does not fit its {obs_size}-value observation")
    return offset, height, width

