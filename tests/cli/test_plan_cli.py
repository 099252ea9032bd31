"""``python -m wrl_jax.plan``: clear errors before anything compiles, and a small pure-pursuit run.

A real fleet run, checked against recorded shifts, is in ``test_fleet_planners.py`` (it shares their programs).
"""

from __future__ import annotations

import json

import pytest

from wrl_jax.cli import plan


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--planner", "astar"], "unknown planner 'astar'"),
        (["--num-robots", "0"], "--num-robots must be a positive integer"),
        (["--num-robots", "9"], "only 8 start cells"),
        (["--episodes", "0"], "--episodes must be a positive integer"),
        (["--horizon", "-3"], "--horizon must be a positive integer"),
        (["--env", "Warehouse-8x8-v0"], "not a fleet environment"),
        (["--env", "Fleet-7x7-v0"], "unknown environment 'Fleet-7x7-v0'"),
        (["--planner", "pursuit"], "'Fleet-12x12-v0' is not a continuous environment"),
        (["--env", "Continuous-Warehouse-8x8-v0"], "a continuous environment takes --planner pursuit"),
        (["--planner", "pursuit", "--env", "Continuous-Warehouse-8x8-v0", "--num-robots", "2"],
         "--num-robots is for fleets"),
        (["--planner", "pursuit", "--env", "Continuous-Warehouse-8x8-v0", "--episodes", "0"],
         "--episodes must be a positive integer"),
        (["--randomize"], "--randomize is for continuous environments"),
    ],
)
def test_bad_flags_exit_2_with_the_reason(argv, message, capsys):
    assert plan.main([*argv, "--xla-opt-level", "-1"]) == 2
    assert message in capsys.readouterr().err


def test_pursuit_on_a_continuous_env_reports_every_item(tmp_path, capsys):
    out = tmp_path / "pursuit.json"
    argv = ["--planner", "pursuit", "--env", "Continuous-Warehouse-8x8-v0", "--episodes", "10", "--seed", "3",
            "--json", str(out), "--xla-opt-level", "-1"]
    assert plan.main(argv) == 0
    assert "pursuit on Continuous-Warehouse-8x8-v0, 10 episodes" in capsys.readouterr().out
    report = json.loads(out.read_text())
    assert report["delivery_rate"] == 1.0 and report["collisions_per_episode"] == 0.0
    assert [item["episodes"] for item in report["per_item"]] == [1] * 10
    for item in report["per_item"]:
        assert item["strict_bound_steps"] <= item["mean_steps"] <= 1.1 * item["bound_steps"]
