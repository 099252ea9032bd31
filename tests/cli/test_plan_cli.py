"""``python -m wrl_jax.plan``: clear errors before anything compiles.

A real run, checked against recorded shifts, is in ``test_fleet_planners.py`` (it shares their programs).
"""

from __future__ import annotations

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
    ],
)
def test_bad_flags_exit_2_with_the_reason(argv, message, capsys):
    assert plan.main([*argv, "--xla-opt-level", "-1"]) == 2
    assert message in capsys.readouterr().err
