"""Training metrics on disk: JSONL and CSV rows, TensorBoard event files, and the learning-curve plot.

One row per (logged update, seed): ``update`` (updates done, 1-based),
``env_steps`` (per seed), ``seed``, then the algorithm's metrics and the
driver's derived ones (``mean_return``, ``mean_length``, the family's rates such as ``delivery_rate``,
``eval_*``). Missing values (no episode ended, no evaluation at this update)
are NaN in memory, ``null`` in JSONL and empty in CSV.

Both files are append-safe across resumes: :class:`MetricsWriter` opened with
``resume_after=U`` first rewrites them (atomically) keeping only rows with
``update <= U``, the updates the checkpoint holds, so rows written after the
last checkpoint by an interrupted run are dropped and never duplicated.

TensorBoard: the same scalars, one event-file directory per seed under
``tensorboard/seed_<s>/`` (so ``tensorboard --logdir runs/`` shows every run and
seed as its own curve), at global step ``env_steps``. On resume the writer
purges events past the checkpoint (tensorboardX's ``purge_step``), the same
rule as for the JSONL and CSV rows.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from wrl_jax.training.checkpoint import atomic_write_text

JSONL_NAME = "metrics.jsonl"
CSV_NAME = "metrics.csv"
PLOT_NAME = "learning_curve.png"
TENSORBOARD_DIR = "tensorboard"
INDEX_COLUMNS = ("update", "env_steps", "seed")


def _clean(value: Any) -> Any:
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return None if math.isnan(value) or math.isinf(value) else value
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def read_jsonl(path: str | os.PathLike) -> list[dict[str, Any]]:
    """Rows of a metrics JSONL file (``null`` read back as NaN). A torn last line is skipped."""
    path = Path(path)
    if path.is_dir():
        path = path / JSONL_NAME
    rows = []
    if not path.exists():
        return rows
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue  # an interrupted append; it is beyond the checkpoint anyway
            rows.append({k: (math.nan if v is None else v) for k, v in row.items()})
    return rows


class MetricsWriter:
    """Appends metric rows to ``metrics.jsonl`` and ``metrics.csv`` in ``out_dir``.

    Args:
        out_dir: the run directory.
        resume_after: ``None`` starts fresh (existing files are replaced);
            an update count keeps the existing rows up to it and appends after.
        tensorboard: also write TensorBoard event files (``tensorboard/seed_<s>/``).
    """

    def __init__(self, out_dir: str | os.PathLike, resume_after: int | None = None, tensorboard: bool = True):
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.jsonl_path = self.out_dir / JSONL_NAME
        self.csv_path = self.out_dir / CSV_NAME
        self.columns: list[str] | None = None
        kept: list[dict[str, Any]] = []
        if resume_after is not None:
            kept = [row for row in read_jsonl(self.jsonl_path) if row["update"] <= resume_after]
            if kept:
                self.columns = list(kept[0].keys())
        atomic_write_text(self.jsonl_path, "".join(self._jsonl_line(row) for row in kept))
        atomic_write_text(self.csv_path, self._csv_text(kept, header=bool(kept)))
        self.tensorboard = _TensorBoard(self.out_dir / TENSORBOARD_DIR, kept, fresh=resume_after is None) if (
            tensorboard
        ) else None

    def _jsonl_line(self, row: dict[str, Any]) -> str:
        return json.dumps({k: _clean(v) for k, v in row.items()}) + "\n"

    def _csv_text(self, rows: Sequence[dict[str, Any]], header: bool) -> str:
        if not rows:
            return ""
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=self.columns, extrasaction="raise", lineterminator="\n")
        if header:
            writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if (v := _clean(row.get(k))) is None else v) for k in self.columns})
        return buffer.getvalue()

    def append(self, rows: Sequence[dict[str, Any]]) -> None:
        """Append rows (all with the same keys as the first row ever written)."""
        if not rows:
            return
        header = self.columns is None
        if header:
            self.columns = list(rows[0].keys())
        for row in rows:
            if list(row.keys()) != self.columns:
                raise ValueError(f"metric row keys {list(row.keys())} differ from the file's columns {self.columns}")
        with open(self.jsonl_path, "a") as f:
            f.write("".join(self._jsonl_line(row) for row in rows))
        with open(self.csv_path, "a") as f:
            f.write(self._csv_text(rows, header=header))
        if self.tensorboard is not None:
            self.tensorboard.append(rows)

    def sync(self) -> None:
        """Flush every file to disk (called before a checkpoint is written)."""
        for path in (self.jsonl_path, self.csv_path):
            with open(path, "ab") as f:
                os.fsync(f.fileno())
        if self.tensorboard is not None:
            self.tensorboard.flush()

    def close(self) -> None:
        if self.tensorboard is not None:
            self.tensorboard.close()


def _summary_writer_class() -> type:
    """tensorboardX's ``SummaryWriter``, imported without PyTorch.

    tensorboardX imports ``torch`` when it is installed, only to recognise its tensors (1.6 s of every
    training command's start-up where PyTorch is present); we log Python floats. Unless ``torch`` is
    loaded already, its import is hidden for the moment tensorboardX loads, then allowed again.
    """
    import sys

    hide = "torch" not in sys.modules
    if hide:
        sys.modules["torch"] = None  # ``import torch`` raises ImportError, which tensorboardX handles
    try:
        from tensorboardX import SummaryWriter
    finally:
        if hide and sys.modules.get("torch", 0) is None:
            del sys.modules["torch"]
    return SummaryWriter


class _TensorBoard:
    """Per-seed tensorboardX writers of the scalar metrics (NaN values are skipped)."""

    def __init__(self, root: Path, kept: Sequence[dict[str, Any]], fresh: bool):
        import shutil

        if fresh and root.exists():
            shutil.rmtree(root)  # a fresh run replaces the old curves, as it replaces metrics.jsonl
        self.root = root
        # Resuming: events at or after the first step not covered by the kept rows are purged.
        last = {}
        for row in kept:
            last[row["seed"]] = max(last.get(row["seed"], -1), int(row["env_steps"]))
        self._purge = {seed: step + 1 for seed, step in last.items()}
        self._writers: dict[int, Any] = {}

    def _writer(self, seed: int):
        if seed not in self._writers:
            SummaryWriter = _summary_writer_class()

            # Event files are named by the second they are opened in; a nanosecond
            # suffix keeps a run resumed within the same second from replacing the
            # earlier file, and keeps the names in the order they were written.
            self._writers[seed] = SummaryWriter(
                str(self.root / f"seed_{seed}"),
                purge_step=self._purge.get(seed),
                flush_secs=3600,
                filename_suffix=f".{time.time_ns()}",
            )
        return self._writers[seed]

    def append(self, rows: Sequence[dict[str, Any]]) -> None:
        for row in rows:
            writer = self._writer(int(row["seed"]))
            step = int(row["env_steps"])
            for key, value in row.items():
                if key in INDEX_COLUMNS or not isinstance(value, (int, float, np.number)) or isinstance(value, bool):
                    continue
                value = float(value)
                if math.isfinite(value):
                    writer.add_scalar(key, value, global_step=step)

    def flush(self) -> None:
        for writer in self._writers.values():
            writer.flush()

    def close(self) -> None:
        for writer in self._writers.values():
            writer.close()
        self._writers.clear()


def plot_learning_curves(
    rows: Sequence[dict[str, Any]], path: str | os.PathLike, title: str = "", optimal_return: float | None = None,
    panels: Sequence[tuple[str, str]] = (),
) -> Path:
    """Learning curves against env steps: every seed thin, their mean bold.

    Panels: mean episode return, then ``panels`` (``(row key, label)``: the family's
    training rates and periodic evaluation metric) that the rows hold.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    seeds = sorted({row["seed"] for row in rows})
    panels = [("mean_return", "episode return"),
              *((key, label) for key, label in panels
                if any(not math.isnan(row.get(key, math.nan)) for row in rows))]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.0 * len(panels), 3.8), squeeze=False)
    for ax, (key, label) in zip(axes[0], panels):
        curves = []
        for seed in seeds:
            mine = [row for row in rows if row["seed"] == seed and not math.isnan(row.get(key, math.nan))]
            x = np.array([row["env_steps"] for row in mine], dtype=float)
            y = np.array([row[key] for row in mine], dtype=float)
            ax.plot(x, y, lw=0.8, alpha=0.5)
            curves.append(dict(zip(x, y)))
        common = sorted(set.intersection(*(set(c) for c in curves))) if curves else []
        if common:
            ax.plot(common, [np.mean([c[x] for c in curves]) for x in common], lw=2.5, color="black",
                    label=f"mean of {len(seeds)} seeds")
            ax.legend(loc="lower right", fontsize=8)
        if key == "mean_return" and optimal_return is not None:
            ax.axhline(optimal_return, ls="--", color="gray", lw=1)
        ax.set_xlabel("env steps per seed")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
    return path
