"""Trial DAQ logs (CSV or Parquet): reading and checking against the raw-dataset contract.

Canonical channels (docs/data_format.md): ``t`` [s], ``u_cmd`` [V], ``v_shunt`` [V], ``laser`` [V],
``load_cell`` [V], ``relay`` [0/1]. A rig may map other column names/units onto these through
``rig.yaml: channel_map`` (see :mod:`selfsense.io.rig`).

Cheap checks first: the file size, the magic bytes / header line / Parquet footer are inspected before the
body is read, so a wrong or corrupt multi-GB file fails in milliseconds instead of being read whole.
"""
from __future__ import annotations

import csv
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from selfsense.signals.runs import true_runs

from .errors import ContractError, Problem
from .rig import CANONICAL_COLUMNS, Rig, shunt_zero
from .trials import column_problems

__all__ = ["read_log", "check_log", "check_signals", "LIMITS"]

#: plausibility limits (documented in docs/data_format.md)
LIMITS = {
    "u_cmd_max_v": 10.5,        # amplifier input is 0-10 V: more means mV logged as V
    "u_cmd_min_v": -1.0,
    "u_cmd_min_peak_v": 0.05,   # a drive smaller than this is no drive (or V logged as kV)
    "rate_tolerance": 0.05,     # |fs_measured / sample_rate_hz - 1|
    "gap_periods": 3.0,         # a step > 3 nominal periods is a gap
    "step_spread": 0.05,        # |step / period - 1| of the steps that are not gaps: above it, a warning
    "rail_fraction": 0.999,     # |x| >= 0.999 * adc_range_v counts as "at the rail"
    "rail_max_share": 0.005,    # more than 0.5 % of samples at the rail = saturated
    "rail_max_run": 10,         # or this many consecutive samples at the rail
    "clip_min_level": 0.5,      # identical extreme runs only count above 0.5 * adc_range_v
    "adc_overrange": 1.05,      # |x| > 1.05 * adc_range_v cannot come from the ADC: wrong units
}
_PROBE = 1 << 16  # bytes read at the start / end of a file for the cheap checks
_ANALOG = ("u_cmd", "v_shunt", "laser", "load_cell")


def _kind(path: Path, rig: Rig | None) -> str | None:
    if rig is not None and rig.format != "auto":
        return rig.format
    s = path.suffix.lower()
    return {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".tdms": "tdms", ".mat": "mat"}.get(s)


def _probe(path: Path, size: int) -> tuple[bytes, bytes]:
    with open(path, "rb") as fh:
        head = fh.read(min(size, _PROBE))
        if size > _PROBE:
            fh.seek(max(size - _PROBE, _PROBE))
            tail = fh.read()
        else:
            tail = head
    return head, tail


def _csv_header(name: str, path: Path, size: int, wanted: tuple[str, ...] = ()
                ) -> tuple[list[str] | None, list[Problem], int, bool]:
    """``(header, problems, skip, units_row)``: the column names, the number of preamble lines before the header
    line and whether a units row (no number in any cell) follows it.

    The header is the first line; a scope export that starts with preamble lines (instrument, date, settings...)
    is accepted when a later line within the first 64 KiB names every wanted column: the lines before it are
    skipped (docs/data_format.md, "Oscilloscope CSV")."""
    head, tail = _probe(path, size)
    if b"\x00" in head or b"\x00" in tail:
        return None, [Problem(name, None, None, "a text CSV file", "NUL bytes (binary, sparse or corrupt file)")], 0, False
    nl = head.find(b"\n")
    if nl < 0 and size > len(head):
        return None, [Problem(name, None, None, f"a header line within the first {_PROBE} bytes",
                              "no line break")], 0, False
    # the probe may cut the last line (and a multi-byte character in it): only its complete lines are decoded,
    # strictly, so that a byte of another encoding is reported rather than dropped from a column name
    whole = head if size <= len(head) else head[:head.rfind(b"\n") + 1]
    try:
        text = whole.decode("utf-8-sig", errors="strict")
    except UnicodeDecodeError as e:
        line = whole[:e.start].count(b"\n") + 1
        return None, [Problem(name, None, None, "UTF-8 text (save the file as UTF-8)",
                              f"the byte {whole[e.start:e.start + 1]!r} in line {line} of the file")], 0, False
    lines = text.split("\n")
    if size > len(head):
        lines = lines[:-1]  # the line break that ends the decoded part leaves an empty last item
    rows = [[h.strip() for h in next(csv.reader([ln.rstrip("\r")]), [])] for ln in lines[:200]]
    if not rows or not any(rows[0]):
        if not any(any(r) for r in rows):
            return None, [Problem(name, None, None, "a header line naming the columns", "blank first line")], 0, False
    skip = 0
    if wanted and not set(wanted) <= set(rows[0]):
        for i, r in enumerate(rows[1:], start=1):
            if set(wanted) <= set(r):
                skip = i
                break
    header = rows[skip]
    if not any(header):
        return None, [Problem(name, None, None, "a header line naming the columns", "blank first line")], 0, False
    units = False
    if skip + 1 < len(rows):
        nxt = [c for c in rows[skip + 1] if c]
        units = bool(nxt) and len(rows[skip + 1]) == len(header) and not any(_is_number(c) for c in nxt)
    return header, [], skip, units


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _note(name: str, msg: str) -> None:
    """A note about a log that is read anyway (extra channels, scope preamble): the rule log / stderr."""
    import logging

    logging.getLogger("selfsense.io").warning("note: %s: %s", name, msg)


def _parquet_header(name: str, path: Path, size: int):
    import pyarrow.parquet as pq

    head, tail = _probe(path, size)
    if size < 12 or head[:4] != b"PAR1" or tail[-4:] != b"PAR1":
        return None, None, [Problem(name, None, None, "a Parquet file (PAR1 magic at both ends)",
                                    "missing magic bytes: truncated or corrupt file")]
    try:
        pf = pq.ParquetFile(path)
        schema = pf.schema_arrow
    except Exception as e:  # noqa: BLE001 - pyarrow raises several types; report one line
        return None, None, [Problem(name, None, None, "a readable Parquet footer",
                                    f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}")]
    names = [n for n in schema.names if not (n.startswith("__index_level_") and n.endswith("__"))]
    return pf, names, []


def _bad_cells(name: str, raw: pd.DataFrame, cols: list[str]) -> tuple[pd.DataFrame, list[Problem]]:
    """Coerce text columns to float; one Problem per column naming the first non-numeric cell."""
    probs: list[Problem] = []
    out = {}
    for c in cols:
        s = raw[c]
        if pd.api.types.is_numeric_dtype(s) or pd.api.types.is_bool_dtype(s):
            out[c] = s.astype("float64")
            continue
        txt = s.astype(object)
        num = pd.to_numeric(txt, errors="coerce")
        blank = txt.isna() | txt.map(lambda v: isinstance(v, str) and v.strip().lower() in ("", "nan", "na"))
        bad = num.isna().to_numpy() & ~blank.to_numpy()
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            n = int(bad.sum())
            more = f" ({n} non-numeric cells, first shown)" if n > 1 else ""
            cell = str(txt.iloc[i])
            hint = ""
            if re.fullmatch(r"\s*[-+]?\d+,\d+([eE][-+]?\d+)?\s*", cell):
                hint = " with a decimal point (the file uses a decimal comma: export it with '.' as the decimal mark)"
            probs.append(Problem(name, c, i + 1, "a number" + hint + more, cell))
        out[c] = num.astype("float64")
    return pd.DataFrame(out), probs


def _runs_max(mask: np.ndarray) -> int:
    if not mask.any():
        return 0
    starts, ends = true_runs(mask)
    return int((ends - starts).max())


def first_true(mask: np.ndarray) -> tuple[int, int] | None:
    """``(index of the first True entry, number of True entries)`` of ``mask``, or None where none is True."""
    hits = np.flatnonzero(mask)
    return (int(hits[0]), int(hits.size)) if hits.size else None


def relay_not_binary(r: np.ndarray) -> tuple[int, int] | None:
    """The relay contract (docs/data_format.md): :func:`first_true` of the finite samples of ``r`` that are neither 0
    nor 1 (a relay logged as 0 / 5 V, say; non-finite samples are the finiteness check's)."""
    return first_true(np.isfinite(r) & (r != 0) & (r != 1))


def time_steps_not_increasing(t: np.ndarray) -> list[tuple[str, int, int]]:
    """The steps of the finite time stamps ``t`` that break strictly increasing time: ``(what, k, count)`` for
    ``what`` = ``'duplicated'`` and then ``'decreasing'`` where any is, ``k`` the index of the earlier sample of the
    first such step and ``count`` the number of such steps. One rule for :func:`check_signals` (a whole log) and
    ``selfsense estimate`` (a log read block by block, the last time of the previous block prepended)."""
    dt = np.diff(np.asarray(t, dtype=float))
    out = []
    for what, mask in (("duplicated", dt == 0), ("decreasing", dt < 0)):
        hit = first_true(mask)
        if hit is not None:
            out.append((what, hit[0], hit[1]))
    return out


def check_signals(df: pd.DataFrame, rig: Rig | None = None, reference: str | None = None,
                  name: str = "<log>") -> list[Problem]:
    """Physics-free plausibility checks of a canonical log frame (columns ``CANONICAL_COLUMNS``).

    ``reference`` (``'displacement'`` / ``'force'`` / ``None``) says which reference channel must be finite;
    with ``None`` NaN is allowed in both ``laser`` and ``load_cell`` (inf never is).
    """
    probs: list[Problem] = []
    n = len(df)
    if n == 0:
        return [Problem(name, None, None, "at least 2 samples", "no data rows (empty log)")]
    if n < 2:
        return [Problem(name, None, None, "at least 2 samples", f"{n} row")]
    adc = rig.adc_range_v if rig is not None else 10.0
    arr = {c: df[c].to_numpy(dtype=np.float64) for c in CANONICAL_COLUMNS}
    must_be_finite = {"t", "u_cmd", "v_shunt", "relay"}
    if reference == "displacement":
        must_be_finite.add("laser")
    elif reference == "force":
        must_be_finite.add("load_cell")
    for c in CANONICAL_COLUMNS:
        x = arr[c]
        inf = np.isinf(x)
        if inf.any():
            i = int(np.flatnonzero(inf)[0])
            probs.append(Problem(name, c, i + 1, f"finite values ({int(inf.sum())} inf)", float(x[i])))
        nan = np.isnan(x)
        if c in must_be_finite and nan.any():
            i = int(np.flatnonzero(nan)[0])
            why = f" (reference = {reference!r})" if c in ("laser", "load_cell") else ""
            probs.append(Problem(name, c, i + 1, f"no NaN in a required channel{why} ({int(nan.sum())} NaN)",
                                 "NaN"))
    # --- time -------------------------------------------------------------------------------------
    t = arr["t"]
    fin = np.isfinite(t)
    if fin.sum() >= 2:
        idx = np.flatnonzero(fin)
        dt = np.diff(t[idx])
        rows = idx[1:] + 1  # 1-based row of the later sample
        for what, k, count in time_steps_not_increasing(t[idx]):
            probs.append(Problem(name, "t", int(rows[k]), f"strictly increasing time ({count} {what} steps)",
                                 f"{what} time t = {t[idx[k + 1]]:.9g} s after {t[idx[k]]:.9g} s"))
        pos = dt[dt > 0]
        if pos.size:
            med = float(np.median(pos))
            fs_meas = 1.0 / med
            period = med
            if rig is not None:
                fs = rig.sample_rate_hz
                if abs(fs_meas / fs - 1.0) > LIMITS["rate_tolerance"]:
                    ratio = fs_meas / fs
                    hint = ""
                    if 5e-4 < ratio < 2e-3:
                        hint = " (t logged in ms? then set rig.yaml channel_map: {scale: {t: 1.0e-3}})"
                    elif 5e-7 < ratio < 2e-6:
                        hint = " (t logged in us? then set rig.yaml channel_map: {scale: {t: 1.0e-6}})"
                    probs.append(Problem(name, "t", None,
                                         f"a sample rate within 5 % of rig.yaml sample_rate_hz = {fs:g} Hz{hint}",
                                         f"{fs_meas:.6g} Hz (median step {med:.6g} s)"))
                else:
                    period = 1.0 / fs
            gap = dt > LIMITS["gap_periods"] * period
            if gap.any():
                k = int(np.flatnonzero(gap)[0])
                probs.append(Problem(name, "t", int(rows[k]),
                                     f"no gaps longer than {LIMITS['gap_periods']:g} sample periods "
                                     f"({period:.6g} s; {int(gap.sum())} gaps)",
                                     f"a step of {dt[k]:.6g} s"))
            # steps that are neither gaps nor the sample period: a time base that cannot resolve its own steps
            # (float64 time stamps far from 0: at 1e12 s they resolve 1.2e-4 s) or an irregularly clocked log
            ok = (dt > 0) & ~gap
            off = np.abs(dt[ok] / period - 1.0) if ok.any() else np.zeros(0)
            if off.size and off.max() > LIMITS["step_spread"]:
                k = int(np.flatnonzero(ok)[int(np.argmax(off))])
                res = float(np.spacing(np.max(np.abs(t[idx]))))
                hint = (f"; t reaches {np.max(np.abs(t[idx])):.3g} s, where float64 resolves only {res:.2g} s: "
                        "subtract the first time stamp" if res > 0.01 * period else
                        "; time stamps rounded to too few digits or stored as float32, or an irregular clock?")
                probs.append(Problem(name, "t", int(rows[k]),
                                     f"steps within {LIMITS['step_spread']:.0%} of the sample period "
                                     f"{period:.6g} s (the estimate assumes a fixed rate)",
                                     f"{int((off > LIMITS['step_spread']).sum())} steps off by up to "
                                     f"{off.max():.0%}{hint}", level="warning"))
    # --- relay ------------------------------------------------------------------------------------
    r = arr["relay"]
    rf = r[np.isfinite(r)]
    bad = relay_not_binary(r)
    if bad is not None:
        i, count = bad
        probs.append(Problem(name, "relay", i + 1, f"0 or 1 ({count} other values)", float(r[i])))
    elif rf.size:
        if not (rf == 1).any():
            probs.append(Problem(name, "relay", 1, "relay = 1 (leads shorted) at the start of the log",
                                 "relay never 1 (never shorts)"))
        elif r[0] != 1:
            probs.append(Problem(name, "relay", 1, "relay = 1 (leads shorted) at the start of the log",
                                 float(r[0])))
        elif (rf == 1).all():
            probs.append(Problem(name, "relay", None, "relay = 0 at some point (actuator connected)",
                                 "relay always 1"))
    # --- analog channels: units and saturation ---------------------------------------------------
    u = arr["u_cmd"]
    uf = u[np.isfinite(u)]
    u_hi = rig.u_cmd_max_v if rig is not None else LIMITS["u_cmd_max_v"]
    u_lo = rig.u_cmd_min_v if rig is not None else LIMITS["u_cmd_min_v"]
    default_range = (u_lo, u_hi) == (LIMITS["u_cmd_min_v"], LIMITS["u_cmd_max_v"])
    why = ("amplifier input 0-10 V; a bipolar drive or a logged amplifier output is declared in rig.yaml drive"
           if default_range else "rig.yaml drive")
    if uf.size:
        umax, umin = float(uf.max()), float(uf.min())
        if umax > u_hi:
            i = int(np.flatnonzero(u > u_hi)[0])
            probs.append(Problem(name, "u_cmd", i + 1,
                                 f"u_cmd <= {u_hi:g} V ({why}{'; mV logged as V?' if default_range else ''})",
                                 f"max {umax:.6g} V"))
        elif umin < u_lo:
            i = int(np.flatnonzero(u < u_lo)[0])
            probs.append(Problem(name, "u_cmd", i + 1, f"u_cmd >= {u_lo:g} V ({why})", f"min {umin:.6g} V"))
        elif max(abs(umax), abs(umin)) < LIMITS["u_cmd_min_peak_v"]:
            probs.append(Problem(name, "u_cmd", None,
                                 f"a drive signal, max |u_cmd| >= {LIMITS['u_cmd_min_peak_v']:g} V "
                                 "(no drive, or V logged as kV?)", f"max |u_cmd| {max(abs(umax), abs(umin)):.3g} V"))
    for c in ("v_shunt", "laser", "load_cell"):
        x = arr[c]
        xf = x[np.isfinite(x)]
        if xf.size == 0:
            continue
        amax = float(np.abs(xf).max())
        if amax > LIMITS["adc_overrange"] * adc:
            i = int(np.flatnonzero(np.abs(x) > LIMITS["adc_overrange"] * adc)[0])
            probs.append(Problem(name, c, i + 1,
                                 f"values within the +-{adc:g} V ADC range (mV logged as V? then scale this channel "
                                 "by 1.0e-3 in rig.yaml channel_map.scale)", f"{x[i]:.6g} V"))
            continue
        rail = np.abs(x) >= LIMITS["rail_fraction"] * adc
        nr = int(rail.sum())
        if nr and (nr > LIMITS["rail_max_share"] * n or _runs_max(rail) >= LIMITS["rail_max_run"]):
            i = int(np.flatnonzero(rail)[0])
            probs.append(Problem(name, c, i + 1, f"no samples pinned at the +-{adc:g} V ADC rails (saturation)",
                                 f"{nr} samples ({100.0 * nr / n:.2g} %) at |x| >= {LIMITS['rail_fraction'] * adc:g} V"))
            continue
        if amax >= LIMITS["clip_min_level"] * adc:
            need = max(LIMITS["rail_max_run"], math.ceil(LIMITS["rail_max_share"] * n))
            zero = shunt_zero(x, arr["relay"]) if c == "v_shunt" and "relay" in arr else 0.0
            for ext, is_max in ((float(xf.max()), True), (float(xf.min()), False)):
                if abs(ext) < LIMITS["clip_min_level"] * adc:
                    continue
                if c == "v_shunt" and rig is not None and rig.at_current_limit(ext, zero, is_max):
                    continue   # the HV amplifier's declared current limit (rig.yaml amplifier_current_limit_a)
                at = x == ext
                if _runs_max(at) >= need:
                    i = int(np.flatnonzero(at)[0])
                    probs.append(Problem(name, c, i + 1, "no runs of identical extreme values (clipped channel)",
                                         f"{_runs_max(at)} consecutive samples at {ext:.6g} V"))
                    break
    if "v_shunt" in arr:
        v = arr["v_shunt"]
        vf = v[np.isfinite(v)]
        if vf.size > 1 and float(vf.max()) == float(vf.min()):
            probs.append(Problem(name, "v_shunt", None, "a varying shunt signal (in-amp connected?)",
                                 f"constant {vf[0]:.6g} V"))
    return probs


def _too_long(name: str, n: int, max_rows: int | None) -> list[Problem]:
    if max_rows is None or n <= max_rows:
        return []
    return [Problem(name, None, None, f"at most {max_rows:,} samples per trial (the pipeline's sample budget, config "
                    "max_trial_samples: every job stays below 2 GB up to it; split the log into trials, or stream it "
                    "with 'selfsense estimate', which has no length limit)", f"{n:,} samples")]


def _count_csv_rows(path: Path) -> int:
    """Data lines of a CSV file (newlines minus the header), counted in 1 MiB blocks (bounded memory)."""
    n = 0
    last = b"\n"
    with open(path, "rb") as fh:
        while True:
            b = fh.read(1 << 20)
            if not b:
                break
            n += b.count(b"\n")
            last = b[-1:]
    return n + (last != b"\n") - 1


def check_log(path: str | Path, rig: Rig | None = None, reference: str | None = None,
              name: str | None = None, max_rows: int | None = None) -> tuple[pd.DataFrame | None, list[Problem]]:
    """Read and check one trial log; return ``(canonical DataFrame or None, problems)``.

    ``max_rows`` (the pipeline's sample budget): a longer CSV or Parquet log is refused from its row count, before
    its body is read.

    Never raises on bad data. The frame has the columns ``CANONICAL_COLUMNS`` as float64 in SI
    (after ``rig.channel_map`` renaming/scaling) and a RangeIndex; it is ``None`` when the file could not
    be read (missing, empty, corrupt, wrong header).
    """
    path = Path(path)
    name = name or path.name
    if not path.is_file():
        return None, [Problem(name, None, None, "an existing log file", "no such file")]
    size = path.stat().st_size
    if size == 0:
        return None, [Problem(name, None, None, "a header line and data rows", "empty file (0 bytes)")]
    kind = _kind(path, rig)
    if kind is None:
        return None, [Problem(name, None, None, "a .csv, .parquet, .tdms or .mat log (or rig.yaml format)",
                              path.suffix)]
    cmap = rig.channel_map if rig is not None else None
    fcol = {c: (cmap.file_column(c) if cmap else c) for c in CANONICAL_COLUMNS}
    wanted = tuple(fcol[c] for c in CANONICAL_COLUMNS)
    if kind in ("tdms", "mat"):
        # NI TDMS (npTDMS) and MATLAB logs: the readers return the canonical channels by name (channel map
        # applied by name, no scaling); scaling and every signal check below are shared with CSV/Parquet.
        from .errors import ContractError
        from .formats import read_mat, read_tdms

        cols = dict(cmap.columns) if cmap else None
        grp = cmap.group if cmap else None
        # the reference channel the trial needs must be there (named by its own error, not as a column of NaN);
        # the other may be absent even where the channel map names it (docs/data_format.md)
        need = None if reference is None else {"displacement": ("laser",), "force": ("load_cell",)}.get(
            str(reference), ())
        try:
            if kind == "tdms":
                raw = read_tdms(path, cols, group=grp, need=need)
            else:
                dt = None if (cols and "t" in cols) or rig is None else 1.0 / rig.sample_rate_hz
                raw = read_mat(path, cols, group=grp, dt=dt, need=need)
        except ContractError as e:
            return None, list(e.problems)
        fcol = {c: c for c in CANONICAL_COLUMNS}
        num_probs: list[Problem] = []
    elif kind == "csv":
        header, probs, skip, units = _csv_header(name, path, size, wanted)
        if probs:
            return None, probs
        probs = _column_problems(name, header, wanted)
        if probs:
            return None, _separator_hint(name, header, wanted) or probs
        if max_rows is not None:
            probs = _too_long(name, _count_csv_rows(path) - skip - (1 if units else 0), max_rows)
            if probs:
                return None, probs
        if skip:
            _note(name, f"{skip} preamble line(s) before the header line skipped (oscilloscope export)")
        if units:
            _note(name, "units row after the header line skipped")
        # ragged rows are errors, not data; extra columns are read (and dropped below)
        opts = dict(engine="c", encoding="utf-8-sig", skipinitialspace=True, index_col=False,
                    skiprows=list(range(skip)) + ([skip + 1] if units else []) or None,
                    usecols=list(wanted) if set(header) - set(wanted) else None)
        num_probs: list[Problem] = []
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", pd.errors.ParserWarning)
                try:
                    raw = pd.read_csv(path, dtype="float64", **opts)
                except (pd.errors.ParserError, pd.errors.ParserWarning):
                    raise
                except (ValueError, TypeError):  # a non-numeric cell somewhere: find it
                    raw = pd.read_csv(path, dtype=object, keep_default_na=False, **opts)
                    raw, num_probs = _bad_cells(name, raw, list(wanted))
        except (pd.errors.ParserError, pd.errors.ParserWarning) as e:
            bad = _first_ragged_row(path, len(header), skip + 1 + int(units))
            if bad is not None:
                return None, [Problem(name, None, bad[0], f"a well-formed CSV row of {len(header)} cells",
                                      f"{bad[1]} cells")]
            return None, [Problem(name, None, None, "a well-formed CSV", _one_line(e))]
        except Exception as e:  # noqa: BLE001 - UnicodeDecodeError, ...
            return None, [Problem(name, None, None, "a well-formed CSV", _one_line(e))]
    else:
        pf, names, probs = _parquet_header(name, path, size)
        if probs:
            return None, probs
        probs = _column_problems(name, names, wanted)
        if probs:
            return None, probs
        probs = _too_long(name, pf.metadata.num_rows, max_rows)
        if probs:
            return None, probs
        if pf.metadata.num_rows == 0:
            return None, [Problem(name, None, None, "at least 2 samples", "no data rows (empty log)")]
        try:
            table = pf.read(columns=list(wanted))
            raw = table.to_pandas()
            del table  # memory: the log is held once (sample budget)
        except Exception as e:  # noqa: BLE001
            return None, [Problem(name, None, None, "readable Parquet data (truncated or corrupt file?)",
                                  _one_line(e))]
        num_probs = []
        for c in wanted:
            s = raw[c]
            if not (pd.api.types.is_numeric_dtype(s) or pd.api.types.is_bool_dtype(s)
                    or pd.api.types.is_string_dtype(s) or s.dtype == object):
                num_probs.append(Problem(name, c, None, "a numeric column", str(s.dtype)))
        if num_probs:
            return None, num_probs
        raw, num_probs = _bad_cells(name, raw, list(wanted))
    df = pd.DataFrame({c: raw[fcol[c]].to_numpy(dtype=np.float64, copy=True) for c in CANONICAL_COLUMNS})
    del raw  # memory: the log is held once (sample budget)
    if cmap is not None:
        for c, s in cmap.scale.items():
            df[c] = df[c] * s
    if num_probs:
        return None, num_probs
    return df, check_signals(df, rig, reference, name)


def _column_problems(name: str, found: list[str], wanted: tuple[str, ...]) -> list[Problem]:
    """Missing / misspelt / duplicated channel columns. Extra columns (other DAQ channels) are ignored with a
    note when every wanted column is present; if one is missing they are listed, as they may be its misspelling."""
    if found and not ({w.lower() for w in wanted} & {str(c).strip().lower() for c in found}):
        # none of the canonical names: the DAQ's own channel names, which rig.yaml's channel_map maps (one problem
        # instead of one per column)
        shown = ", ".join(repr(c) for c in found[:12]) + (" ..." if len(found) > 12 else "")
        return [Problem(name, None, None, f"the columns {', '.join(wanted)}, or a channel_map in rig.yaml naming "
                        "this file's own columns (docs/data_format.md)", f"the columns {shown}")]
    probs = column_problems(name, found, wanted)
    if all(w in found for w in wanted):
        extra = [c for c in dict.fromkeys(found) if c not in wanted]
        if extra:
            _note(name, f"extra column(s) {', '.join(map(repr, extra))} ignored")
        probs = [p for p in probs if p.field in wanted]  # keep duplicated wanted columns
    return probs


def _separator_hint(name: str, header: list[str], wanted: tuple[str, ...]) -> list[Problem] | None:
    """One clear problem instead of one per column when the file is a semicolon/tab-separated CSV
    (European spreadsheet exports, often with decimal commas)."""
    line = ",".join(header)
    for sep, label in ((";", "semicolon"), ("\t", "tab")):
        cols = [c.strip() for c in line.split(sep)]
        if len(cols) > 1 and set(wanted) <= set(cols):
            return [Problem(name, None, None, "a comma-separated CSV with decimal points (the header must read "
                            + ",".join(wanted) + ")", f"a {label}-separated file; export it again with ',' as the "
                            "separator and '.' as the decimal mark")]
    return None


def _first_ragged_row(path: Path, ncols: int, header_lines: int = 1) -> tuple[int, int] | None:
    """(1-based data row, number of cells) of the first CSV row whose cell count differs from the header."""
    with open(path, newline="", encoding="utf-8-sig", errors="replace") as fh:
        rd = csv.reader(fh)
        for _ in range(header_lines):
            next(rd, None)
        for i, r in enumerate(rd, start=1):
            if r and len(r) != ncols:
                return i, len(r)
    return None


def _one_line(e: BaseException) -> str:
    s = str(e).strip().splitlines()
    return f"{type(e).__name__}: {s[0] if s else ''}"


def read_log(path: str | Path, rig: Rig | None = None, reference: str | None = None) -> pd.DataFrame:
    """Read one trial log (CSV or Parquet) into the canonical channels, checked.

    Parameters
    ----------
    path : the log file (``.csv`` / ``.parquet``, or as forced by ``rig.format``).
    rig : optional :class:`~selfsense.io.rig.Rig`; enables the sample-rate check against
        ``sample_rate_hz``, the ADC range, and the ``channel_map`` column/unit mapping.
    reference : ``'displacement'`` / ``'force'`` / ``None``: which reference channel must be NaN-free.

    Returns a DataFrame with float64 columns ``t, u_cmd, v_shunt, laser, load_cell, relay`` (raw DAQ volts,
    time in s). Raises :class:`ContractError` listing every problem found.
    """
    df, probs = check_log(path, rig, reference)
    if probs or df is None:
        raise ContractError(probs, str(path))
    return df
