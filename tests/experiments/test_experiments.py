"""Tests of wrl_jax.experiments: the CI helper, per-seed metrics, segmented training,
the stage-blind observation, and every experiment's --quick path end to end.

The quick runs share compiled training programs (same setting, seed batch and evaluation cadence):
table3's PPO 12x12 is media's and scale's (scale runs the 12x12 map for it), failure_modes' DQN 8x8
pair of variants is media's. DQN 8x8's quick budget is checked on failure_modes' table (table3 runs PPO)."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax.envs.warehouse import evaluation
from wrl_jax.experiments import common, failure_modes, forgetting, media, scale, sensitivity, table3
from wrl_jax.experiments.configs import ENV_8, ENV_12, Setting, build
from wrl_jax.core.registry import make


# ------------------------------------------------------------------ CI helper
@pytest.mark.parametrize("df, expected", [(1, 12.7062047), (2, 4.3026527), (3, 3.1824463), (7, 2.3646243),
                                          (8, 2.3060041), (30, 2.0422725), (100, 1.9839715)])
def test_t_quantile_matches_tables(df, expected):
    assert common.t_quantile(0.95, df) == pytest.approx(expected, abs=1e-6)


def test_t_quantile_other_levels_and_errors():
    assert common.t_quantile(0.90, 10) == pytest.approx(1.8124611, abs=1e-6)
    assert common.t_quantile(0.99, 5) == pytest.approx(4.0321430, abs=1e-6)
    with pytest.raises(ValueError, match="confidence level"):
        common.t_quantile(1.0, 3)
    with pytest.raises(ValueError, match="degrees of freedom"):
        common.t_quantile(0.95, 0)


def test_mean_ci_t_interval_by_hand():
    values = [1, 2, 3, 4, 5, 6, 7, 8]
    ci = common.mean_ci(values)
    half = 2.3646243 * np.std(values, ddof=1) / math.sqrt(8)  # t quantile, 7 degrees of freedom
    assert ci.mean == 4.5 and ci.n == 8
    assert ci.low == pytest.approx(4.5 - half, abs=1e-6) and ci.high == pytest.approx(4.5 + half, abs=1e-6)


def test_mean_ci_bootstrap_bounds_nan_and_constant():
    values = [0.2, 0.4, 0.9, 1.0, 1.0, 0.5]
    a, b = common.mean_ci(values, method="bootstrap"), common.mean_ci(values, method="bootstrap")
    assert a == b  # fixed resampling seed
    assert a.low < a.mean < a.high
    assert min(values) <= a.low and a.high <= max(values)  # a percentile bootstrap never leaves the data's range
    clipped = common.mean_ci([0.0, 1.0, 1.0], bounds=(0.0, 1.0))
    assert clipped.high == 1.0 and clipped.low >= 0.0
    assert common.mean_ci([1.0, float("nan"), 3.0]).n == 2
    constant = common.mean_ci([1.0] * 8)
    assert (constant.low, constant.mean, constant.high) == (1.0, 1.0, 1.0)
    assert common.mean_ci([]).n == 0 and common.mean_ci([]).fmt() == "n/a"
    with pytest.raises(ValueError, match="unknown CI method"):
        common.mean_ci([1.0, 2.0], method="wald")


def test_per_seed_metrics_by_hand():
    # 2 seeds x 3 item rows, the last row padding (invalid); NumPy inputs (the metrics are NumPy: no eager programs).
    ep = evaluation.EpisodeEval(
        valid=np.array([[True, True, False], [True, True, False]]),
        delivered=np.array([[True, True, False], [True, False, False]]),
        steps=np.array([[14, 16, 0], [14, 150, 0]]),
        optimal_steps=np.array([[14, 14, 14], [14, 14, 14]]),
        episode_return=np.array([[271.5, 270.5, 0.0], [271.5, -75.0, 0.0]]),
        collisions=np.array([[0, 1, 0], [0, 0, 0]]),
        wall_bumps=np.zeros((2, 3), np.int32),
        pickup_step=np.array([[5, 7, -1], [5, -1, -1]]),
        stage_switch=np.array([[True, False, False], [True, False, False]]),
    )
    m = common.per_seed_metrics(ep)
    np.testing.assert_allclose(m["success_rate"], [1.0, 0.5])
    np.testing.assert_allclose(m["optimal_rate"], [0.5, 0.5])
    np.testing.assert_allclose(m["mean_steps"], [15.0, 14.0])
    np.testing.assert_allclose(m["excess_steps"], [1.0, 0.0])
    np.testing.assert_allclose(m["collision_free_rate"], [0.5, 1.0])
    np.testing.assert_allclose(m["stage_switch_rate"], [0.5, 0.5])
    np.testing.assert_allclose(m["mean_return"], [271.0, 98.25])
    np.testing.assert_allclose(m["all_optimal"], [0.0, 0.0])


# ----------------------------------------------------------- segmented training
def test_one_item_params_keeps_shapes_and_rejects_bad_items():
    _, params = make(ENV_8)
    one = forgetting.one_item_params(params, 4)
    assert one.items.shape == params.items.shape
    assert int(one.num_items) == 1
    expected = np.broadcast_to(np.asarray(params.items)[4], params.items.shape)
    np.testing.assert_array_equal(np.asarray(one.items), expected)
    with pytest.raises(ValueError, match="out of range"):
        forgetting.one_item_params(params, 10)


def test_segments_really_swap_the_item_and_keep_learning_state():
    # Short episodes (max 4 steps) so every environment resets within a segment of 8 updates.
    setting = Setting("dqn", "default", ENV_8, overrides=(("num_envs", 4), ("learning_starts", 8),
                                                          ("total_timesteps", 64), ("buffer_size", 256)))
    env, full = make(ENV_8, max_steps=4)
    algo, _, _ = build(setting, env=env, params=full)
    seeds = [0, 1]
    # Runners 0-1: randomized items (the full layout); runners 2-3: segmented (one item per segment).
    runners = forgetting.training_init(algo, seeds * 2, full)
    # Shapes, indices, buffer counts and a changed kernel: compiled at LLVM level 0 (tests/fast_compile.py).
    segment = fast_compile.fast(forgetting.make_segment_fn(algo, full, segment_updates=8))
    clear = jnp.zeros(4, bool)
    for k, item in enumerate([3, 7]):
        one = forgetting.one_item_params(full, item)
        params = common.stack_trees([full, full, one, one])
        before = runners
        runners, stats, episodes = segment(runners, params, clear, jnp.int32(8 * k))
        # Segmented runners' environments now only hold the segment's item ...
        seg_items = np.asarray(runners.env_state.item_index)[2:]  # NumPy indexing: no eager slice programs
        assert np.all(seg_items == 0)  # index 0 of the one-item layout ...
        np.testing.assert_array_equal(np.asarray(runners.env_state.item_pos)[2:],
                                      np.broadcast_to(np.asarray(full.items)[item], (2, 4, 2)))  # ... is that cell
        num_items = np.asarray(runners.env_params.num_items)
        assert int(num_items[2]) == 1 and int(num_items[0]) == 10
        # ... while the randomized ones see several items.
        assert len({tuple(cell) for cell in np.asarray(runners.env_state.item_pos)[:2].reshape(-1, 2).tolist()}) > 1
        # Learning state carries over: the buffer keeps growing, the network changes.
        assert np.all(np.asarray(runners.buffer.size) > np.asarray(before.buffer.size))
        assert episodes.delivered.shape == (4, 10)  # evaluated on every item, not the segment's one
    kernel_after, kernel_before = (np.asarray(jax.tree.leaves(r.params)[0])[2] for r in (runners, before))
    assert not np.allclose(kernel_after, kernel_before)

    # The same compiled segment (8 updates of one vector step of 4 transitions each), clearing runners 2-3 first.
    cleared = segment(runners, common.stack_trees([full] * 4), jnp.array([False, False, True, True]), jnp.int32(16))[0]
    assert np.all(np.asarray(cleared.buffer.size)[2:] == 8 * 4)  # emptied, then the segment's 32 transitions
    assert np.all(np.asarray(cleared.buffer.size)[:2] == np.asarray(runners.buffer.size)[:2] + 8 * 4)


# ------------------------------------------------------------- stage-blind env
def test_stage_blind_observation_hides_the_stage():
    env, params = failure_modes.stage_blind()
    plain, _ = make(ENV_8, observe_carrying=False)
    assert env != plain and env.obs_size == 6

    @fast_compile.jit  # one program (eagerly, each operation compiles on its own); grid logic: LLVM level 0
    def walk():
        obs0, state = env.reset_to_item(1, params)  # item 1 at (1, 3): right x3, down x1
        for action in (3, 3, 3, 1):
            obs, state, *_ = env.transition(None, state, action, params)
        plain_obs, _, *_ = plain.transition(None, state.replace(carrying=False, pos=jnp.array([1, 2])), 3, params)
        return obs0, obs, state.carrying, plain_obs

    obs0, obs, carrying, plain_obs = jax.device_get(walk())
    assert bool(carrying)
    np.testing.assert_array_equal(obs[4:6], obs0[4:6])  # item coordinates unchanged
    assert float(plain_obs[4]) < 0  # the plain observation blanks them after pickup


# ------------------------------------------------------- quick paths end to end
def _read(path):
    return json.loads(path.read_text())


def test_table3_quick_writes_files(tmp_path):
    assert table3.main(["--quick", "--presets", "default", "--algos", "ppo", "--out", str(tmp_path)]) == 0
    for name in ("table3.md", "table3.json", "table3.png"):
        assert (tmp_path / name).stat().st_size > 0
    data = _read(tmp_path / "table3.json")
    entry = data["settings"]["PPO 12x12 default"]
    assert data["quick"] and entry["seeds"] == [0, 1] and entry["env_steps_per_seed"] == 4_096
    assert "Task Completion Rate" in (tmp_path / "table3.md").read_text()


def test_failure_modes_quick_writes_files(tmp_path):
    assert failure_modes.main(["--quick", "--modes", "collision", "forgetting", "--out", str(tmp_path)]) == 0
    data = _read(tmp_path / "table4.json")
    assert data["quick"] and data["env_steps_per_seed"] == 3_200  # DQN 8x8 default's quick budget
    expected = {"fixed (final setting)", "collision bug", "collision bug, evaluated without the bug"}
    assert set(data["variants"]) == expected
    assert data["forgetting"]["variants"] == list(forgetting.VARIANTS)
    for name in ("table4.md", "table4.png", "forgetting.png"):
        assert (tmp_path / name).stat().st_size > 0


def test_sensitivity_quick_writes_files(tmp_path):
    assert sensitivity.main(["--quick", "--scales", "0", "--out", str(tmp_path)]) == 0
    data = _read(tmp_path / "sensitivity.json")
    assert data["scales"] == [0.0, 1.0] and len(data["variants"]) == 1 + len(sensitivity.TERMS)
    assert np.asarray(data["grid"]["success_rate"]).shape == (len(sensitivity.TERMS), 2)
    assert (tmp_path / "sensitivity.png").stat().st_size > 0


def test_scale_quick_writes_files(tmp_path):
    assert scale.main(["--quick", "--envs", ENV_12, "--out", str(tmp_path)]) == 0
    data = _read(tmp_path / "scale.json")
    assert set(data["results"]) == {"DQN 12x12 default", "PPO 12x12 default"}
    assert (tmp_path / "scale.png").stat().st_size > 0


def test_media_quick_writes_gifs(tmp_path):
    """Cells of 8 pixels, not the README's 32: every frame of the quick runs' episodes (300 steps at 12x12) is
    rendered at LLVM level 0 and quantized into a GIF, and 16 times fewer pixels take 4.5 of the test's 18 s of CPU
    off. (The GIFs of the README's size are a few tens of KiB at 32 pixels in quick mode, far under the 1 MiB.)"""
    assert media.main(["--quick", "--failure-frames", "10", "--cell-size", "8", "--out", str(tmp_path)]) == 0
    for name in ("dqn_8x8.gif", "ppo_12x12.gif", "failure_oscillation.gif", "learning_curves.png"):
        size = (tmp_path / name).stat().st_size
        assert 0 < size < 1 << 20


def test_bad_arguments_are_rejected(tmp_path):
    with pytest.raises(SystemExit):
        table3.main(["--seeds", "1", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        sensitivity.main(["--scales", "-1", "--out", str(tmp_path)])
