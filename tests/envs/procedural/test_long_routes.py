"""Long-route generator families (issue 33): serpentine, spiral and comb floors, and their out-of-distribution sets.

One batch per family (and one of the training mixture, the yardstick) is generated under ``jit`` + ``vmap``
once for the module; distances come from a NumPy BFS (a batched one here, checked against
``wrl_jax.envs.warehouse.layout.bfs_distances``), independent of the JAX flood fill.

Every long family's batch and drawn floors come out of ONE program (``_program``), compiled at LLVM level 0
(``fast_compile``: three programs at LLVM level 1 cost twice as much to compile). Level 0 suits them:
the layouts are checked for validity, connectivity and route lengths, never bit for bit against a program at
another level (generation draws a few fractions in float32, which another level may round otherwise);
the same-key test runs that program again, the determinism a user relies on. The mixture's batch, on the same keys, comes from the
default generator's 64-layout pool program in chunks (``_mixture``): the program of the other procedural
modules' 64-layout pools, which the session's cache serves.
"""

from __future__ import annotations

from types import SimpleNamespace

import fast_compile
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax.envs.procedural import generators as gen
from wrl_jax.envs.procedural import layout_sets
from wrl_jax.envs.procedural.draws import HEADER_WORDS, cell_words
from wrl_jax.envs.procedural.layout import stack
from wrl_jax.envs.procedural.layout_sets import study_layout
from wrl_jax.envs.procedural.pool import pool_from_keys, pool_hashes
from wrl_jax.envs.procedural.route_floors import long_floor_size
from wrl_jax.envs.warehouse.layout import bfs_distances

LONG = ("serpentine", "spiral", "comb")
NUM_LAYOUTS = 1024
SHORT_ROUTE = 43
"""About the longest start-to-target distance of the training families at 16x16."""


def _floors(key, family):
    """256 floors of ``family`` as drawn, before placement: ``(256, 16, 16)`` bool, off-grid cells blocked."""
    config = gen.GeneratorConfig(family=family)
    headers = jax.random.bits(key, (256, HEADER_WORDS), jnp.uint32)
    words = jax.vmap(lambda h: cell_words(h, config.max_shape)[0])(headers)
    shelves, height, width = jax.vmap(lambda h, w: gen.FLOORS[family](h, w, config))(headers, words)
    return shelves | ~jax.vmap(lambda h, w: gen.in_bounds_mask(h, w, config.max_shape))(height, width)


@fast_compile.jit
def _program(keys, floor_key):
    """``({long family: (layouts, attempts)}, {long family: floors})``: a batch per long family, one layout per
    key, and each long family's drawn floors."""
    batches = {family: jax.vmap(gen.generate_with_attempts, in_axes=(0, None))(keys, gen.GeneratorConfig(family=family))
               for family in LONG}
    return batches, {family: _floors(floor_key, family) for family in LONG}


def _keys():
    return jax.random.split(jax.random.key(33), NUM_LAYOUTS)


def _run():
    return jax.tree.map(np.asarray, _program(_keys(), jax.random.key(5)))


def _mixture(keys, chunk=64):
    """The training mixture's layouts, one per key, as NumPy: ``pool_from_keys`` of the default generator on
    chunks of 64 keys (the 64-layout pool program every procedural module compiles; each key's layout is
    drawn alone under ``vmap``, as in one batch of all the keys)."""
    parts = [pool_from_keys(keys[start:start + chunk], gen.GeneratorConfig()).layouts
             for start in range(0, len(keys), chunk)]
    return jax.tree.map(lambda *leaves: np.concatenate([np.asarray(leaf) for leaf in leaves]), *parts)


def numpy_bfs(blocked: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """BFS distances ``(N, H, W)`` from each layout's source over its free cells, -1 where unreachable."""
    free = ~blocked
    dist = np.full(blocked.shape, -1, dtype=np.int32)
    frontier = np.zeros_like(free)
    frontier[np.arange(len(sources)), sources[:, 0], sources[:, 1]] = True
    dist[frontier] = 0
    layer = 0
    while frontier.any():
        layer += 1
        grown = np.zeros_like(frontier)
        grown[:, 1:] |= frontier[:, :-1]
        grown[:, :-1] |= frontier[:, 1:]
        grown[:, :, 1:] |= frontier[:, :, :-1]
        grown[:, :, :-1] |= frontier[:, :, 1:]
        frontier = grown & free & (dist < 0)
        dist[frontier] = layer
    return dist


@pytest.fixture(scope="module")
def generated():
    """``_program``'s outputs as NumPy."""
    return _run()


@pytest.fixture(scope="module")
def batches(generated):
    """``{family: (layouts as NumPy, attempts, from_start, from_goal)}`` for the long families and the mixture
    (its attempts ``None``: no test reads them)."""
    drawn = {"mixture": (_mixture(_keys()), None), **generated[0]}
    return {family: (layouts, attempts, numpy_bfs(layouts.blocked, layouts.start),
                     numpy_bfs(layouts.blocked, layouts.goal)) for family, (layouts, attempts) in drawn.items()}


def _item_distances(layouts, from_start, from_goal):
    """``(d(start, item), d(item, goal), real)``, each ``(N, I)``."""
    rows = np.arange(len(layouts.start))[:, None]
    items_r, items_c = layouts.items[..., 0], layouts.items[..., 1]
    real = np.arange(layouts.items.shape[1])[None, :] < layouts.num_items[:, None]
    return from_start[rows, items_r, items_c], from_goal[rows, items_r, items_c], real


def test_the_families_are_registered():
    assert set(LONG) <= set(gen.FAMILIES) and set(LONG) <= set(gen.FLOORS)
    assert gen.GeneratorConfig(family="spiral").family == "spiral"
    with pytest.raises(ValueError, match="unknown generator family"):
        gen.GeneratorConfig(family="labyrinth")


@pytest.mark.parametrize("family", LONG)
def test_layouts_are_valid_and_solvable(batches, family):
    layouts, _, from_start, from_goal = batches[family]
    n = len(layouts.start)
    assert layouts.blocked.shape == (n, 16, 16)
    # Large floors: 3/4 of the maximum shape per axis, up to all of it.
    for sizes in (layouts.height, layouts.width):
        assert sizes.min() == 12 and sizes.max() == 16
    rows, cols = np.arange(16)[None, :, None], np.arange(16)[None, None, :]
    off_grid = (rows >= layouts.height[:, None, None]) | (cols >= layouts.width[:, None, None])
    assert layouts.blocked[off_grid].all()
    to_start, to_goal, real = _item_distances(layouts, from_start, from_goal)
    assert (from_start[np.arange(n), layouts.goal[:, 0], layouts.goal[:, 1]] > 0).all()
    assert (to_start[real] > 0).all() and (to_goal[real] > 0).all()
    assert ((from_start >= 0) == ~layouts.blocked).all()  # every free cell is reachable
    for index in range(0, n, 97):  # distinct marked cells; the batched BFS agrees with the study's BFS
        count = layouts.num_items[index]
        cells = {tuple(layouts.start[index]), tuple(layouts.goal[index])}
        cells |= {tuple(cell) for cell in layouts.items[index][:count]}
        assert len(cells) == count + 2
        np.testing.assert_array_equal(from_start[index], bfs_distances(layouts.blocked[index],
                                                                       tuple(layouts.start[index])))


@pytest.mark.parametrize("family", LONG)
def test_floors_are_connected_before_placement(generated, family):
    """The drawn floors themselves are connected: placement never has to fill a pocket (whole walls, no gaps)."""
    blocked = generated[1][family]
    free = ~blocked
    first = np.argmax(free.reshape(len(free), -1), axis=1)
    reached = numpy_bfs(blocked, np.stack([first // 16, first % 16], axis=1)) >= 0
    assert (reached == free).all()
    assert blocked.mean() > 0.2  # the walls are there


def test_routes_are_several_times_longer_than_the_training_mixture(batches):
    means, longest = {}, {}
    for family, (layouts, _, from_start, from_goal) in batches.items():
        to_start, to_goal, real = _item_distances(layouts, from_start, from_goal)
        route = np.where(real, to_start + to_goal, 0)
        means[family] = (route.sum(axis=1) / real.sum(axis=1)).mean()
        longest[family] = max(to_start[real].max(), to_goal[real].max())
    assert longest["mixture"] <= SHORT_ROUTE
    for family in LONG:  # measured: mixture 17.3; serpentine 59, spiral 60, comb 38 (4,000 layouts each)
        assert means[family] >= 2 * means["mixture"], (family, means)
    for family in ("serpentine", "spiral"):  # measured at most 117 and 136 (4,000 layouts)
        assert longest[family] > 2 * SHORT_ROUTE, (family, longest)


@pytest.fixture(scope="module")
def again():
    """``_program`` run again on the same keys."""
    return _run()


@pytest.mark.parametrize("family", LONG)
def test_same_key_same_layout_and_keys_differ(batches, again, family):
    layouts, _ = again[0][family]
    for a, b in zip(jax.tree.leaves(layouts), jax.tree.leaves(batches[family][0])):
        np.testing.assert_array_equal(a, b)
    hashes = pool_hashes(jax.tree.map(jnp.asarray, layouts))
    assert len(np.unique(hashes)) >= 0.99 * NUM_LAYOUTS


@pytest.mark.parametrize("family", LONG)
def test_the_repair_is_rare(batches, family):
    attempts = batches[family][1]
    assert attempts.min() >= 1 and attempts.max() <= gen.GeneratorConfig().max_attempts
    assert np.mean(attempts == gen.GeneratorConfig().max_attempts) < 0.01


def test_ood_sets_hold_the_long_route_sets_unless_told_not_to_and_build_only_those_named(monkeypatch):
    """The sets and the generators they are drawn from (test_procedural's final report generates them for real)."""
    calls = []

    def fake_pool(key, count, config, stream="train"):
        calls.append((config, stream, tuple(np.asarray(jax.random.key_data(key)).tolist())))
        return SimpleNamespace(layouts=stack([study_layout("8x8", config.max_shape)] * count))

    monkeypatch.setattr(layout_sets, "generate_pool", fake_pool)
    monkeypatch.setattr(layout_sets, "MOVINGAI_DRAWS", 1)
    generator = gen.GeneratorConfig()
    sets = {s.name: s for s in layout_sets.ood_sets(generator, 16)}
    assert list(sets)[:5] == ["dense", "narrow_shelves", *LONG]
    configs = {config.family: config for config, _, _ in calls}
    for family in LONG:
        assert sets[family].size == 16 and sets[family].description.startswith(f"{family} floors at 16x16")
        assert configs[family] == gen.GeneratorConfig(family=family, min_shape=(16, 16))
    assert all(stream == "heldout" for _, stream, _ in calls) and len({key for *_, key in calls}) == len(calls)
    # The existing sets keep their keys: dense is fold_in(fold_in(key(EVAL_SEED), 3), 0).
    dense_key = jax.random.fold_in(jax.random.fold_in(jax.random.key(layout_sets.EVAL_SEED), 3), 0)
    assert calls[0][2] == tuple(np.asarray(jax.random.key_data(dense_key)).tolist())
    # At min_shape = max_shape the long-route floors fill the maximum shape.
    height, width = jax.jit(lambda key: jax.vmap(lambda h: long_floor_size(h, configs["spiral"]))(  # one program
        jax.random.bits(key, (8, HEADER_WORDS), jnp.uint32)))(jax.random.key(1))
    assert (np.asarray(height) == 16).all() and (np.asarray(width) == 16).all()
    calls.clear()
    without = [s.name for s in layout_sets.ood_sets(generator, 16, long_routes=False)]
    assert not set(LONG) & set(without) and without[:2] == ["dense", "narrow_shelves"] and len(calls) == 2
    # Only the sets asked for are built (and generated with the keys they have in the full list).
    calls.clear()
    chosen = layout_sets.ood_sets(generator, 16, names=["spiral", "study_12x12"])
    assert [s.name for s in chosen] == ["spiral", "study_12x12"] and [c[0].family for c in calls] == ["spiral"]
    assert chosen[0].description == sets["spiral"].description
    spiral_key = jax.random.fold_in(jax.random.fold_in(jax.random.key(layout_sets.EVAL_SEED), 3), 3)
    assert calls[0][2] == tuple(np.asarray(jax.random.key_data(spiral_key)).tolist())
    with pytest.raises(ValueError, match=r"unknown out-of-distribution set\(s\) \['spirals'\]"):
        layout_sets.ood_sets(generator, 16, names=["spirals"])
    with pytest.raises(ValueError, match=r"set\(s\) \['spiral'\] do not fit this generator"):
        layout_sets.ood_sets(generator, 16, long_routes=False, names=["spiral"])
    with pytest.raises(ValueError, match="a list of set names"):
        layout_sets.ood_sets(generator, 16, names="spiral")
