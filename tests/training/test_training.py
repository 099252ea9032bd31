"""The shared training driver: chunking, exact resume, evaluation, convergence bookkeeping.

Compiled programs are the cost here, so the tests share them: ``reference`` (one chunk of 7 updates) and
``chunked`` (chunks of 2, the same seeds) are the module's two trainers; the chunk-size, resume and TensorBoard
tests all run ``chunked`` (one compiled chunk program), and so does the ``log_every`` check, whose trainer differs
from it only in ``log_every`` and only makes the rows.
:data:`TINY` and the loop settings are ``test_cli.py``'s command's (its run chunks by 2, its resume by 7), so
the two modules compile these chunk programs and the evaluation once between them."""

from __future__ import annotations

import copy
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import commands_level

import wrl_jax
from wrl_jax import training
from wrl_jax.agents.base import make_train_seeds
from wrl_jax.training import checkpoint
from wrl_jax.envs.warehouse import evaluation
from wrl_jax.training import metrics_io
from wrl_jax.envs.warehouse import routes
from wrl_jax.agents.ppo import PPO
from wrl_jax.agents.ppo_config import PPOConfig
from wrl_jax.envs.warehouse.layout import MOVES

# A tiny PPO (compiles in seconds, runs in milliseconds): the driver is what is tested here. The configuration
# of test_cli.py's TINY command (same programs).
TINY = PPOConfig(
    num_envs=8, num_steps=16, num_minibatches=2, update_epochs=2, hidden_sizes=(16,), total_timesteps=8 * 16 * 7
)
SEEDS = [3, 4]


def leaves_equal(a, b) -> bool:
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


def rows_equal(a, b) -> bool:
    """Metric rows equal value for value, NaN equal to NaN."""
    return len(a) == len(b) and all(
        x.keys() == y.keys()
        and np.array_equal(np.array(list(x.values()), float), np.array(list(y.values()), float), equal_nan=True)
        for x, y in zip(a, b)
    )


@pytest.fixture(scope="module")
def algo():
    env, params = wrl_jax.make("Warehouse-8x8-v0")
    return PPO(TINY, env, params)


@pytest.fixture(scope="module")
def reference(algo):
    """An uninterrupted run in one chunk, evaluating every 3 updates."""
    trainer = training.Trainer(algo, SEEDS, training.LoopConfig(chunk_updates=7, eval_every=3, progress=False))
    return trainer, training.run(trainer)


@pytest.fixture(scope="module")
def chunked(algo):
    """The same seeds in chunks of 2 updates (2, 2, 2, then 1 of the last chunk's 2): one compiled program that
    the chunk-size, resume and TensorBoard tests share."""
    return training.Trainer(algo, SEEDS, training.LoopConfig(chunk_updates=2, eval_every=3, progress=False))


def test_one_trace_of_the_evaluation_serves_the_loop_its_shapes_and_evaluate(algo, monkeypatch):
    """The loop's evaluations (inside the chunk), the empty evaluation's shapes and ``evaluate`` share one trace of
    the family's evaluation: a fleet's, with PIBT inside, takes seconds to trace. Traced here, not compiled."""
    traced = []
    evaluate = training.Trainer._evaluate
    monkeypatch.setattr(training.Trainer, "_evaluate", lambda self, runners: traced.append(1) or evaluate(self, runners))
    trainer = training.Trainer(algo, SEEDS, training.LoopConfig(chunk_updates=2, eval_every=3, progress=False))
    runners = trainer.template()
    trainer._chunk_jit.trace(runners, jnp.int32(0), trainer.empty_eval(runners))
    jax.eval_shape(trainer.evaluate, runners)
    assert len(traced) == 1


def test_chunk_size_does_not_change_results(chunked, reference):
    _, ref = reference
    result = training.run(chunked)
    assert result.updates_done == ref.updates_done == 7
    assert leaves_equal(result.runners, ref.runners)
    assert rows_equal(result.rows, ref.rows)
    assert result.convergence.to_json() == ref.convergence.to_json()


@commands_level.at_commands_level  # a claim about level-1 programs (tests/commands_level.py)
def test_make_train_matches_the_chunked_driver(algo, chunked):
    """``make_train``'s one program and the driver's chunks of 2 give the same bits at the commands' level.

    Compared with each other directly, not through ``reference`` (the one-chunk run): at level 1 that trainer
    would be a third training program to compile in the level-1 process, and what it adds, that the chunk size
    changes nothing, is the chunk-size test's claim above, at the session's level (the same program XLA builds)."""
    runner, metrics = jax.jit(make_train_seeds(algo))(training.seed_keys(SEEDS))
    assert metrics["episodes"].shape == (len(SEEDS), TINY.num_updates)
    assert leaves_equal(training.run(chunked).runners, runner)


def test_exact_resume_from_a_chunk_boundary(chunked, reference, tmp_path):
    _, ref = reference
    trainer = chunked
    meta = {"algo": "ppo", "config": {"note": "test"}}
    first = training.run(trainer, tmp_path, metadata=meta, stop_after=3)
    assert first.updates_done == 4 and not first.finished  # rounded up to the chunk boundary
    # Simulate a crash after the checkpoint: rows beyond it must be dropped on resume.
    with open(tmp_path / metrics_io.JSONL_NAME, "a") as f:
        f.write('{"update": 99, "env_steps": 0, "seed": 3}\n{"upd')
    resumed = training.run(trainer, tmp_path, metadata=meta, resume=True)
    assert resumed.finished and resumed.updates_done == 7
    assert leaves_equal(resumed.runners, ref.runners)
    rows = metrics_io.read_jsonl(tmp_path / metrics_io.JSONL_NAME)
    assert len(rows) == 7 * len(SEEDS)  # no duplicate, no stray row
    assert rows_equal(rows, ref.rows)  # JSON round trip of float64 values is exact
    csv_lines = (tmp_path / metrics_io.CSV_NAME).read_text().splitlines()
    assert len(csv_lines) == 1 + 7 * len(SEEDS)
    assert resumed.convergence.to_json() == ref.convergence.to_json()
    # A resume with another configuration is refused before anything runs.
    with pytest.raises(checkpoint.CheckpointMismatchError, match="config.note"):
        training.run(trainer, tmp_path, metadata={**meta, "config": {"note": "other"}}, resume=True)


def test_checkpoints_wait_checkpoint_seconds_but_the_last_is_always_written(chunked, tmp_path, monkeypatch):
    """Four chunks: with ``checkpoint_seconds=0`` a checkpoint after each, with an hour only the last one (a
    ``stop_after`` run's too)."""
    saved = []
    real_save = checkpoint.save
    monkeypatch.setattr(checkpoint, "save", lambda path, tree, meta: saved.append(meta["updates_done"])
                        or real_save(path, tree, meta))
    trainer = copy.copy(chunked)  # the same compiled chunks, another host cadence
    for seconds, expected in ((0.0, [2, 4, 6, 7]), (3600.0, [7])):
        saved.clear()
        trainer.loop = dataclasses.replace(chunked.loop, checkpoint_seconds=seconds)
        training.run(trainer, tmp_path / str(seconds), metadata={"algo": "ppo"})
        assert saved == expected
    saved.clear()
    training.run(trainer, tmp_path / "stopped", metadata={"algo": "ppo"}, stop_after=3)
    assert saved == [4]
    with pytest.raises(ValueError, match="checkpoint_seconds"):
        training.LoopConfig(checkpoint_seconds=-1).resolve(10)


def test_seeds_differ_and_runs_repeat_bit_for_bit(algo, reference):
    trainer, ref = reference
    params = np.asarray(ref.runners.params)
    assert not np.array_equal(params[0], params[1])
    again = training.run(trainer)
    assert leaves_equal(again.runners, ref.runners)


def test_metric_rows_and_evaluations(algo, reference):
    trainer, ref = reference
    assert [row["update"] for row in ref.rows[:: len(SEEDS)]] == list(range(1, 8))
    evaluated = [row["update"] for row in ref.rows[:: len(SEEDS)] if not np.isnan(row["eval_success_rate"])]
    assert evaluated == [3, 6, 7]  # every 3 updates and after the last
    assert ref.convergence.updates == [3, 6, 7]
    for row in ref.rows:
        if row["episodes"]:
            assert row["mean_return"] == pytest.approx(row["return_sum"] / row["episodes"])
    # The final in-loop evaluation is the same as a separately compiled one.
    final = training.final_evaluation(trainer, ref)
    assert leaves_equal(final, trainer.evaluate(ref.runners))


def test_log_every_aggregates_sums_and_means(algo, chunked):
    """Updates logged every 2: one row per 2 updates and seed, sums and means of its 2 updates. ``chunked``'s
    settings but for ``log_every``, which only :meth:`Trainer.metric_rows` reads: ``chunked`` runs the chunks (its
    compiled program), this trainer makes the rows. The two chunks' metrics are also read as one chunk of 4, so a
    row per chunk instead of per ``log_every`` would fail."""
    trainer = training.Trainer(algo, SEEDS, training.LoopConfig(chunk_updates=2, log_every=2, eval_every=3,
                                                                progress=False))
    runners = chunked.init()
    runners, first, latest = chunked.run_chunk(runners, 0)
    _, second, _ = chunked.run_chunk(runners, 2, latest)
    rows = [row for row in trainer.metric_rows(first, 0) + trainer.metric_rows(second, 2) if row["seed"] == SEEDS[0]]
    assert [row["update"] for row in rows] == [2, 4]
    assert rows[0]["episodes"] == pytest.approx(first["episodes"][:2, 0].sum())
    assert rows[1]["loss"] == pytest.approx(second["loss"][:2, 0].mean())  # updates 3 and 4
    joined = {name: np.concatenate([first[name], second[name]]) for name in first}  # one chunk of 4 updates
    assert [row for row in trainer.metric_rows(joined, 0) if row["seed"] == SEEDS[0]] == rows


def test_loop_config_validation():
    with pytest.raises(ValueError, match="multiple of log_every"):
        training.LoopConfig(chunk_updates=3, log_every=2).resolve(10)
    with pytest.raises(ValueError, match="chunk_updates"):
        training.LoopConfig(chunk_updates=0).resolve(10)
    with pytest.raises(ValueError, match="eval_every"):
        training.LoopConfig(eval_every=-1).resolve(10)
    loop = training.LoopConfig().resolve(1000)
    assert loop.log_every == 2 and loop.chunk_updates % loop.log_every == 0 and loop.eval_every == 20


def test_convergence_first_and_stable():
    conv = training.Convergence()
    flags = np.array([[0, 1], [1, 1], [0, 1], [1, 1]], dtype=np.float32)
    conv.record({"eval_all_optimal": flags}, start=0)
    assert conv.updates == [1, 2, 3, 4]
    assert conv.first_solved_update(2) == [2, 1]
    assert conv.stable_solved_update(2) == [4, 1]
    assert training.Convergence.from_json(conv.to_json()) == conv


# ----------------------------------------------------------------- evaluation
def oracle_greedy(env):
    """A policy that reads the observation and follows BFS: every item at the optimum."""

    def act(shelves, obs):
        cells = jnp.round(obs * (env.size - 1)).astype(jnp.int32)
        target = jnp.where(obs[6] > 0.5, cells[2:4], cells[4:6])
        dist = routes.distance_map(shelves, target)
        neighbours = cells[0:2][None, :] + jnp.asarray(MOVES)
        inside = jnp.all((neighbours >= 0) & (neighbours < env.size), axis=-1)
        clipped = jnp.clip(neighbours, 0, env.size - 1)
        return jnp.argmin(jnp.where(inside, dist[clipped[:, 0], clipped[:, 1]], routes.UNREACHABLE)).astype(jnp.int32)

    return act


@pytest.mark.parametrize("name, optimum", [("Warehouse-8x8-v0", 14.0), ("Warehouse-12x12-v0", 22.0)])
def test_evaluation_of_an_optimal_policy(name, optimum):
    env, params = wrl_jax.make(name)
    result, scalars = jax.jit(lambda p: (lambda r: (r, evaluation.seed_summary(r)))(
        evaluation.evaluate_policy(oracle_greedy(env), p.shelves, env, p)))(params)
    summary = evaluation.summarize(jax.tree.map(lambda x: np.asarray(x)[None], result), seeds=[7])
    assert summary["success_rate"] == 1.0 and summary["optimal_rate"] == 1.0 and summary["all_seeds_optimal"]
    assert summary["mean_steps"] == optimum == summary["optimal_mean_steps"]
    assert summary["collision_free_rate"] == 1.0 and summary["stage_switch_rate"] == 1.0
    assert len(summary["rows"]) == int(params.num_items)
    assert float(scalars["eval_all_optimal"]) == 1.0
    table = evaluation.format_table3(summary, "oracle", [1000])
    assert "100.0%" in table and f"{optimum:.2f}" in table


def test_evaluation_of_bad_policies():
    env, params = wrl_jax.make("Warehouse-8x8-v0", max_steps=20)
    # Both policies' episodes in one compiled program (eagerly, every operation compiles on its own).
    right, down = jax.jit(lambda p: [evaluation.evaluate_policy(lambda _, obs: jnp.int32(action), None, env, p)
                                     for action in (3, 1)])(params)
    # Always "right" from (0, 0): picks up item 0 at (0, 6), reaches (0, 7) and bumps the wall 13 times.
    assert not bool(right.delivered.any())
    assert (np.asarray(right.steps) == 20).all()
    assert int(right.pickup_step[0]) == 6 and int(right.wall_bumps[0]) == 13
    assert (np.asarray(right.pickup_step[1:]) == -1).all()
    # Always "down" from (0, 0) then stuck at (7, 0): item 5 at (4, 0) on the way.
    assert int(down.pickup_step[5]) == 4
    summary = evaluation.summarize(jax.tree.map(lambda x: np.asarray(x)[None], down))
    assert summary["success_rate"] == 0.0 and summary["mean_steps"] is None
    assert summary["stage_switch_rate"] == 0.0


def test_evaluation_counts_collisions():
    # Item 1 of 8x8 sits at (1, 3) above the shelf row (2, 1..3): "down" from (1, 3) collides.
    env, params = wrl_jax.make("Warehouse-8x8-v0", max_steps=12)

    def policy(_, obs):
        carrying = obs[6] > 0.5
        row = jnp.round(obs[0] * 7)
        return jnp.where(carrying, jnp.int32(1), jnp.where(row < 1, jnp.int32(1), jnp.int32(3)))

    result, summary = jax.jit(lambda p: (lambda r: (r, evaluation.seed_summary(r)))(
        evaluation.evaluate_policy(policy, None, env, p)))(params)
    # item 1: down to (1, 0), right to (1, 3) picks it up at step 4, then down into the shelf until truncation.
    assert int(result.pickup_step[1]) == 4
    assert int(result.collisions[1]) == 12 - 4
    assert float(summary["eval_collision_free_rate"]) < 1.0


def _tensorboard_scalars(run_dir, seed) -> dict[str, dict[int, float]]:
    """The scalars TensorBoard would show for one seed: events in file order, a
    ``SessionLog.START`` at step T hiding earlier events at steps >= T (tensorboardX's purge)."""
    import struct as binary

    from tensorboardX.proto import event_pb2

    scalars: dict[str, dict[int, float]] = {}
    for path in sorted((run_dir / metrics_io.TENSORBOARD_DIR / f"seed_{seed}").iterdir()):
        data = path.read_bytes()
        offset = 0
        while offset < len(data):
            (length,) = binary.unpack("<Q", data[offset : offset + 8])
            event = event_pb2.Event.FromString(data[offset + 12 : offset + 12 + length])
            offset += 12 + length + 4
            if event.HasField("session_log") and event.session_log.status == event_pb2.SessionLog.START:
                for steps in scalars.values():
                    for step in [s for s in steps if s >= event.step]:
                        del steps[step]
            for value in event.summary.value:
                scalars.setdefault(value.tag, {})[event.step] = value.simple_value
    return scalars


def test_tensorboard_events_match_the_metric_rows_across_a_resume(chunked, reference, tmp_path):
    _, ref = reference
    trainer = chunked
    training.run(trainer, tmp_path, stop_after=3)
    # Curves written past the checkpoint by a run that then crashed must disappear on resume.
    from tensorboardX import SummaryWriter

    seed_dir = tmp_path / metrics_io.TENSORBOARD_DIR / f"seed_{SEEDS[0]}"
    with SummaryWriter(str(seed_dir), filename_suffix=".stray") as stray:
        stray.add_scalar("mean_return", 12345.0, global_step=10**6)
    # Event files are named by the second they were opened in and read in name order: date the stray
    # file before the resume's (a resume within the same second would otherwise sort after it).
    (stray_file,) = seed_dir.glob("*.stray")
    stray_file.rename(seed_dir / "events.out.tfevents.0000000001.stray")
    training.run(trainer, tmp_path, resume=True)
    for seed in SEEDS:
        shown = _tensorboard_scalars(tmp_path, seed)
        rows = [row for row in ref.rows if row["seed"] == seed]
        for key in ("mean_return", "episodes", "eval_optimal_rate", "policy_loss"):
            expected = {int(r["env_steps"]): np.float32(r[key]) for r in rows if np.isfinite(r[key])}
            assert {s: np.float32(v) for s, v in shown[key].items()} == expected, key
