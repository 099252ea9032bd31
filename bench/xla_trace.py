"""Which of a compiled program's XLA fusions take its time: a ``jax.profiler`` trace, summed per fusion.

Why: a fleet step is some fifty fusions; timing parts alone (``fleet_step_profile.py --parts``) misses
what XLA fused across parts, and the aims of issue 14 are bounded by where the whole program spends
its time. Each call of the program runs under ``jax.profiler.trace``; the trace's complete events whose
name is an instruction of the compiled HLO are summed by name (over all devices of a split program, so
shares, not seconds, are what to read: with more devices than cores the events also count the time a
device's thread waits for a core). Each fusion is reported with its shape and the JAX operation XLA
names in its metadata.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import re
import tempfile
from typing import Any, Callable

import jax


def fusion_shares(compiled: Any, call: Callable[[], Any], calls: int = 3, top: int = 12) -> list[dict]:
    """The ``top`` instructions of ``compiled`` by traced time while ``call()`` runs ``calls`` times.

    Returns dicts ``{"name", "share", "shape", "op"}``, ``share`` of the time of all traced instructions
    of the program (loops excluded: their bodies' fusions are counted themselves).
    """
    hlo = compiled.as_text()
    with tempfile.TemporaryDirectory() as folder:
        jax.block_until_ready(call())  # warm, outside the trace
        with jax.profiler.trace(folder):
            for _ in range(calls):
                jax.block_until_ready(call())
        files = glob.glob(f"{folder}/**/*.trace.json.gz", recursive=True)
        if not files:
            raise RuntimeError(f"jax.profiler wrote no trace under {folder}")
        with gzip.open(files[0]) as handle:
            events = json.load(handle)["traceEvents"]
    spent: collections.Counter = collections.Counter()
    for event in events:
        if event.get("ph") == "X":
            spent[event["name"]] += event.get("dur", 0)
    rows = []
    for name, duration in spent.items():
        found = re.search(r"^\s*%" + re.escape(name) + r" = (\S+) ([\w-]+)\((.*)$", hlo, re.M)
        if found and found.group(2) not in ("while", "conditional", "call"):
            op = re.search(r'op_name="([^"]*)"', found.group(3))
            rows.append({"name": name, "time": duration, "shape": found.group(1).split("{")[0],
                         "op": op.group(1).split("/")[-1] if op else ""})
    total = sum(row["time"] for row in rows) or 1
    rows.sort(key=lambda row: -row["time"])
    return [{"name": row["name"], "share": row["time"] / total, "shape": row["shape"], "op": row["op"]}
            for row in rows[:top]]
