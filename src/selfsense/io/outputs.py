"""Output folders that never destroy data: ownership marker, input guard, lock, all-or-nothing replacement.

Rules (every ``selfsense`` command that writes a folder or a file given by ``--out`` follows them):

* A folder is replaced only if it is empty, or was written by selfsense (it holds the marker file
  :data:`MARKER`), or ``force=True`` (``--force``). A folder holding ``rig.yaml`` or ``trials.csv`` (a raw
  dataset) is never replaced without ``force``, marker or not.
* No output may resolve (symlinks followed) to an input, lie inside an input folder, or contain an input.
* Nothing is written inside a raw dataset folder (a folder holding ``rig.yaml`` and ``trials.csv``), whatever
  its name (:func:`inside_dataset`).
* A folder is written all-or-nothing: into a temporary sibling, then renamed into place under an exclusive lock
  (a lock file in the temp folder named by the resolved path), so a crash or a concurrent second run never leaves a mixed file set:
  the second run stops with a message instead.
"""
from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

__all__ = ["MARKER", "OutputError", "check_output_dir", "check_output_file", "output_dir", "output_lock",
           "inside_dataset", "file_mode", "DATASET_FILES"]

#: file written into every folder a selfsense command creates (proof of ownership: it may be replaced)
MARKER = ".selfsense-output"
#: files that make a folder a raw dataset
DATASET_FILES = ("rig.yaml", "trials.csv")


class OutputError(ValueError):
    """An output location that would destroy data or overlap an input; the message is one line."""


def file_mode() -> int:
    """Permission bits for new files: 0o666 minus the process umask (0644 under the usual umask 022)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except OSError:  # pragma: no cover - not Linux
        pass
    old = os.umask(0o022)  # pragma: no cover
    os.umask(old)  # pragma: no cover
    return 0o666 & ~old  # pragma: no cover


def _resolve(p: str | os.PathLike) -> Path:
    return Path(p).expanduser().resolve()


def _is_dataset(d: Path) -> bool:
    return any((d / f).is_file() for f in DATASET_FILES)


def inside_dataset(path: str | os.PathLike) -> Path | None:
    """The raw dataset folder (holding rig.yaml and trials.csv) that contains ``path`` (not ``path`` itself),
    symlinks resolved; ``None`` if there is none."""
    p = _resolve(path)
    for anc in p.parents:
        if all((anc / f).is_file() for f in DATASET_FILES):
            return anc
    return None


def _overlap(out: Path, inputs: Iterable[str | os.PathLike]) -> str | None:
    for i in inputs:
        if i is None:
            continue
        ri = _resolve(i)
        if out == ri:
            return f"it resolves to the input {i}"
        if out.is_relative_to(ri):
            return f"it lies inside the input {i}"
        if ri.is_relative_to(out):
            return f"it contains the input {i}"
    return None


def check_output_file(out: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), what: str = "--out") -> Path:
    """Refuse an output file that resolves to, lies in or contains an input, is a folder, or lies in a dataset."""
    ro = _resolve(out)
    why = _overlap(ro, inputs)
    if why:
        raise OutputError(f"{what} {out}: refusing to write there: {why}")
    if ro.is_dir():
        raise OutputError(f"{what} {out}: expected a file path, found an existing folder")
    ds = inside_dataset(ro)
    if ds is not None:
        raise OutputError(f"{what} {out}: refusing to write inside the raw dataset {ds} (it holds rig.yaml/trials.csv)")
    return Path(out)


def check_output_dir(out: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), force: bool = False,
                     what: str = "--out", allow_in_dataset: bool = False) -> Path:
    """Refuse an output folder that would destroy data (see the module docstring); return it as a Path."""
    ro = _resolve(out)
    why = _overlap(ro, inputs)
    if why:
        raise OutputError(f"{what} {out}: refusing to write there: {why}")
    if not allow_in_dataset:
        ds = inside_dataset(ro)
        if ds is not None:
            raise OutputError(f"{what} {out}: refusing to write inside the raw dataset {ds} "
                              "(it holds rig.yaml/trials.csv)")
    if ro.exists() or Path(out).is_symlink():
        if not ro.is_dir():
            raise OutputError(f"{what} {out}: expected a folder (or nothing), found an existing file")
        if _is_dataset(ro) and not force:
            raise OutputError(f"{what} {out}: refusing to replace a folder holding rig.yaml/trials.csv (a dataset); "
                              "choose another folder or pass --force")
        if any(ro.iterdir()) and not (ro / MARKER).is_file() and not force:
            raise OutputError(f"{what} {out}: refusing to replace a non-empty folder that selfsense did not create "
                              f"(no {MARKER} file in it); choose another folder or pass --force")
    return Path(out)


def _lock_path(out: Path) -> Path:
    """Lock file of an output path: in the temp folder, named by a hash of the resolved path (no litter beside
    the user's folders; every process on this machine agrees on it)."""
    import hashlib

    d = Path(tempfile.gettempdir()) / f"selfsense-locks-{os.getuid() if hasattr(os, 'getuid') else 0}"
    d.mkdir(mode=0o700, exist_ok=True)
    return d / (hashlib.sha256(str(_resolve(out)).encode()).hexdigest()[:32] + ".lock")


@contextlib.contextmanager
def output_lock(out: str | os.PathLike, what: str = "--out") -> Iterator[None]:
    """Exclusive, non-blocking lock on the output path ``out`` (:func:`_lock_path`)."""
    import fcntl

    out = Path(out)
    _resolve(out).parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(_lock_path(out), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            if e.errno in (errno.EAGAIN, errno.EACCES):
                raise OutputError(f"{what} {out}: another selfsense command is writing this folder now; "
                                  "wait for it to finish (or choose another folder)") from None
            raise
        yield
    finally:
        os.close(fd)


@contextlib.contextmanager
def output_dir(out: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), force: bool = False,
               what: str = "--out", allow_in_dataset: bool = False) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``out``; on success it replaces ``out`` as a whole.

    Checked first (:func:`check_output_dir`), under an exclusive lock (:func:`output_lock`). The finished folder
    holds :data:`MARKER` and has mode 0o777 minus the umask. On any exception the temporary folder is removed
    and ``out`` is left exactly as it was.
    """
    inputs = list(inputs)
    out = Path(out)
    with output_lock(out, what):
        check_output_dir(out, inputs, force, what, allow_in_dataset)
        ro = _resolve(out)
        tmp = Path(tempfile.mkdtemp(prefix=f".{ro.name}.tmp-", dir=ro.parent))
        old: Path | None = None
        try:
            yield tmp
            (tmp / MARKER).write_text("written by selfsense; this folder may be replaced by the next run\n")
            os.chmod(tmp / MARKER, file_mode())
            os.chmod(tmp, file_mode() | ((file_mode() & 0o444) >> 2))  # rw- -> rwx where r is set
            if ro.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{ro.name}.old-", dir=ro.parent))
                os.rmdir(old)
                os.replace(ro, old)
            os.replace(tmp, ro)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            if old is not None and old.exists() and not ro.exists():
                os.replace(old, ro)  # put the previous folder back
                old = None
            raise
        finally:
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
