"""Maps from files: MovingAI ``.map`` files (the MAPF benchmarks) and this project's ASCII maps.

The MovingAI grid format::

    type octile
    height 4
    width 6
    map
    ..@@..
    ......

``@ O T W`` are blocked (out of bounds, trees, water), ``. G S`` free. A map
becomes a :class:`PaddedLayout` with the start, goal and items either given
(checked: on the floor, free, distinct, reachable, with a ``ValueError``
naming the cell) or drawn from a key by the generators' placement
(:func:`wrl_jax.envs.procedural.generators.place`: the start's component must
hold at least ``min_reach`` of the free cells; free cells it does not reach
become blocked, which changes nothing a robot can do).

Every malformed file is a ``ValueError`` naming the file and the line (and
the column for a bad cell) before anything compiles.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.procedural.draws import cell_words
from wrl_jax.envs.procedural.generators import GeneratorConfig, place
from wrl_jax.envs.procedural.layout import PaddedLayout, from_arrays
from wrl_jax.envs.warehouse.layout import parse

BLOCKED_CHARS = frozenset("@OTW")
FREE_CHARS = frozenset(".GS")
DRAW_ATTEMPTS = 16


def parse_movingai(text: str, source: str = "<string>") -> np.ndarray:
    """A MovingAI map's cells as ``(height, width)`` bool, True where blocked.

    Raises:
        ValueError: naming ``source`` and the 1-based line: a missing or
            misspelt header line, a type other than ``octile``, a height or
            width that is not a positive integer, too few or too many map rows,
            a row of the wrong length, an unknown character (with its column).
    """
    lines = text.splitlines()
    header = {}
    for number, (field, expect_value) in enumerate((("type", True), ("height", True), ("width", True),
                                                     ("map", False)), start=1):
        if number > len(lines):
            raise ValueError(f"{source}: ends at line {number - 1}; expected the header line {field!r}")
        words = lines[number - 1].split()
        if not words or words[0].lower() != field or len(words) != (2 if expect_value else 1):
            wanted = f"'{field} <value>'" if expect_value else f"'{field}'"
            raise ValueError(f"{source}, line {number}: expected {wanted}, got {lines[number - 1]!r}")
        if expect_value:
            header[field] = words[1]
    if header["type"].lower() != "octile":
        raise ValueError(f"{source}, line 1: map type {header['type']!r} is not supported; expected 'octile'")
    for number, field in ((2, "height"), (3, "width")):
        value = header[field]
        if not value.isdigit() or int(value) < 1:
            raise ValueError(f"{source}, line {number}: {field} must be a positive integer, got {value!r}")
    height, width = int(header["height"]), int(header["width"])
    rows = lines[4:]
    while rows and not rows[-1].strip():  # trailing blank lines are harmless
        rows.pop()
    if len(rows) != height:
        raise ValueError(f"{source}: the header says height {height} but the map has {len(rows)} rows "
                         f"(lines 5..{4 + len(rows)})")
    blocked = np.zeros((height, width), dtype=bool)
    for row, line in enumerate(rows):
        line = line.rstrip("\r\n")
        if len(line) != width:
            raise ValueError(f"{source}, line {row + 5}: map row {row} has {len(line)} cells, "
                             f"the header says width {width}")
        for col, char in enumerate(line):
            if char in BLOCKED_CHARS:
                blocked[row, col] = True
            elif char not in FREE_CHARS:
                raise ValueError(f"{source}, line {row + 5}, column {col + 1}: unknown character {char!r} "
                                 f"at cell {(row, col)}; expected one of '@OTW' (blocked) or '.GS' (free)")
    return blocked


def movingai_layout(blocked: np.ndarray, *, max_shape: tuple[int, int] | None = None, max_items: int = 8,
                    start=None, goal=None, items=None, num_items: int | None = None,
                    key: jax.Array | None = None, min_reach: float = 0.5, source: str = "map") -> PaddedLayout:
    """A blocked grid as a :class:`PaddedLayout`, with the cells given or drawn.

    Either give ``start``, ``goal`` and ``items`` (a list of cells), or give
    none of them and a ``key`` (and ``num_items``, default ``max_items``) to
    draw them. ``max_shape`` defaults to the map's own shape.
    """
    blocked = np.asarray(blocked, dtype=bool)
    given = [value is not None for value in (start, goal, items)]
    if all(given):
        return from_arrays(blocked, start, goal, np.asarray(items), max_shape, max_items, what=source)
    if any(given):
        raise ValueError(f"{source}: give all of start, goal and items, or none of them (and a key to draw them)")
    if key is None:
        raise ValueError(f"{source}: no start, goal and items given, and no key to draw them from")
    height, width = blocked.shape
    max_shape = (height, width) if max_shape is None else tuple(int(v) for v in max_shape)
    if height > max_shape[0] or width > max_shape[1]:
        raise ValueError(f"{source} is {height}x{width}, larger than max_shape {max_shape[0]}x{max_shape[1]}")
    num_items = max_items if num_items is None else int(num_items)
    if not 1 <= num_items <= max_items:
        raise ValueError(f"{source}: num_items must be in 1..max_items={max_items}, got {num_items}")
    config = GeneratorConfig(max_shape=max_shape, min_shape=(height, width), max_items=max_items,
                             items_on_pick_faces=False, min_reach=min_reach)
    padded = np.zeros(max_shape, dtype=bool)
    padded[:height, :width] = blocked
    floor = (jnp.asarray(padded), jnp.int32(height), jnp.int32(width))
    for attempt in range(DRAW_ATTEMPTS):
        layout, ok = _draw(jax.random.fold_in(key, attempt), floor, config, jnp.int32(num_items))
        if bool(ok):
            return layout
    raise ValueError(f"{source}: found no start in {DRAW_ATTEMPTS} draws whose reachable area holds "
                     f"{num_items + 2} cells and {min_reach:.0%} of the free floor; the map is too fragmented "
                     f"(lower min_reach or num_items)")


def _draw(key: jax.Array, floor, config: GeneratorConfig, num_items: jax.Array) -> tuple[PaddedLayout, jax.Array]:
    header = jax.random.bits(key, (16,), jnp.uint32)
    _, scores = cell_words(header, config.max_shape)
    return place(header, scores, floor, config, num_items)


_draw = jax.jit(_draw, static_argnames=("config",))


def is_movingai(path: str | Path, text: str) -> bool:
    """Whether a map file is read as MovingAI (a ``.map`` suffix, or a first line ``type ...``) rather than ASCII."""
    first = next((line for line in text.splitlines() if line.strip()), "")
    return Path(path).suffix.lower() == ".map" or first.split()[:1] == ["type"]


def load_map(path: str | Path, **kwargs) -> PaddedLayout:
    """A map file as a :class:`PaddedLayout`: MovingAI (a ``.map`` file, or first line ``type ...``) or ASCII.

    MovingAI maps take :func:`movingai_layout`'s keyword arguments. ASCII maps
    (``S`` ``G`` ``#`` ``.`` and item markers, ``wrl_jax.envs.warehouse.layout.parse``) carry
    their own start, goal and items; they take ``max_shape`` and ``max_items``.
    """
    path = Path(path)
    text = path.read_text()
    if is_movingai(path, text):
        return movingai_layout(parse_movingai(text, str(path)), source=str(path), **kwargs)
    unknown = sorted(set(kwargs) - {"max_shape", "max_items"})
    if unknown:
        raise ValueError(f"{path}: an ASCII map carries its own cells; unexpected argument(s) {unknown}")
    try:
        layout = parse(text)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    return from_arrays(np.asarray(layout.shelves, dtype=bool), layout.start, layout.goal, layout.items,
                       kwargs.get("max_shape"), kwargs.get("max_items"), what=str(path))
