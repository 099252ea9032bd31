"""The fleet's built-in maps (FLEET_SPEC.md format: several ``S`` starts, several ``G`` stations).

``FLEET_12X12`` is the study's 12x12 warehouse with eight start cells in the
top-left corner, twenty pick stations ``0-9a-j`` and one delivery station.

``FLEET_32X32`` is a shelf-block warehouse of our own design: 64 start cells
(the top two rows: a robot depot), five bands of four 2x6 shelf blocks
separated by 3-wide horizontal aisles and 2-wide vertical aisles, 40 pick
stations on the aisle cells above and below each block (the faces a picker
works from), and eight delivery stations (packing desks) along the bottom
wall. Robots leave the depot, fetch in the aisles and deliver at the bottom,
so traffic crosses the whole floor: the mean BFS round trip ``L*`` is 54.85
steps (21.0 on the 12x12 map; see ``docs/fleet.md``). Its shift is 512 steps,
about nine round trips a robot without traffic: long enough for congestion to
settle into a steady state, short enough to keep rollouts cheap.
"""

FLEET_12X12 = """
S S S S 0 . . . . . 5 .
S S S S . . . . . . . .
. 1 . . . . . 6 . . . .
. # # # # # # # # . 7 .
2 . . . . 3 . . . . . .
. . 4 . . . 8 . . . . 9
. a . # # # # # # # # .
. . . . . . . . . f . .
. . . . b . g . . . . .
. # # # # # # # . . h .
c . . d . . . i . . . .
. . . . . e . . . j . G
"""

FLEET_32X32 = """
S S S S S S S S S S S S S S S S S S S S S S S S S S S S S S S S
S S S S S S S S S S S S S S S S S S S S S S S S S S S S S S S S
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . 0 . . . . . . . 2 . . . . . . . 4 . . . . . . . 6 . . . .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. . . . 1 . . . . . . . 3 . . . . . . . 5 . . . . . . . 7 . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . 8 . . . . . . . a . . . . . . . c . . . . . . . e . . . .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. . . . 9 . . . . . . . b . . . . . . . d . . . . . . . f . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . g . . . . . . . i . . . . . . . k . . . . . . . m . . . .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. . . . h . . . . . . . j . . . . . . . l . . . . . . . n . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . o . . . . . . . q . . . . . . . s . . . . . . . u . . . .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. . . . p . . . . . . . r . . . . . . . t . . . . . . . v . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . w . . . . . . . y . . . . . . . A . . . . . . . C . . . .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. # # # # # # . . # # # # # # . . # # # # # # . . # # # # # # .
. . . . x . . . . . . . z . . . . . . . B . . . . . . . D . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . . . . . . . . . . . . . . . . . . . . . . . . . . . . . . .
. . G . . . G . . . G . . . G . . G . . . G . . . G . . . G . .
"""

MAX_STEPS = {"12x12": 256, "32x32": 512}
"""Shift length of each built-in map."""

MAPS = {"12x12": FLEET_12X12, "32x32": FLEET_32X32}
"""Built-in maps by size name (``Fleet-<name>-v0``)."""
