"""Compile time and training speed under the XLA CPU settings the commands could use, in one run.

Each setting trains the same short runs with ``train_ppo.py`` (a fresh process each, so
every program is compiled from scratch: no compilation cache), in turns (A B C A B C ...)
so that a change of machine load falls on every setting alike. What is read back is the
run's ``summary.json``: compile seconds (the training program), training seconds (compile
apart), the final report's seconds (compile-dominated: many small programs) and the wall.

    python bench/xla_compile_flags.py [--repeats 2] [--out bench/results/xla_compile_flags.json]

Settings: XLA's defaults (LLVM level 3, the MLIR fusion emitters), LLVM level 1 (the
commands' default until 2026-12-02), and level 1 with the classic fusion emitter
(``--xla_cpu_use_fusion_emitters=false``, the commands' default since).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SETTINGS = {
    "xla defaults": "--xla_backend_optimization_level=3 --xla_cpu_use_fusion_emitters=true",
    "level 1": "--xla_backend_optimization_level=1 --xla_cpu_use_fusion_emitters=true",
    "level 1, classic emitter": "--xla_backend_optimization_level=1 --xla_cpu_use_fusion_emitters=false",
}

RUNS = {
    "Fleet-12x12-v0 (K = 4, 50 updates)": ["--env", "Fleet-12x12-v0", "--total-timesteps", "102400"],
    "Warehouse-12x12-v0 (200k steps)": ["--env", "Warehouse-12x12-v0", "--total-timesteps", "200000"],
}

FIELDS = ("compile_seconds", "train_seconds", "eval_seconds", "wall_seconds")


def train_once(args: list[str], flags: str, out: Path) -> dict:
    env = {**os.environ, "XLA_FLAGS": flags}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    command = [sys.executable, str(ROOT / "train_ppo.py"), *args, "--eval-every", "0", "--no-progress", "--no-plot",
               "--overwrite", "--out", str(out)]
    subprocess.run(command, env=env, check=True, capture_output=True, cwd=ROOT)
    summary = json.loads((out / "summary.json").read_text())
    return {field: summary[field] for field in FIELDS}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "xla_compile_flags.json")
    args = parser.parse_args(argv)
    samples = {run: {setting: [] for setting in SETTINGS} for run in RUNS}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for run, run_args in RUNS.items():
                for setting, flags in SETTINGS.items():
                    row = train_once(run_args, flags, Path(tmp) / "run")
                    samples[run][setting].append(row)
                    print(f"[{repeat}] {run} | {setting}: " + ", ".join(f"{k} {v:.1f}" for k, v in row.items()),
                          flush=True)
    table = {run: {setting: {field: statistics.median(r[field] for r in rows) for field in FIELDS}
                   for setting, rows in by_setting.items()} for run, by_setting in samples.items()}
    lines = ["| run | setting | compile s | train s | final report s | wall s | compile vs level 1 | train vs level 1 |",
             "|---|---|---|---|---|---|---|---|"]
    for run, by_setting in table.items():
        base = by_setting["level 1"]
        for setting, m in by_setting.items():
            lines.append(f"| {run} | {setting} | {m['compile_seconds']:.1f} | {m['train_seconds']:.1f} | "
                         f"{m['eval_seconds']:.1f} | {m['wall_seconds']:.1f} | "
                         f"{m['compile_seconds'] / base['compile_seconds']:.2f}x | "
                         f"{m['train_seconds'] / base['train_seconds']:.2f}x |")
    print("\n".join(lines))
    sys.path.insert(0, str(ROOT))
    from wrl_jax.cli.machine import cpu_info

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"settings": SETTINGS, "runs": RUNS, "repeats": args.repeats, "medians": table,
                                    "samples": samples, "machine": cpu_info(), "table": lines}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
