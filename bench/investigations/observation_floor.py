"""The memory floor of a fleet step's observations: write two ``(B, K, D)`` float32 arrays a step, sum them.

Why: at K = 8 the fleet step writes 640 bytes of observations a robot-step (``obs`` and
``final_obs``, 80 float32 values each) and ``bench/fleet_throughput.py`` reads them back for its
checksum. This program does only that, with values that cost nothing to make (a step-dependent
iota), in the same shape of program (a ``lax.scan`` over steps, the batch split over host devices
with ``shard_map``): its robot-steps/s is the most any fleet step could reach with those bytes.

    .venv/bin/python bench/investigations/observation_floor.py                       # K = 8, D = 80, 8 devices
    .venv/bin/python bench/investigations/observation_floor.py --devices 16 --batch 8192 32768
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
if str(ROOT / "bench") not in sys.path:
    sys.path.insert(0, str(ROOT / "bench"))

DEFAULT_DEVICES = 8

if __name__ == "__main__":
    from host_split import split_cpu_from_argv

    split_cpu_from_argv(sys.argv[1:], "--devices", DEFAULT_DEVICES)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, PartitionSpec as P  # noqa: E402


def floor_program(batch: int, robots: int, width: int, horizon: int, devices: int):
    """``(seeds (devices,)) -> (devices,)`` sums: ``horizon`` steps of writing and summing two observation arrays."""
    local_batch = batch // devices

    def local(seed):
        base = jax.lax.broadcasted_iota(jnp.int32, (local_batch, robots, width), 2) + seed[0]

        def step(total, t):
            obs = (base + t).astype(jnp.float32)
            final_obs = (base - t).astype(jnp.float32)
            return total + jnp.sum(obs) + jnp.sum(final_obs), None

        total, _ = jax.lax.scan(step, jnp.float32(0.0), jnp.arange(horizon))
        return total[None]

    mesh = Mesh(np.array(jax.devices()[:devices]), ("envs",))
    return jax.jit(jax.shard_map(local, mesh=mesh, in_specs=P("envs"), out_specs=P("envs"), check_vma=False))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[8192, 32768], help="fleets a step, all devices")
    parser.add_argument("--robots", type=int, default=8)
    parser.add_argument("--width", type=int, default=80, help="float32 values an observation row (80: V = 2)")
    parser.add_argument("--horizon", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--devices", type=int, default=DEFAULT_DEVICES,
                        help="host devices the CPU is split into (set before JAX starts) and the batch over")
    args = parser.parse_args(argv)
    devices = min(args.devices, len(jax.devices()))
    rows = []
    for batch in args.batch:
        if batch % devices:
            raise ValueError(f"batch {batch} does not split over {devices} devices")
        program = floor_program(batch, args.robots, args.width, args.horizon, devices)
        seeds = jnp.arange(devices)
        jax.block_until_ready(program(seeds))  # compile and warm up
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            jax.block_until_ready(program(seeds))
            times.append(time.perf_counter() - start)
        rate = batch * args.robots * args.horizon / statistics.median(times)
        rows.append({"batch": batch, "devices": devices, "robots": args.robots, "width": args.width,
                     "robot_steps_per_s": rate, "times_s": times})
        print(f"batch {batch:>6} over {devices} devices: {rate / 1e6:6.1f} M robot-steps/s "
              f"(writing and summing 2 x {args.width} float32 a robot-step)", flush=True)
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
