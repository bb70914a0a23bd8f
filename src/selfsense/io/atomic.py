"""Atomic, deterministic writing of pipeline artefacts.

Every writer here writes to a temporary file in the destination directory, flushes and fsyncs it, then
``os.replace``-s it over the target, so a crash or an exception mid-write never leaves a partial file
(docs/data_format.md: "never a half-written output"). Nothing is ever written under a ``data/raw`` folder.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import IO, Any, Iterator

from .outputs import file_mode

import numpy as np
import pandas as pd

__all__ = ["RawDataWriteError", "assert_not_in_raw", "atomic_write", "atomic_write_bytes", "atomic_write_text",
           "write_parquet_atomic", "write_json_atomic", "dumps_json", "write_text_atomic", "write_bytes_atomic",
           "parquet_bytes", "savefig_atomic"]


class RawDataWriteError(PermissionError):
    """Refusal to write inside ``data/raw`` or any raw dataset folder (raw datasets are read-only)."""


def assert_not_in_raw(path: str | os.PathLike) -> Path:
    """Raise :class:`RawDataWriteError` if ``path`` (resolved, symlinks followed) lies under any ``data/raw``, or
    inside any folder holding ``rig.yaml`` and ``trials.csv`` (a raw dataset, whatever its name)."""
    from .outputs import inside_dataset

    p = Path(path).expanduser()
    resolved = p.resolve()
    for cand in (p.absolute(), resolved):
        parts = cand.parts
        for i in range(len(parts) - 1):
            if parts[i] == "data" and parts[i + 1] == "raw":
                raise RawDataWriteError(f"refusing to write {p}: raw datasets under data/raw are read-only")
    ds = inside_dataset(resolved)
    if ds is not None:
        raise RawDataWriteError(f"refusing to write {p}: it lies inside the raw dataset {ds} (rig.yaml, trials.csv)")
    return p


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb", encoding: str | None = None) -> Iterator[IO]:
    """Context manager yielding a temp file beside ``path``; on success it replaces ``path`` atomically,
    on any exception the temp file is removed and ``path`` is untouched."""
    path = assert_not_in_raw(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, file_mode())  # mkstemp makes 0600; artefacts are 0666 minus the umask (0644 usually)
        with os.fdopen(fd, mode, encoding=encoding, **({"newline": ""} if "b" not in mode else {})) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    with atomic_write(path, "wb") as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    with atomic_write(path, "w", encoding=encoding) as fh:
        fh.write(text)
    return Path(path)


def write_text_atomic(text: str, path: str | os.PathLike, encoding: str = "utf-8") -> Path:
    """Same as :func:`atomic_write_text` with the payload first (like :func:`write_json_atomic`)."""
    return atomic_write_text(path, text, encoding)


def write_bytes_atomic(data: bytes, path: str | os.PathLike) -> Path:
    """Same as :func:`atomic_write_bytes` with the payload first."""
    return atomic_write_bytes(path, data)


def _parquet_table(df: pd.DataFrame, columns: list[str] | None = None):
    """The Arrow table written for ``df`` (or its ``columns``): checked index and names, no metadata."""
    import pyarrow as pa

    if not isinstance(df.index, pd.RangeIndex) or df.index.start != 0 or df.index.step != 1:
        raise ValueError("write_parquet_atomic: the frame must have a default RangeIndex; "
                         "call df.reset_index() (keep the index as a column) first")
    if not all(isinstance(c, str) for c in df.columns):
        raise ValueError("write_parquet_atomic: column names must be strings")
    cols = list(df.columns) if columns is None else list(columns)
    if all(df[c].dtype.kind in "fiub" for c in cols):
        # numeric columns: arrays straight from numpy (zero-copy data buffers; NaN -> null exactly as from_pandas),
        # so a long trial is not held twice -- same bytes as Table.from_pandas
        table = pa.Table.from_arrays([pa.array(df[c].to_numpy(), from_pandas=True) for c in cols], names=cols)
    else:
        table = pa.Table.from_pandas(df[cols], preserve_index=False).replace_schema_metadata(None)
    return table


_PARQUET_OPTIONS = dict(compression="zstd", compression_level=3, use_dictionary=False, write_statistics=True,
                        store_schema=False)


def parquet_bytes(df: pd.DataFrame, columns: list[str] | None = None) -> bytes:
    """Deterministic Parquet bytes of ``df``: no index, no pandas/arrow schema metadata, fixed options.

    The frame must have a default RangeIndex (a meaningful index would be silently lost: reset it first).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    sink = pa.BufferOutputStream()
    pq.write_table(_parquet_table(df, columns), sink, **_PARQUET_OPTIONS)
    return sink.getvalue().to_pybytes()


def write_parquet_atomic(df: pd.DataFrame, path: str | os.PathLike, columns: list[str] | None = None) -> Path:
    """Write ``df`` (or its ``columns``) to ``path`` as deterministic Parquet (same frame -> same bytes as
    :func:`parquet_bytes`), atomically, streamed into the temporary file (the bytes are never held in memory)."""
    import pyarrow.parquet as pq

    table = _parquet_table(df, columns)
    with atomic_write(path, "wb") as fh:
        pq.write_table(table, fh, **_PARQUET_OPTIONS)
    return Path(path)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _check_finite(o: Any, where: str = "") -> None:
    if isinstance(o, float) and not math.isfinite(o):
        raise ValueError(f"JSON artefacts must not contain NaN/inf (found {o!r} at {where or 'the top level'}); "
                         "use null")
    if isinstance(o, dict):
        for k, v in o.items():
            _check_finite(v, f"{where}.{k}" if where else str(k))
    elif isinstance(o, (list, tuple)):
        for i, v in enumerate(o):
            _check_finite(v, f"{where}[{i}]")


def dumps_json(obj: Any) -> str:
    """Deterministic JSON: sorted keys, 2-space indent, floats as ``repr`` (shortest round-trip), strict
    (no NaN/inf), numpy scalars/arrays converted, trailing newline."""
    text = json.dumps(obj, sort_keys=True, indent=2, ensure_ascii=False, allow_nan=True, default=_json_default)
    _check_finite(json.loads(text))
    return text + "\n"


def write_json_atomic(obj: Any, path: str | os.PathLike) -> Path:
    """Write ``obj`` as deterministic JSON (see :func:`dumps_json`), atomically; a NaN / inf is refused with the file
    and the key path that holds it (nothing is written)."""
    try:
        text = dumps_json(obj)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return atomic_write_text(path, text)


def savefig_atomic(fig, path: str | os.PathLike, **kw) -> Path:
    """``fig.savefig`` into a temp file beside ``path``, then an atomic rename (format from the suffix unless
    ``format=`` is given): a concurrent reader or a crash never sees a half-written figure."""
    path = Path(path)
    kw.setdefault("format", path.suffix.lstrip(".").lower() or "png")
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, **kw)
    return path
