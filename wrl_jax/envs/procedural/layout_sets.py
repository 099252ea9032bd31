"""The sets of layouts a procedural policy is judged on: held-out layouts of its own generator (checked
by hash against training), out-of-distribution sets, the study's maps, a MovingAI warehouse and map files.

Each is a :class:`LayoutSet` (a named batch of padded layouts); :func:`~wrl_jax.envs.procedural.evaluation.evaluate_sets`
runs them all in one compiled program. Every set is drawn from fixed keys of :data:`EVAL_SEED`, so every run
and every seed meets the same layouts.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.procedural.layout import PaddedLayout, from_layout, stack
from wrl_jax.envs.procedural.movingai import is_movingai, load_map, movingai_layout, parse_movingai
from wrl_jax.envs.procedural.pool import LayoutPool, disjoint_from, generate_pool, pool_hashes
from wrl_jax.envs.warehouse.layout import parse
from wrl_jax.envs.warehouse.maps import WAREHOUSE_8X8, WAREHOUSE_12X12

EVAL_SEED = 2026
FINAL_HELDOUT_LAYOUTS = 1024
"""Held-out layouts of the final evaluation (the key stream of ``fold_in(key(EVAL_SEED), 1)``)."""
OOD_LAYOUTS = 256
"""Layouts of each generated out-of-distribution set."""
MOVINGAI_DRAWS = 32
"""Start, goal and item placements drawn on :data:`MOVINGAI_WAREHOUSE` (one layout each)."""

MOVINGAI_WAREHOUSE = """type octile
height 15
width 16
map
................
.@@@@@@..@@@@@@.
.@@@@@@..@@@@@@.
................
.@@@@@@..@@@@@@.
.@@@@@@..@@@@@@.
................
.@@@@@@..@@@@@@.
.@@@@@@..@@@@@@.
................
..TT........TT..
................
.@@@@@@@@@@@@@@.
................
................
"""
"""A small warehouse in MovingAI's format (15x16: four double-depth shelf rows, pillars ``T``, a long rack).

Written here rather than downloaded (MovingAI's warehouse maps are far larger than a 16x16 policy can see).
"""


@dataclasses.dataclass(frozen=True)
class LayoutSet:
    """A named batch of layouts to evaluate on (``layouts``: a :class:`PaddedLayout` with a leading axis)."""

    name: str
    description: str
    layouts: PaddedLayout

    @property
    def size(self) -> int:
        return int(self.layouts.num_items.shape[0])


def pad_items(layouts: PaddedLayout, capacity: int) -> PaddedLayout:
    """A batch of layouts with ``capacity`` item rows (extra rows repeat item 0, as padding items do)."""
    extra = capacity - layouts.max_items
    if extra < 0:
        raise ValueError(f"layouts hold {layouts.max_items} item rows, more than the capacity {capacity}")
    if extra == 0:
        return layouts
    filler = jnp.repeat(layouts.items[:, :1], extra, axis=1)
    return layouts.replace(items=jnp.concatenate([layouts.items, filler], axis=1))


STUDY_MAPS = {"8x8": WAREHOUSE_8X8, "12x12": WAREHOUSE_12X12}


def study_layout(name: str, max_shape: tuple[int, int]) -> PaddedLayout:
    """The study's ``"8x8"`` or ``"12x12"`` map padded to ``max_shape``, every one of its items."""
    if name not in STUDY_MAPS:
        raise ValueError(f"unknown study map {name!r}; expected one of {sorted(STUDY_MAPS)}")
    return from_layout(parse(STUDY_MAPS[name]), max_shape)


def movingai_layouts(max_shape: tuple[int, int], draws: int | None = None, num_items: int = 8) -> PaddedLayout:
    """``draws`` (:data:`MOVINGAI_DRAWS`) placements of start, goal and items on :data:`MOVINGAI_WAREHOUSE`, padded."""
    draws = MOVINGAI_DRAWS if draws is None else int(draws)
    blocked = parse_movingai(MOVINGAI_WAREHOUSE, "MOVINGAI_WAREHOUSE")
    key = jax.random.fold_in(jax.random.key(EVAL_SEED), 2)
    return stack([movingai_layout(blocked, max_shape=max_shape, max_items=num_items, num_items=num_items,
                                  key=jax.random.fold_in(key, draw), source="MOVINGAI_WAREHOUSE")
                  for draw in range(draws)])


def ood_sets(generator, ood_layouts: int | None = None, long_routes: bool = True,
             names: Sequence[str] | None = None) -> list[LayoutSet]:
    """The out-of-distribution sets for a policy trained on ``generator``'s layouts (skipping what does not fit).

    - ``dense``: obstacle floors of a density above the training range (its top to 10 points over it);
    - ``narrow_shelves``: shelf floors at the maximum shape, one-cell aisles, no knocked-out shelves;
    - ``serpentine``, ``spiral``, ``comb`` (with ``long_routes``): the long-route families of
      :mod:`~wrl_jax.envs.procedural.route_floors` at the maximum shape, routes several times longer than
      the training families' (a test of planning);
    - ``study_8x8``, ``study_12x12``: the study's maps, padded, every item;
    - ``movingai``: :data:`MOVINGAI_WAREHOUSE` with :data:`MOVINGAI_DRAWS` drawn placements.

    ``names``: build only these sets (each generated family compiles its own generator), in the order above;
    a name that is not one of them, or a set that does not fit this generator, is a ``ValueError``.
    """
    if isinstance(names, str):
        raise ValueError(f"names must be a list of set names, got the string {names!r}")
    ood_layouts = OOD_LAYOUTS if ood_layouts is None else int(ood_layouts)
    key = jax.random.fold_in(jax.random.key(EVAL_SEED), 3)
    top = generator.density[1]
    height, width = generator.max_shape
    shape = f"{height}x{width}"

    def generated(index: int, config) -> PaddedLayout:
        return generate_pool(jax.random.fold_in(key, index), ood_layouts, config, stream="heldout").layouts

    dense = dataclasses.replace(generator, family="obstacles", density=(top, min(top + 0.1, 0.95)))
    narrow = dataclasses.replace(generator, family="shelves", min_shape=generator.max_shape, aisle=(1, 1),
                                 gap_rate=(0.0, 0.0))
    builders = {  # name -> (fits, description, layouts), built only when asked for
        "dense": (True, f"obstacle floors, density {dense.density[0]:.2f}..{dense.density[1]:.2f} "
                        f"(training {generator.density[0]:.2f}..{top:.2f})", lambda: generated(0, dense)),
        "narrow_shelves": (True, f"shelf floors at {shape}, one-cell aisles, no gaps", lambda: generated(1, narrow)),
    }
    for index, (family, what) in enumerate((
            ("serpentine", "parallel walls with one opening each, at alternating ends: one long snake"),
            ("spiral", "a corridor winding from an outer corner into the centre"),
            ("comb", "a spine corridor with long dead-end teeth, mostly hairpins")), start=2):
        config = dataclasses.replace(generator, family=family, min_shape=generator.max_shape)
        builders[family] = (long_routes, f"{family} floors at {shape}: {what}",
                            lambda index=index, config=config: generated(index, config))
    for name, side in (("8x8", 8), ("12x12", 12)):
        builders[f"study_{name}"] = (side <= min(height, width), f"the study's {name} map, padded, every item",
                                     lambda name=name: stack([study_layout(name, generator.max_shape)]))
    rows, cols = parse_movingai(MOVINGAI_WAREHOUSE).shape
    items = min(generator.max_items, 8)
    builders["movingai"] = (rows <= height and cols <= width,
                            f"a {rows}x{cols} MovingAI .map warehouse, {MOVINGAI_DRAWS} drawn placements of "
                            f"start, goal and {items} items",
                            lambda: movingai_layouts(generator.max_shape, num_items=items))
    unknown = sorted(set(names or ()) - set(builders))
    if unknown:
        raise ValueError(f"unknown out-of-distribution set(s) {unknown}; the sets are {list(builders)}")
    unfit = [name for name in names or () if not builders[name][0]]
    if unfit:
        raise ValueError(f"out-of-distribution set(s) {unfit} do not fit this generator (max_shape "
                         f"{shape}{'' if long_routes else ', long_routes=False'})")
    return [LayoutSet(name, what, build()) for name, (fits, what, build) in builders.items()
            if fits and (names is None or name in names)]


def layout_file_sets(paths: Sequence[str], max_shape: tuple[int, int], num_items: int = 8) -> list[LayoutSet]:
    """One :class:`LayoutSet` per map file, padded to ``max_shape`` (the run's observation), checked.

    ASCII maps carry their start, goal and items; a MovingAI map gets ``num_items``
    items (fewer if it is small) and a start and goal drawn from a fixed key.

    Raises:
        ValueError: naming the file: a missing file, a malformed map, or a floor
            larger than ``max_shape``, which the run's observation cannot represent.
    """
    sets = []
    for index, name in enumerate(paths):
        path = Path(name)
        if not path.is_file():
            raise ValueError(f"--layout {path}: no such file")
        text = path.read_text()
        try:
            if is_movingai(path, text):
                blocked = parse_movingai(text, str(path))
                if blocked.shape[0] > max_shape[0] or blocked.shape[1] > max_shape[1]:
                    raise ValueError(f"{path} is {blocked.shape[0]}x{blocked.shape[1]}, larger than max_shape "
                                     f"{max_shape[0]}x{max_shape[1]}")
                items = max(1, min(num_items, int((~blocked).sum()) - 2))
                layout = load_map(path, max_shape=max_shape, max_items=items, num_items=items,
                                  key=jax.random.fold_in(jax.random.key(EVAL_SEED), 4))
            else:
                layout = load_map(path, max_shape=max_shape)
        except ValueError as error:
            message = str(error)
            if "larger than max_shape" in message:
                message += (f"; the run's observation covers floors of at most {max_shape[0]}x{max_shape[1]} "
                            "(its environment's padded shape)")
            raise ValueError(message if str(path) in message else f"{path}: {message}") from None
        sets.append(LayoutSet(str(path) if str(path) not in {s.name for s in sets} else f"{path}#{index}",
                              f"{'MovingAI' if is_movingai(path, text) else 'ASCII'} map, "
                              f"{int(layout.height)}x{int(layout.width)}, {int(layout.num_items)} items",
                              stack([layout])))
    return sets


def heldout_set(generator, training: LayoutPool | np.ndarray, count: int | None = None) -> tuple[LayoutSet, int]:
    """``(set, overlap)``: ``count`` (:data:`FINAL_HELDOUT_LAYOUTS`) held-out layouts minus any training saw.

    ``training``: the training pool, or the hashes of every layout training saw (a refreshed pool:
    :meth:`~wrl_jax.envs.procedural.env.ProceduralWarehouse.training_layout_hashes`). ``overlap``
    counts the generated layouts whose hash is among them (dropped).
    """
    count = FINAL_HELDOUT_LAYOUTS if count is None else int(count)
    pool = generate_pool(jax.random.fold_in(jax.random.key(EVAL_SEED), 1), count, generator, stream="heldout")
    seen = pool_hashes(training) if isinstance(training, LayoutPool) else np.asarray(training, dtype=np.uint64)
    keep = disjoint_from(pool, seen)
    layouts = jax.tree.map(lambda leaf: leaf[np.flatnonzero(keep)], pool.layouts)
    overlap = int((~keep).sum())
    return LayoutSet("heldout", f"{int(keep.sum())} held-out layouts of the training generator "
                                f"(key stream disjoint from training; {overlap} shared by hash, dropped)",
                     layouts), overlap
