"""The tools of ``bench/`` run and compare what they say they compare (tiny sizes: a smoke test).

``fleet_step_profile.py --devices N`` splits the batch over N host devices (the split the throughput aims
are measured in) and, with ``--baseline``, times an older copy of the env beside the current one;
``--trace`` lists the compiled program's fusions by share of traced time (``bench/xla_trace.py``);
``pibt_profile.py --baseline`` times an older planners.py and refuses one that plans other moves;
``observation_floor.py`` sums exactly the observation-sized arrays it writes; ``continuous_randomization.py``
widens the randomization ranges as it says; ``periodic_evaluations.py`` counts what the runs' metrics say.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path

import forked
import pytest

ROOT = Path(__file__).resolve().parents[2]


TOOL_RUNS = {
    "step_profile": ["bench/investigations/fleet_step_profile.py", "--robots", "2", "--batch", "16", "--devices", "2",
                     "--horizon", "4", "--repeats", "1", "--parts", "core", "obs", "--baseline",
                     "wrl_jax/envs/fleet/env.py", "--trace"],
    "observation_floor": ["bench/investigations/observation_floor.py", "--batch", "8", "--devices", "2", "--horizon",
                          "2", "--repeats", "1"],
}
"""The command lines run as a user runs them: each splits the CPU into host devices before it starts JAX."""

@pytest.fixture(scope="module")
def tool_runs(tmp_path_factory):
    """``{name: CompletedProcess}`` of :data:`TOOL_RUNS`, run at once, each in a process forked by one interpreter
    that loaded what both load before JAX (:mod:`forked`)."""
    folder = tmp_path_factory.mktemp("tools")
    runs = {name: {"argv": argv, "out": str(folder / f"{name}.out"), "err": str(folder / f"{name}.err")}
            for name, argv in TOOL_RUNS.items()}
    (codes,) = forked.launch([list(runs.values())], timeout=300)
    return {name: subprocess.CompletedProcess(run["argv"], code, Path(run["out"]).read_text(),
                                              Path(run["err"]).read_text())
            for (name, run), code in zip(runs.items(), codes)}


def test_step_profile_splits_over_devices_and_times_a_baseline(tool_runs):
    done = tool_runs["step_profile"]
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["devices"] == 2
    for fusions in report["top_fusions"].values():  # --trace: the program's own fusions, by share of time
        assert fusions and all(0 < row["share"] <= 1 and row["name"] for row in fusions)
        assert sum(row["share"] for row in fusions) <= 1 + 1e-9
    rows = {(row["impl"], row["part"]): row for row in report["rows"]}
    assert set(rows) == {(impl, part) for impl in ("current", "baseline") for part in ("core", "obs")}
    for part in ("core", "obs"):  # the same program on the same inputs: the same checksum
        assert rows[("current", part)]["checksum"] == rows[("baseline", part)]["checksum"]
    assert "ratio current/baseline" in done.stdout


def test_pibt_profile_refuses_a_baseline_that_plans_other_moves(tmp_path, capsys, monkeypatch):
    """Both runs profile the same recorded fleet states (same sizes, same seed): the tool's rollout that records
    them is run once, for the first, and its NumPy arrays handed to the second."""
    sys.path.insert(0, str(ROOT / "bench" / "investigations"))
    from pibt_profile import main as pibt_profile

    import fleet_throughput

    monkeypatch.setattr(fleet_throughput, "recorded_states", functools.cache(fleet_throughput.recorded_states))

    source = (ROOT / "wrl_jax/envs/fleet/planners.py").read_text()
    same = tmp_path / "same.py"
    same.write_text(source)
    assert pibt_profile(["--robots", "2", "--batch", "32", "--repeats", "1", "--baseline", str(same)]) == 0
    assert "same moves" in capsys.readouterr().out
    other = tmp_path / "other.py"  # a planner that always waits
    other.write_text(source.replace("    return pibt_choices(candidate_ids(pos, size), cand_dist, priority)",
                                    "    return jnp.full(pos.shape[0], WAIT, dtype=jnp.int32)"))
    assert other.read_text() != source
    with pytest.raises(AssertionError, match="plans other moves"):
        pibt_profile(["--robots", "2", "--batch", "32", "--repeats", "1", "--baseline", str(other)])


def test_observation_floor_sums_what_it_writes_and_splits_over_devices(tool_runs):
    """``bench/investigations/observation_floor.py``: the written arrays are summed exactly (checked against NumPy in this
    process, one device) and the command line splits the batch over host devices."""
    sys.path.insert(0, str(ROOT / "bench" / "investigations"))
    import numpy as np

    from observation_floor import floor_program

    batch, robots, width, horizon = 4, 3, 5, 6
    total = float(floor_program(batch, robots, width, horizon, devices=1)(np.arange(1))[0])
    base = np.broadcast_to(np.arange(width), (batch, robots, width))
    expected = sum(float((base + t).sum() + (base - t).sum()) for t in range(horizon))
    assert total == expected
    done = tool_runs["observation_floor"]
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout.strip().splitlines()[-1])
    assert rows[0]["devices"] == 2 and rows[0]["robot_steps_per_s"] > 0


def test_randomization_bench_widens_every_range_around_its_centre():
    """``bench/continuous_randomization.py``'s test conditions: off, the contract's ranges, each 1.5x as wide."""
    import numpy as np

    sys.path.insert(0, str(ROOT / "bench"))
    import continuous_randomization as bench

    import wrl_jax

    _, params = wrl_jax.make("Continuous-Warehouse-8x8-v0")
    cases = bench.conditions(params)
    assert list(cases) == ["nominal", "1x", "1.5x"]
    assert not bool(cases["nominal"].randomize) and bool(cases["1x"].randomize) and bool(cases["1.5x"].randomize)
    wide = cases["1.5x"]
    np.testing.assert_allclose([float(wide.gain_low), float(wide.gain_high)], [0.7, 1.3], rtol=1e-6)
    for name, value in (("actuation_noise", 0.075), ("lidar_noise", 0.03), ("lidar_dropout", 0.03)):
        np.testing.assert_allclose(float(getattr(wide, name)), value, rtol=1e-6)
    assert float(wide.start_jitter) == float(params.start_jitter)  # capped by the start cell: see the bench
    assert float(cases["1x"].gain_low) == float(params.gain_low)


def test_randomization_bench_reuses_only_the_run_it_would_train(tmp_path):
    """A finished run in ``--out`` is evaluated again only if learner, map, seeds and every environment option the
    command gives today are the asked ones (a run from before a default changed is refused)."""
    sys.path.insert(0, str(ROOT / "bench"))
    import continuous_randomization as bench
    from wrl_jax.cli.options import parse

    def saved(name, overrides):
        run = tmp_path / name
        run.mkdir()
        (run / "config.json").write_text(json.dumps({
            "algo": "sac", "env": "Continuous-Warehouse-12x12-v0", "env_overrides": overrides,
            "seeds": [0, 1, 2, 3], "config": {"total_timesteps": 400_000}}))
        (run / "summary.json").write_text(json.dumps({"wall_seconds": 412.5}))
        return run

    today = parse("sac", ["--env", "Continuous-Warehouse-12x12-v0", "--randomize", "True"]).env.overrides()
    run = saved("randomized", today)
    assert bench.train("sac", "Continuous-Warehouse-12x12-v0", run, 0, 4, True, None) == 412.5
    assert bench.train("sac", "Continuous-Warehouse-12x12-v0", run, 400_000, 4, True, None) == 412.5
    for other in (("td3", "Continuous-Warehouse-12x12-v0", run, 0, 4, True, None),
                  ("sac", "Continuous-Warehouse-12x12-v0", run, 0, 4, False, None),
                  ("sac", "Continuous-Warehouse-12x12-v0", run, 200_000, 4, True, None),
                  ("sac", "Continuous-Warehouse-12x12-v0", saved("older", {**today, "escape_after": 10}), 0, 4, True,
                   None)):
        with pytest.raises(SystemExit, match="holds another run"):
            bench.train(*other)


def test_rware_learning_passes_the_tie_order_only_when_asked():
    """The learning table's older rows need ``--tie-order insertion``; without the flag the environment's own order."""
    sys.path.insert(0, str(ROOT / "bench"))
    from rware_learning import command_of

    ippo = command_of("rware-tiny-4ag-v2", "IPPO", Path("/tmp/x"), 4, 2, False, "insertion")
    assert ippo[ippo.index("--tie-order") + 1] == "insertion" and "local" in ippo
    assert "--tie-order" not in command_of("rware-tiny-4ag-v2", "MAPPO", Path("/tmp/x"), 4, 2, False)


def test_periodic_evaluations_merge_runs_count_solved_seeds_and_refuse_mixed_views(tmp_path):
    """``bench/investigations/periodic_evaluations.py`` (the NOTES' solved-per-evaluation tables): runs of one
    variant merge by seed, evaluations before ``from_steps`` and training-only rows are left out, and runs with
    different environment overrides are refused."""
    sys.path.insert(0, str(ROOT / "bench" / "investigations"))
    from periodic_evaluations import summarize

    header = "env_steps,seed,eval_solved,eval_success_rate,eval_mean_steps\n"

    def run(name: str, rows: str, overrides: dict) -> Path:
        path = tmp_path / name
        path.mkdir()
        (path / "metrics.csv").write_text(header + rows)
        (path / "config.json").write_text(json.dumps({"env_overrides": overrides}))
        return path

    first = run("a", "8,0,,,\n8,0,1.0,1.0,9.0\n16,0,0.0,0.95,9.5\n16,1,1.0,1.0,9.25\n", {"safety_stop": True})
    second = run("b", "8,2,1.0,1.0,8.0\n16,2,1.0,1.0,8.5\n", {"safety_stop": True})
    summary = summarize([first, second], from_steps=16)
    assert summary["solved"] == {"16": 2} and (summary["late_solved"], summary["late_evaluations"]) == (2, 3)
    assert summary["per_evaluation"]["16"]["0"] == {"solved": False, "delivered": 0.95, "steps_per_item": 9.5}
    assert summarize([first, second], from_steps=0)["solved"] == {"8": 2, "16": 2}
    with pytest.raises(SystemExit, match="share their environment overrides"):
        summarize([first, run("c", "16,3,1.0,1.0,9.0\n", {})], from_steps=0)


def test_rware_throughput_table_takes_its_ratio_from_the_alternated_pairs():
    """``rware_throughput.markdown``: the headline column is the median of the alternated pairs' ratios with their
    range, and a report without pairs says its ratio was not alternated (a best batch over rware's median)."""
    sys.path.insert(0, str(ROOT / "bench"))
    from rware_throughput import markdown

    rows = [{"batch": 32, "agent_steps_per_s": 2.0e6}, {"batch": 1024, "agent_steps_per_s": 6.0e6}]
    entry = {"ours": rows, "rware": {"agent_steps_per_s": 8.0e3}, "jumanji": "not run",
             "paired": {"batch": 1024, "pairs": 3, "ratios": [700.0, 900.0, 800.0], "median_ratio": 800.0}}
    report = {"date": "d", "machine": "m", "command": "c", "ids": {"rware-tiny-4ag-v2": entry}}
    line = next(row for row in markdown(report).splitlines() if row.startswith("| rware-tiny-4ag-v2"))
    assert "**800x** (700-900x over 3 pairs at B=1024)" in line and "750x" not in line
    del entry["paired"]
    line = next(row for row in markdown(report).splitlines() if row.startswith("| rware-tiny-4ag-v2"))
    assert "750x (best batch over rware, not alternated)" in line
    assert "cores" not in markdown(report)  # a report from before the field says nothing about them
    report["cores"] = 2
    assert "could use 2 cores: rware's loop runs on one" in markdown(report)
    report["cores"] = 1
    assert "Every side on one core" in markdown(report)
