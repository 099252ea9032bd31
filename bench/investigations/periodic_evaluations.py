"""Every periodic greedy evaluation of saved runs, per seed, gathered from their ``metrics.csv`` (issue 34).

A run of T steps reports what a longer run's periodic evaluation at T reports when nothing in the
configuration depends on the total (SAC's default: no annealing), so these tables say what a shorter
budget would have given on the same seeds, and how often a late evaluation solves the map.

    python bench/investigations/periodic_evaluations.py --from-steps 240000 \
        --variant stop_held RUN_0-3 RUN_4-7 ... --variant route_alone RUN ... --out FILE.json

Each variant's entry holds its runs' environment overrides (``config.json``), the number of seeds solved
at each evaluation (every item delivered, no contact), the late evaluations solved out of all, and every
evaluation per seed. Recorded in bench/results/continuous/NOTES.md.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path


def read_evaluations(run: Path, from_steps: int) -> dict[int, dict[int, dict]]:
    """``{env_steps: {seed: {solved, delivered, steps_per_item}}}`` of one run's periodic evaluations."""
    evaluations: dict[int, dict[int, dict]] = {}
    with open(run / "metrics.csv") as handle:
        for row in csv.DictReader(handle):
            if row["eval_solved"] == "" or int(row["env_steps"]) < from_steps:
                continue
            evaluations.setdefault(int(row["env_steps"]), {})[int(row["seed"])] = {
                "solved": float(row["eval_solved"]) > 0.5,
                "delivered": round(float(row["eval_success_rate"]), 4),
                "steps_per_item": round(float(row["eval_mean_steps"]), 3) if row["eval_mean_steps"] else None}
    return evaluations


def summarize(runs: list[Path], from_steps: int) -> dict:
    """One variant's runs (disjoint seeds) merged: overrides, solved per evaluation, late counts, the evaluations."""
    merged: dict[int, dict[int, dict]] = {}
    for run in runs:
        for steps, seeds in read_evaluations(run, from_steps).items():
            merged.setdefault(steps, {}).update(seeds)
    overrides = {json.dumps(json.loads((run / "config.json").read_text())["env_overrides"], sort_keys=True)
                 for run in runs}
    if len(overrides) != 1:
        raise SystemExit(f"the runs of one variant must share their environment overrides, got {sorted(overrides)}")
    steps = sorted(merged)
    return {"env_overrides": json.loads(overrides.pop()),
            "solved": {str(t): sum(e["solved"] for e in merged[t].values()) for t in steps},
            "late_solved": sum(e["solved"] for t in steps for e in merged[t].values()),
            "late_evaluations": sum(len(merged[t]) for t in steps),
            "per_evaluation": {str(t): {str(s): merged[t][s] for s in sorted(merged[t])} for t in steps}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", nargs="+", action="append", required=True, metavar=("NAME", "RUN"),
                        help="a name, then the run directories of that variant")
    parser.add_argument("--from-steps", type=int, default=0, help="the first evaluation kept (env steps per seed)")
    parser.add_argument("--out", type=Path, help="write the report here as JSON")
    args = parser.parse_args()
    report = {"from_steps": args.from_steps, "variants": {}}
    for name, *runs in args.variant:
        if not runs:
            raise SystemExit(f"--variant {name}: give at least one run directory")
        report["variants"][name] = summary = summarize([Path(run) for run in runs], args.from_steps)
        print(f"{name}: late evaluations solved {summary['late_solved']} of {summary['late_evaluations']}; "
              "solved per evaluation " + " ".join(f"{int(t) // 1000}k:{n}" for t, n in summary["solved"].items()))
    if args.out:
        args.out.write_text(json.dumps(report, separators=(",", ":")))


if __name__ == "__main__":
    main()
