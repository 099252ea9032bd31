"""Checkpoints (atomic, path-keyed, compatibility-checked) and the metrics files."""

from __future__ import annotations

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from wrl_jax.training import checkpoint
from wrl_jax.training import metrics_io


@struct.dataclass
class Runner:
    params: dict
    key: jax.Array
    typed_key: jax.Array
    count: jax.Array
    flags: jax.Array


def make_runner(seed: int = 0) -> Runner:
    return Runner(
        params={"w": jax.random.normal(jax.random.PRNGKey(seed), (3, 4)), "b": jnp.arange(4.0)},
        key=jax.random.PRNGKey(seed + 1),
        typed_key=jax.random.split(jax.random.key(seed + 2), 2),
        count=jnp.int32(7),
        flags=jnp.array([True, False]),
    )


def test_round_trip_is_exact(tmp_path):
    runner = make_runner()
    meta = {"algo": "ppo", "config": {"lr": 0.1, "sizes": [64, 64]}, "updates_done": 3}
    path = checkpoint.save(tmp_path, runner, meta)
    assert path == tmp_path / checkpoint.CHECKPOINT_NAME
    assert [p.name for p in tmp_path.iterdir()] == [checkpoint.CHECKPOINT_NAME]  # no temp file left
    loaded, saved = checkpoint.load(tmp_path, jax.eval_shape(make_runner), expected={"algo": "ppo"})
    for a, b in zip(jax.tree_util.tree_leaves(runner), jax.tree_util.tree_leaves(loaded)):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        assert a.dtype == b.dtype and np.array_equal(np.asarray(a), np.asarray(b))
    assert saved["updates_done"] == 3 and saved["config"]["sizes"] == [64, 64]
    assert saved["wrl_jax_version"] and saved["format_version"] == checkpoint.FORMAT_VERSION
    assert checkpoint.read_metadata(path)["algo"] == "ppo"
    # The typed key still works as a key.
    jax.random.normal(loaded.typed_key[0], ())


def test_mismatched_config_is_refused_with_the_field_named(tmp_path):
    checkpoint.save(tmp_path, make_runner(), {"algo": "ppo", "config": {"lr": 0.1, "epochs": 4}, "seeds": [0, 1]})
    with pytest.raises(checkpoint.CheckpointMismatchError) as info:
        checkpoint.load(tmp_path, make_runner(), expected={"algo": "ppo", "config": {"lr": 0.2, "epochs": 4}})
    assert "config.lr: checkpoint has 0.1, this run has 0.2" in str(info.value)
    with pytest.raises(checkpoint.CheckpointMismatchError, match="algo"):
        checkpoint.load(tmp_path, make_runner(), expected={"algo": "dqn"})


def test_structure_shape_and_dtype_mismatches_are_named(tmp_path):
    checkpoint.save(tmp_path, make_runner(), {})
    wider = make_runner().replace(params={"w": jnp.zeros((3, 5)), "b": jnp.zeros(4)})
    with pytest.raises(checkpoint.CheckpointError, match=r"\.params\['w'\]: checkpoint has float32\[3, 4\].*float32\[3, 5\]"):
        checkpoint.load(tmp_path, wider)
    other = {"something": jnp.zeros(2)}
    with pytest.raises(checkpoint.CheckpointError, match="missing leaves"):
        checkpoint.load(tmp_path, other)
    as_int = make_runner().replace(count=jnp.float32(7))
    with pytest.raises(checkpoint.CheckpointError, match="count"):
        checkpoint.load(tmp_path, as_int)


def test_unreadable_or_missing_checkpoints(tmp_path):
    with pytest.raises(checkpoint.CheckpointError, match="no checkpoint"):
        checkpoint.read_metadata(tmp_path)
    (tmp_path / checkpoint.CHECKPOINT_NAME).write_bytes(b"\x00garbage")
    with pytest.raises(checkpoint.CheckpointError):
        checkpoint.read_metadata(tmp_path)


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    target = tmp_path / "file.txt"
    checkpoint.atomic_write_text(target, "old")

    class Boom(Exception):
        pass

    real_replace = os.replace

    def failing_replace(src, dst):
        raise Boom

    os.replace = failing_replace
    try:
        with pytest.raises(Boom):
            checkpoint.atomic_write_text(target, "new")
    finally:
        os.replace = real_replace
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


def rows(updates, seeds=(0, 1)):
    return [{"update": u, "env_steps": 10 * u, "seed": s, "loss": 0.5 * u, "eval": float("nan")}
            for u in updates for s in seeds]


def test_metrics_files_resume_without_duplicates(tmp_path):
    writer = metrics_io.MetricsWriter(tmp_path)
    writer.append(rows([1, 2]))
    writer.append(rows([3]))
    # The run checkpointed after update 2 and died after writing update 3: resume drops it.
    writer = metrics_io.MetricsWriter(tmp_path, resume_after=2)
    writer.append(rows([3, 4]))
    back = metrics_io.read_jsonl(tmp_path)
    assert [(r["update"], r["seed"]) for r in back] == [(u, s) for u in (1, 2, 3, 4) for s in (0, 1)]
    assert np.isnan(back[0]["eval"])
    lines = (tmp_path / metrics_io.CSV_NAME).read_text().splitlines()
    assert lines[0] == "update,env_steps,seed,loss,eval" and len(lines) == 1 + 8
    assert lines[1] == "1,10,0,0.5,"
    assert json.loads((tmp_path / metrics_io.JSONL_NAME).read_text().splitlines()[0])["eval"] is None
    with pytest.raises(ValueError, match="columns"):
        writer.append([{"update": 5, "seed": 0}])
    # A fresh (non-resumed) writer starts the files over.
    metrics_io.MetricsWriter(tmp_path)
    assert metrics_io.read_jsonl(tmp_path) == []


def test_learning_curve_plot(tmp_path):
    data = [
        {"update": u, "env_steps": 100 * u, "seed": s, "mean_return": float(u + s), "delivery_rate": 0.1 * u,
         "eval_optimal_rate": float("nan") if u % 2 else 0.2 * u}
        for u in range(1, 6) for s in range(3)
    ]
    path = metrics_io.plot_learning_curves(data, tmp_path / "curve.png", title="test", optimal_return=5.0,
                                           panels=[("delivery_rate", "delivered"), ("eval_optimal_rate", "optimal"),
                                                   ("eval_missing", "a metric no row has")])
    assert path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image

    assert Image.open(path).size[0] == 3 * 550  # return, delivered, optimal: a panel no row has is left out


def test_a_run_saved_before_the_package_move_still_evaluates_the_same(tmp_path):
    """Checkpoints hold pytrees and JSON metadata, no module paths: a run written by git 820cc3e (before
    the gymnax base class and the package move) loads and evaluates to the numbers it reported then
    (resuming loads the same way: ``checkpoint.load`` against the new code's template)."""
    import json
    from pathlib import Path

    from wrl_jax.cli import evaluate as cli_evaluate

    saved = Path(__file__).parent / "data" / "run_before_gymnax_base"
    then = json.loads((saved / "summary_then.json").read_text())["eval"]
    now = cli_evaluate.evaluate_run(saved)
    for key in ("success_rate", "mean_steps", "optimal_rate", "collision_free_rate", "stage_switch_rate"):
        assert now[key] == then[key], key
    assert abs(now["mean_return"] - then["mean_return"]) < 1e-3
    assert [s["success_rate"] for s in now["per_seed"]] == [s["success_rate"] for s in then["per_seed"]]


def test_tensorboard_writer_loads_without_importing_torch(tmp_path, monkeypatch):
    """tensorboardX imports PyTorch when it is installed (1.3 s of a command's start-up): the writer hides it
    while tensorboardX loads, writes events all the same, and leaves ``import torch`` possible afterwards."""
    import sys

    torch_loaded = sys.modules.get("torch")  # another test of this process may have imported it (SB3)
    for name in [m for m in sys.modules if m.startswith("tensorboardX")]:
        monkeypatch.delitem(sys.modules, name)  # tensorboardX loads again, as in a fresh process
    writer_class = metrics_io._summary_writer_class()
    if torch_loaded is None:
        assert "torch" not in sys.modules  # neither imported nor left blocked (a None entry)
    else:
        assert sys.modules["torch"] is torch_loaded
    writer = writer_class(str(tmp_path))
    writer.add_scalar("mean_return", 1.5, 10)
    writer.close()
    assert any(path.name.startswith("events.out.tfevents") for path in tmp_path.iterdir())
