"""Checkpoints: a runner-state pytree plus JSON metadata, written atomically.

A checkpoint is one msgpack file holding

- ``metadata``: a JSON string with the algorithm, environment name and
  overrides, the algorithm config, the seeds, how many updates are done, the
  ``wrl_jax`` version and anything else the driver wants back on resume;
- ``leaves``: every array leaf of the runner state, keyed by its pytree path
  (``jax.tree_util.keystr``), as NumPy arrays (typed PRNG keys are stored as
  their raw key data and re-wrapped on load).

Keying by path rather than relying on flax's state-dict conversion means any
pytree an algorithm uses (optax states, replay buffers, ``flax.struct``
dataclasses) round-trips without registration, and a mismatch names the
exact leaf. Loading needs a *template* (e.g. ``jax.eval_shape`` of the
algorithm's init) and checks every leaf's path, shape and dtype against it;
:func:`check_compatible` compares metadata fields and raises
:class:`CheckpointMismatchError` naming each difference.

Writes are atomic: a temporary file in the same directory, ``fsync``, then
``os.replace`` (and an ``fsync`` of the directory), so a crash leaves either the
old checkpoint or the new one, never a torn file.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

FORMAT_VERSION = 1
CHECKPOINT_NAME = "checkpoint.msgpack"


class CheckpointError(ValueError):
    """A checkpoint is missing, unreadable, or does not fit the runner it is loaded into."""


class CheckpointMismatchError(CheckpointError):
    """The checkpoint was written by a different configuration than the one resuming it."""


def wrl_jax_version() -> str:
    """The installed ``wrl_jax`` version, or the source tree's from ``pyproject.toml``."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("wrl_jax")
    except PackageNotFoundError:
        pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
        if pyproject.exists():
            import tomllib

            return str(tomllib.loads(pyproject.read_text())["project"]["version"])
        return "unknown"


# ------------------------------------------------------------------ atomic io
def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old file or the new one, never a mix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # not every platform can open a directory
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# -------------------------------------------------------------------- leaves
def _is_key(x: Any) -> bool:
    return hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jax.dtypes.prng_key)


def _flatten(tree: Any) -> dict[str, Any]:
    flat, _ = jax.tree_util.tree_flatten_with_path(tree)
    out = {}
    for path, leaf in flat:
        name = jax.tree_util.keystr(path)
        if name in out:
            raise CheckpointError(f"two leaves share the path {name!r}")
        out[name] = leaf
    return out


def to_bytes(tree: Any, metadata: dict[str, Any]) -> bytes:
    """Serialize a runner-state pytree and its metadata to msgpack bytes."""
    leaves = {}
    for name, leaf in _flatten(tree).items():
        if _is_key(leaf):
            leaf = jax.random.key_data(leaf)
        leaves[name] = np.asarray(leaf)
    payload = {"format_version": FORMAT_VERSION, "metadata": json.dumps(metadata, sort_keys=True), "leaves": leaves}
    return serialization.msgpack_serialize(payload)


def _read_payload(path: Path) -> dict[str, Any]:
    if not path.exists():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        payload = serialization.msgpack_restore(path.read_bytes())
    except Exception as exc:  # msgpack raises several types
        raise CheckpointError(f"cannot read checkpoint {path}: {exc}") from exc
    if not isinstance(payload, dict) or "leaves" not in payload or "metadata" not in payload:
        raise CheckpointError(f"{path} is not a wrl_jax checkpoint")
    if payload.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path} has checkpoint format {payload.get('format_version')}, this wrl_jax reads format {FORMAT_VERSION}"
        )
    return payload


def resolve(path: str | os.PathLike) -> Path:
    """A checkpoint file, given the file itself or the run directory holding it."""
    path = Path(path)
    return path / CHECKPOINT_NAME if path.is_dir() else path


# ------------------------------------------------------------------ save/load
def save(path: str | os.PathLike, tree: Any, metadata: dict[str, Any]) -> Path:
    """Atomically write ``tree`` (the runner state) and ``metadata`` (JSON-able) to ``path``.

    ``path`` may be a run directory, in which case the file is ``checkpoint.msgpack`` in it.
    The ``wrl_jax`` version and the format version are added to the metadata.
    """
    path = Path(path)
    if path.suffix != ".msgpack":
        path = path / CHECKPOINT_NAME
    metadata = {**metadata, "wrl_jax_version": wrl_jax_version(), "format_version": FORMAT_VERSION}
    atomic_write_bytes(path, to_bytes(jax.device_get(tree), metadata))
    return path


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The metadata of a checkpoint (file or run directory), without building any arrays."""
    return json.loads(_read_payload(resolve(path))["metadata"])


def load(path: str | os.PathLike, template: Any, expected: dict[str, Any] | None = None,
         absent: dict[str, Any] | None = None) -> tuple[Any, dict]:
    """Read a checkpoint into the structure of ``template``.

    Args:
        path: the checkpoint file or its run directory.
        template: a pytree with the runner's structure; leaves may be arrays or
            ``jax.ShapeDtypeStruct`` (``jax.eval_shape`` of the batched init).
        expected: metadata fields that must match (see :func:`check_compatible`).
        absent: what a field missing from an older checkpoint stands for (see :func:`check_compatible`).

    Returns:
        ``(tree, metadata)`` with the tree's leaves as ``jax.Array``.

    Raises:
        CheckpointMismatchError: a metadata field differs from ``expected``.
        CheckpointError: a leaf is missing, extra, or has another shape or dtype.
    """
    path = resolve(path)
    payload = _read_payload(path)
    metadata = json.loads(payload["metadata"])
    if expected is not None:
        check_compatible(metadata, expected, where=str(path), absent=absent)
    stored: dict[str, np.ndarray] = payload["leaves"]
    template_leaves = _flatten(template)
    missing = sorted(set(template_leaves) - set(stored))
    extra = sorted(set(stored) - set(template_leaves))
    if missing or extra:
        raise CheckpointError(
            f"checkpoint {path} does not fit this runner state: missing leaves {missing[:5]}, "
            f"unexpected leaves {extra[:5]} (was it written by another algorithm or version?)"
        )
    restored = {}
    for name, like in template_leaves.items():
        value = np.asarray(stored[name])
        if _is_key(like):
            impl = jax.random.key_impl(like) if isinstance(like, jax.Array) else like.dtype._impl
            try:
                key = jax.random.wrap_key_data(jnp.asarray(value), impl=impl)
            except (TypeError, ValueError) as exc:
                raise CheckpointError(f"leaf {name}: stored key data {value.dtype}{list(value.shape)} is not a key "
                                      f"of this run's kind: {exc}") from exc
            if key.shape != tuple(like.shape):
                raise CheckpointError(f"leaf {name}: checkpoint has {key.shape} keys, this run expects {like.shape}")
            restored[name] = key
            continue
        if tuple(value.shape) != tuple(like.shape) or value.dtype != np.dtype(like.dtype):
            raise CheckpointError(
                f"leaf {name}: checkpoint has {value.dtype}{list(value.shape)}, this run expects "
                f"{np.dtype(like.dtype)}{list(like.shape)} (different seeds, network size or number of envs?)"
            )
        restored[name] = jnp.asarray(value)
    treedef = jax.tree_util.tree_structure(template)
    order = list(template_leaves)
    return jax.tree_util.tree_unflatten(treedef, [restored[name] for name in order]), metadata


def check_compatible(saved: dict[str, Any], expected: dict[str, Any], where: str = "checkpoint",
                     absent: dict[str, Any] | None = None) -> None:
    """Raise :class:`CheckpointMismatchError` listing every field of ``expected`` that ``saved`` differs in.

    Nested dicts (the algorithm config, environment overrides) are compared key by key
    so the message names e.g. ``config.learning_rate``. ``absent`` (nested alike) gives the value a key
    missing from ``saved`` stands for: a setting added after the checkpoint was written, whose default
    is what that run trained with.
    """
    differences = list(_differences(saved, expected, prefix="", absent=absent or {}))
    if differences:
        lines = "\n".join(f"  {name}: checkpoint has {old!r}, this run has {new!r}" for name, old, new in differences)
        raise CheckpointMismatchError(
            f"{where} was written by a different configuration:\n{lines}\n"
            "Resume with the same settings (the checkpoint's are used when you pass only --resume --out DIR), "
            "or train into another --out directory."
        )


def _differences(saved: Any, expected: Any, prefix: str, absent: Any) -> Iterable[tuple[str, Any, Any]]:
    if isinstance(expected, dict):
        saved = saved if isinstance(saved, dict) else {}
        absent = absent if isinstance(absent, dict) else {}
        for key in expected:
            missing = absent[key] if key in absent and not isinstance(absent[key], dict) else "<absent>"
            yield from _differences(saved.get(key, missing), expected[key], f"{prefix}{key}.", absent.get(key))
        return
    saved_j, expected_j = json.loads(json.dumps(saved)), json.loads(json.dumps(expected))
    if saved_j != expected_j:
        yield prefix.rstrip("."), saved_j, expected_j
