"""IPPO and MAPPO on EPyMARL's RWARE tasks, through the training command: the learning table of docs/rware.md.

Each (task, learner) pair is one ``python train_ppo.py --env <task>`` run with the ``rware`` preset
(``--critic local``: IPPO, the preset's own; ``--critic centralized``: MAPPO), all its seeds vmapped and
split over the host's devices (a pair already finished in ``--out`` is read, not retrained). The table reads each run's ``summary.json``: the greedy team's return (all
agents' rewards summed over a 500-step episode, EPyMARL's RWARE number) per seed, the seeds in which
every agent delivers in every episode, and the run's wall time; ``curves.csv`` has every run's periodic
evaluations with the training entropy.

Run from the repository root (7-17 minutes a pair alone on a 2-core CPU, 80 for the six)::

    .venv/bin/python bench/rware_learning.py --out runs/rware-learning
    .venv/bin/python bench/rware_learning.py --quick --out /tmp/rware_learning  # a smoke run
    .venv/bin/python bench/rware_learning.py --collect --out runs/rware-learning  # tabulate finished runs only
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("rware-tiny-2ag-v2", "rware-tiny-4ag-v2", "rware-small-4ag-v2")
LEARNERS = {"IPPO": ["--critic", "local"], "MAPPO": ["--critic", "centralized"]}
QUICK = ["--total-timesteps", "4096", "--num-envs", "4", "--num-steps", "16", "--hidden-sizes", "16", "16",
         "--eval-every", "4"]


def command_of(task: str, learner: str, out: Path, seeds: int, devices: int, quick: bool,
               tie_order: str | None = None) -> list[str]:
    order = ["--tie-order", tie_order] if tie_order else []
    return ["train_ppo.py", "--env", task, "--num-seeds", str(seeds), "--devices", str(devices),
            "--out", str(out / f"{task}-{learner.lower()}"), *LEARNERS[learner], *order, *(QUICK if quick else [])]


def run_pair(command: list[str]) -> None:
    done = subprocess.run([sys.executable, *command, "--overwrite", "--no-progress", "--no-plot"], cwd=ROOT,
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr[-3000:]}")


def read_pair(task: str, learner: str, command: list[str], run_dir: Path) -> dict:
    """One row of the table from a finished run's ``summary.json``."""
    summary = json.loads((run_dir / "summary.json").read_text())
    ev = summary["eval"]
    return {"task": task, "learner": learner, "command": " ".join(["python", *command]),
            "env_steps_per_seed": summary["env_steps_per_seed"], "wall_s": round(summary["wall_seconds"], 1),
            "compile_s": round(summary["compile_seconds"], 1), "env_steps_per_s": summary["env_steps_per_second"],
            "return": ev["return"], "return_ci95_over_seeds": ev["return_ci95_over_seeds"],
            "per_seed_return": [row["return"] for row in ev["per_seed"]],
            "deliveries": ev["deliveries"], "seeds_solved": ev["seeds_solved"], "seeds": len(ev["per_seed"])}


def write_curves(out: Path, run_dirs: list[Path]) -> None:
    """``curves.csv``: every periodic evaluation of every run (return, solved) beside the training entropy then."""
    with (out / "curves.csv").open("w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(["pair", "seed", "env_steps", "eval_return", "eval_solved", "entropy"])
        for run_dir in run_dirs:
            metrics = run_dir / "metrics.jsonl"
            rows = [json.loads(line) for line in metrics.read_text().splitlines()] if metrics.exists() else []
            rows = sorted((r for r in rows if r.get("eval_return") is not None),
                          key=lambda r: (r["env_steps"], r["seed"]))
            for r in rows:
                writer.writerow([run_dir.name, r["seed"], r["env_steps"], f"{r['eval_return']:.4f}",
                                 f"{r['eval_solved']:.1f}", f"{r['entropy']:.4f}"])


def table(rows: list[dict]) -> str:
    lines = ["| task | learner | greedy return (mean, 95 % CI over seeds) | per seed | seeds solved | wall |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        low, high = row["return_ci95_over_seeds"]
        span = "" if low is None else f" [{low:.1f}, {high:.1f}]"
        seeds = ", ".join(f"{value:.1f}" for value in row["per_seed_return"])
        lines.append(f"| {row['task']} | {row['learner']} | {row['return']:.1f}{span} | {seeds} | "
                     f"{row['seeds_solved']} of {row['seeds']} | {row['wall_s'] / 60:.1f} min |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for the runs, learning.json and learning.md")
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS), choices=list(LEARNERS))
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--devices", type=int, default=2, help="host devices the seeds are split over")
    parser.add_argument("--tie-order", choices=("set", "insertion"), default=None,
                        help="rware's tie order (default: the environment's, set; insertion: learning/earlier/standardized-insertion-order/)")
    parser.add_argument("--quick", action="store_true", help="tiny budgets: checks the tool, learns nothing")
    parser.add_argument("--collect", action="store_true", help="tabulate the runs already in --out, train nothing")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows, run_dirs = [], []
    for task in args.tasks:
        for learner in args.learners:
            command = command_of(task, learner, args.out, args.seeds, args.devices, args.quick, args.tie_order)
            run_dir = args.out / f"{task}-{learner.lower()}"
            if not (run_dir / "summary.json").exists():
                if args.collect:
                    continue
                run_pair(command)
            rows.append(read_pair(task, learner, command, run_dir))
            run_dirs.append(run_dir)
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    (args.out / "learning.json").write_text(json.dumps(rows, indent=1) + "\n")
    (args.out / "learning.md").write_text(table(rows) + "\n")
    write_curves(args.out, sorted(run_dirs))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
