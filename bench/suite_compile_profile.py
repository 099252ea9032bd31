"""Summarize a test run's compile profile (tests/compile_profile.py): where JAX's time goes, by module and function.

    python -m pytest -n 2 --dist loadscope --no-loadscope-reorder -p tests.compile_profile --compile-profile /tmp/prof
    python bench/suite_compile_profile.py /tmp/prof [--top 25]

Prints the totals (trace, lower, compile seconds and counts; compiles by duration), then the modules and the
jitted functions that cost most. A function compiled many times across modules is a candidate for sharing
one program (a module fixture, one static setting); many sub-50 ms compiles are eager operations.
"""

from __future__ import annotations

import argparse
import collections
import json
import re
from pathlib import Path

BINS = ((0.05, "< 0.05 s"), (0.2, "0.05-0.2 s"), (1.0, "0.2-1 s"), (3.0, "1-3 s"), (float("inf"), ">= 3 s"))


def function_name(name: str) -> str:
    """JAX names a function ``train`` in its trace event and ``jit(train)`` in its lowering and compile events."""
    match = re.fullmatch(r"\w+\((.*)\)", name)
    return match.group(1) if match else name


def load(folder: Path) -> list[tuple[str, str, str, float]]:
    events = []
    for path in sorted(folder.glob("*.json")):
        events += [(test, kind, function_name(function), duration)
                   for test, kind, function, duration in json.loads(path.read_text())]
    return events


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args()
    events = load(args.folder)
    if not events:
        raise SystemExit(f"{args.folder}: no profile (run pytest with -p tests.compile_profile --compile-profile DIR)")
    seconds, counts = collections.Counter(), collections.Counter()
    for _, kind, _, duration in events:
        seconds[kind] += duration
        counts[kind] += 1
    print("totals: " + ", ".join(f"{kind} {seconds[kind]:.1f} s ({counts[kind]})" for kind in sorted(seconds)))
    compiles = [duration for _, kind, _, duration in events if kind == "compile"]
    low = 0.0
    for high, label in BINS:
        inside = [d for d in compiles if low <= d < high]
        print(f"  compiles {label:>10}: {len(inside):5d}, {sum(inside):7.1f} s")
        low = high
    by_module, by_function = collections.defaultdict(collections.Counter), collections.defaultdict(collections.Counter)
    modules_of = collections.defaultdict(set)
    for test, kind, function, duration in events:
        module = test.split("::")[0]
        by_module[module][kind] += duration
        by_function[function][kind] += duration
        if kind == "compile":
            by_function[function]["n"] += 1
            modules_of[function].add(module)

    def cost(counter):
        return counter["trace"] + counter["lower"] + counter["compile"]

    print(f"\nmodules (trace + lower + compile seconds), top {args.top}:")
    for module, counter in sorted(by_module.items(), key=lambda kv: -cost(kv[1]))[: args.top]:
        print(f"  {cost(counter):7.1f}  compile {counter['compile']:6.1f}  trace {counter['trace']:5.1f}  {module}")
    print(f"\njitted functions (trace + lower + compile seconds; compiles; modules), top {args.top}:")
    for function, counter in sorted(by_function.items(), key=lambda kv: -cost(kv[1]))[: args.top]:
        print(f"  {cost(counter):7.1f}  {counter['n']:5d}  {len(modules_of[function]):3d}  {function}")


if __name__ == "__main__":
    main()
