"""Provenance of a report: package version, git commit of the code, dataset content hash and date.

Deterministic for the same code, data and configuration (no wall-clock time): the data date is the newest
modification time of the raw files, the hash covers their bytes and relative names only.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import platform
import subprocess
from pathlib import Path
from typing import Any

__all__ = ["dataset_files", "dataset_hash", "git_commit", "provenance"]


def dataset_files(dataset_dir: str | Path) -> list[Path]:
    """``rig.yaml``, ``trials.csv`` and every log listed in ``trials.csv`` that exists, sorted by relative name."""
    import csv

    d = Path(dataset_dir)
    files = [d / "rig.yaml", d / "trials.csv"]
    tp = d / "trials.csv"
    if tp.is_file():
        with open(tp, newline="", encoding="utf-8-sig") as fh:
            for row in csv.DictReader(fh):
                f = (row.get("file") or "").strip()
                if f:
                    files.append(d / f)
    return sorted({f for f in files if f.is_file()}, key=lambda p: p.relative_to(d).as_posix())


def dataset_hash(dataset_dir: str | Path) -> tuple[str, int]:
    """SHA-256 over (relative name, SHA-256 of the bytes) of :func:`dataset_files`; returns (hex, n_files)."""
    d = Path(dataset_dir)
    h = hashlib.sha256()
    files = dataset_files(d)
    for f in files:
        fh = hashlib.sha256()
        with open(f, "rb") as src:
            for block in iter(lambda: src.read(1 << 20), b""):
                fh.update(block)
        h.update(f.relative_to(d).as_posix().encode() + b"\0" + fh.hexdigest().encode() + b"\n")
    return h.hexdigest(), len(files)


def git_commit(path: str | Path) -> str:
    """``<commit>`` (``+ local changes`` when the work tree differs) of the git checkout holding ``path``, or a
    note that the code is not a git checkout (an installed package)."""
    p = Path(path).resolve()
    cwd = p if p.is_dir() else p.parent
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True, timeout=10)
        if rev.returncode != 0:
            return "not a git checkout (installed package)"
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=cwd,
                               capture_output=True, text=True, timeout=30)
        return rev.stdout.strip() + (" + local changes" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown (git not available)"


def provenance(dataset_dir: str | Path) -> dict[str, Any]:
    """The provenance block of a report for ``dataset_dir``."""
    import selfsense
    from selfsense import version

    d = Path(dataset_dir)
    digest, n = dataset_hash(d)
    files = dataset_files(d)
    newest = max((f.stat().st_mtime for f in files), default=None)
    out: dict[str, Any] = {
        "selfsense_version": version(),
        "git_commit": git_commit(Path(selfsense.__file__).parent),
        "dataset": d.name,
        "dataset_sha256": digest,
        "n_files": n,
        "data_date": (_dt.datetime.fromtimestamp(newest, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
                      if newest is not None else "n/a"),
        "python": platform.python_version(),
    }
    try:
        from importlib.metadata import version as _v

        out["snakemake"] = _v("snakemake")
    except Exception:  # pragma: no cover
        pass
    return out
