"""Training with the CPU split into several XLA host devices: ``train_ppo.py --devices D`` for D = 1, 2, 4.

Why: XLA's CPU backend runs one device's program on (mostly) one thread, so on a 2-core machine a
one-device training run leaves most of the second core idle. ``--devices D`` (wrl_jax/cli/machine.py)
splits the CPU into ``D`` host devices before JAX starts and shards the seeds over them
(wrl_jax/training/sharding.py): each device trains its share of the seeds on its own thread.

Each case is ``train_ppo.py --env ENV --stop-after U --devices D`` in a subprocess of its own (so the
device count can differ), the environments' own default presets and 4 seeds, rounds interleaved
(every case once per round, so all see the same load). The time compared is ``train_seconds`` of
``summary.json``: the training updates alone, compile and the final evaluation apart (both reported).
The mean last-update return of the 4 seeds is recorded beside it: the sharded runs train the same
seeds, each seed in its own program (equal to float32 rounding, docs/scale.md), so it should agree.

    .venv/bin/python bench/host_devices.py            # writes bench/results/host_devices.json
    .venv/bin/python bench/host_devices.py --quick    # smoke run: one env, 20 updates, devices 1 and 2
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
ENVS = ("Warehouse-12x12-v0", "Procedural-Warehouse-v0", "Fleet-12x12-v0")


def train_once(env: str, devices: int, updates: int, out: Path) -> dict:
    """One ``train_ppo.py`` run in a subprocess without a device count in ``XLA_FLAGS``; its timings."""
    environ = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    command = [sys.executable, str(ROOT / "train_ppo.py"), "--env", env, "--stop-after", str(updates),
               "--devices", str(devices), "--no-progress", "--no-plot", "--out", str(out), "--overwrite"]
    done = subprocess.run(command, cwd=ROOT, env=environ, capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr[-3000:]}")
    summary = json.loads((out / "summary.json").read_text())
    with open(out / "metrics.csv") as handle:
        rows = list(csv.DictReader(handle))
    last = max(int(row["update"]) for row in rows)
    returns = [float(row["mean_return"]) for row in rows if int(row["update"]) == last and row.get("mean_return")]
    return {"train_seconds": summary["train_seconds"], "compile_seconds": summary["compile_seconds"],
            "eval_seconds": summary["eval_seconds"], "env_steps_per_second": summary["env_steps_per_second"],
            "updates": last, "last_update_mean_return": statistics.fmean(returns) if returns else None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", nargs="+", default=list(ENVS))
    parser.add_argument("--devices", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--updates", type=int, default=100, help="PPO updates per run (--stop-after)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=Path, default=RESULTS / "host_devices.json")
    args = parser.parse_args(argv)
    if args.quick:
        args.envs, args.devices, args.updates, args.repeats = ["Fleet-12x12-v0"], [1, 2], 20, 1
    runs: dict[str, dict[str, list[dict]]] = {env: {str(d): [] for d in args.devices} for env in args.envs}
    loads = []
    with tempfile.TemporaryDirectory(prefix="wrl-host-devices-") as scratch:
        for round_ in range(args.repeats):
            for env in args.envs:
                for devices in args.devices:
                    result = train_once(env, devices, args.updates, Path(scratch) / f"{env}-{devices}")
                    runs[env][str(devices)].append(result)
                    print(f"round {round_ + 1} {env} devices={devices}: train {result['train_seconds']:.1f} s, "
                          f"compile {result['compile_seconds']:.1f} s", flush=True)
            loads.append(list(os.getloadavg()))
    speedups = {}
    for env, by_devices in runs.items():
        base = statistics.median(r["train_seconds"] for r in by_devices[str(args.devices[0])])
        speedups[env] = {f"devices={d}": base / statistics.median(r["train_seconds"] for r in rows)
                         for d, rows in by_devices.items()}
    result = {"command": " ".join([".venv/bin/python", "bench/host_devices.py", *(argv or sys.argv[1:])]),
              "updates": args.updates, "runs": runs,
              "train_speedup_vs_first_device_count": speedups, "load_average_per_round": loads,
              "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version(),
                          "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(speedups, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
