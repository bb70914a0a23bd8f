"""``trials.csv``: one row per trial log (docs/data_format.md).

Columns (all required, no others; order free): trial, file, role, tip, object_mm, reference, signal.
"""
from __future__ import annotations

import csv
import difflib
import io as _io
import math
import re
from pathlib import Path, PurePosixPath

import pandas as pd

from .errors import ContractError, Problem

__all__ = ["TRIAL_COLUMNS", "ALLOWED", "check_trials", "load_trials", "pipeline_problems", "TRIALS_FILE", "LOG_SUFFIXES"]

TRIALS_FILE = "trials.csv"
TRIAL_COLUMNS: tuple[str, ...] = ("trial", "file", "role", "tip", "object_mm", "reference", "signal")
ALLOWED: dict[str, tuple[str, ...]] = {
    "role": ("calibration", "validation"),
    "tip": ("free", "blocked", "object"),
    "reference": ("displacement", "force"),
    "signal": ("sine", "mixed", "steps", "other"),
}
LOG_SUFFIXES = (".csv", ".parquet", ".tdms", ".mat")
_TRIAL_RE = re.compile(r"[A-Za-z0-9_-]+")
_MAX_TRIALS_BYTES = 16 << 20


def _alts(values) -> str:
    values = [repr(v) for v in values]
    return ", ".join(values[:-1]) + " or " + values[-1] if len(values) > 1 else values[0]


def column_problems(file: str, found: list[str], required: tuple[str, ...]) -> list[Problem]:
    """Missing / extra / misspelt / duplicated column names (with a difflib suggestion)."""
    probs: list[Problem] = []
    seen: set[str] = set()
    for c in found:
        if c in seen:
            probs.append(Problem(file, c, None, "each column once", "duplicated column"))
        seen.add(c)
    missing = [c for c in required if c not in seen]
    extra = [c for c in found if c not in required]
    pair = len(missing) == 1 and len(extra) == 1  # one wrong name: surely a misspelling of the missing one
    for c in extra:
        close = missing if pair else difflib.get_close_matches(c, missing, n=1, cutoff=0.6)
        if close:
            probs.append(Problem(file, c, None, f"column {close[0]!r} (misspelt?)", "unknown column"))
        else:
            probs.append(Problem(file, c, None, "only the columns " + ", ".join(required), "unexpected column"))
    for c in missing:
        close = extra if pair else difflib.get_close_matches(c, extra, n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        probs.append(Problem(file, c, None, "this required column" + hint, "missing"))
    return probs


def check_trials(dataset_dir: str | Path) -> tuple[pd.DataFrame | None, list[Problem]]:
    """Read and check ``trials.csv``; return ``(DataFrame or None, problems)``. Never raises on bad data."""
    d = Path(dataset_dir)
    p = d / TRIALS_FILE
    F = TRIALS_FILE
    if not p.is_file():
        return None, [Problem(F, None, None, "a trials.csv file in the dataset folder", "no such file")]
    size = p.stat().st_size
    if size == 0:
        return None, [Problem(F, None, None, "a header line and at least one trial", "empty file")]
    if size > _MAX_TRIALS_BYTES:
        return None, [Problem(F, None, None, f"a small CSV file (< {_MAX_TRIALS_BYTES} bytes)", f"{size} bytes")]
    try:
        text = p.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as e:
        return None, [Problem(F, None, None, "UTF-8 text", f"undecodable byte at offset {e.start}")]
    if "\x00" in text:
        return None, [Problem(F, None, None, "a text CSV file", "NUL bytes (binary or corrupt file)")]
    try:
        rows = list(csv.reader(_io.StringIO(text, newline="")))
    except csv.Error as e:
        return None, [Problem(F, None, None, "valid CSV", str(e))]
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        return None, [Problem(F, None, None, "a header line and at least one trial", "empty file")]
    header = [h.strip() for h in rows[0]]
    probs = column_problems(F, header, TRIAL_COLUMNS)
    if probs:
        return None, probs
    body = rows[1:]
    if not body:
        return None, [Problem(F, None, None, "at least one trial row", "no rows")]
    recs = []
    ids: dict[str, int] = {}
    files: dict[str, int] = {}
    for i, r in enumerate(body, start=1):
        if len(r) != len(header):
            probs.append(Problem(F, None, i, f"{len(header)} cells", f"{len(r)} cells"))
            continue
        rec = {h: c.strip() for h, c in zip(header, r)}
        t = rec["trial"]
        if not _TRIAL_RE.fullmatch(t):
            probs.append(Problem(F, "trial", i, "an identifier matching [A-Za-z0-9_-]+", t))
        elif t in ids:
            probs.append(Problem(F, "trial", i, f"a unique trial id (already used in row {ids[t]})", t))
        else:
            ids[t] = i
        for col, allowed in ALLOWED.items():
            if rec[col] not in allowed:
                close = difflib.get_close_matches(rec[col], allowed, n=1, cutoff=0.5)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                probs.append(Problem(F, col, i, _alts(allowed) + hint, rec[col]))
        # object_mm: present and positive iff tip = object
        om = rec["object_mm"]
        obj = math.nan
        if rec["tip"] == "object":
            try:
                obj = float(om)
            except ValueError:
                obj = math.nan
            if not (math.isfinite(obj) and obj > 0):
                probs.append(Problem(F, "object_mm", i, "a positive object size in mm when tip = 'object'",
                                     om if om else "empty"))
        elif om != "":
            probs.append(Problem(F, "object_mm", i, f"an empty cell when tip = {rec['tip']!r}", om))
        # file: a relative path inside the dataset folder, an existing .csv/.parquet log
        f = rec["file"]
        pp = PurePosixPath(f.replace("\\", "/"))
        if not f:
            probs.append(Problem(F, "file", i, "a relative path to the trial log", "empty"))
        elif pp.is_absolute() or ".." in pp.parts or re.match(r"^[A-Za-z]:", f):
            probs.append(Problem(F, "file", i, "a relative path inside the dataset folder", f))
        elif pp.suffix.lower() not in LOG_SUFFIXES:
            probs.append(Problem(F, "file", i, "a .csv, .parquet, .tdms or .mat log", f))
        elif not (d / pp).is_file():
            probs.append(Problem(F, "file", i, "an existing log file", f"{f} (no such file)"))
        elif f in files:
            probs.append(Problem(F, "file", i, f"one trial per log (file already used in row {files[f]})", f))
        else:
            files[f] = i
        recs.append({**rec, "object_mm": obj, "_row": i})
    if not probs:
        cal = [r for r in recs if r["role"] == "calibration"]
        if not cal:
            probs.append(Problem(F, "role", None, "at least one 'calibration' trial", "none"))
        elif not any(r["tip"] == "free" for r in cal):
            probs.append(Problem(F, "tip", None,
                                 "at least one calibration trial with a free tip (it calibrates H(q))", "none"))
    if probs:
        return None, probs
    df = pd.DataFrame.from_records(recs, columns=[*TRIAL_COLUMNS, "_row"]).rename(columns={"_row": "row"})
    for c in ("trial", "file", "role", "tip", "reference", "signal"):
        df[c] = df[c].astype(object)
    df["object_mm"] = df["object_mm"].astype("float64")
    return df, probs


def load_trials(dataset_dir: str | Path) -> pd.DataFrame:
    """Load ``trials.csv`` as a DataFrame (columns of docs/data_format.md + ``row``; ``object_mm`` float, NaN
    when empty); raise :class:`ContractError` listing all problems."""
    df, probs = check_trials(dataset_dir)
    if probs or df is None:
        raise ContractError(probs, str(dataset_dir))
    return df


def pipeline_problems(trials: pd.DataFrame) -> list[Problem]:
    """What the pipeline needs beyond the contract (``selfsense validate`` and the ``validate_dataset`` rule
    check it, so a dataset never passes validation to fail later in a fit):

    * a calibration trial with reference ``displacement`` and one with reference ``force``: the A-coefficient
      regression (thesis ``000_18d138f03f1777c3.txt`` eq. (52)) needs both (thesis: free tip + laser, blocked
      tip + load cell);
    * at least one validation trial: Table 3 averages the validation trials.
    """
    F = TRIALS_FILE
    probs: list[Problem] = []
    cal = trials[trials["role"] == "calibration"]
    for ref, why in (("displacement", "free tip + laser"), ("force", "blocked tip + load cell")):
        if not (cal["reference"] == ref).any():
            probs.append(Problem(F, "reference", None,
                                 f"at least one calibration trial with reference {ref!r} (the A-coefficient "
                                 f"regression of thesis eq. 52 needs both; typically {why})", "none"))
    if not (trials["role"] == "validation").any():
        probs.append(Problem(F, "role", None, "at least one 'validation' trial (Table 3 averages them)", "none"))
    return probs
