"""Other DAQ log formats: NI TDMS and MATLAB ``.mat`` readers, and ``.mat`` export of estimates.

The readers return the *raw* canonical channels of a trial log (docs/data_format.md,
"Trial log columns"): a float64 DataFrame with a RangeIndex and exactly the columns
``t`` [s], ``u_cmd`` [V], ``v_shunt`` [V], ``laser`` [V], ``load_cell`` [V], ``relay`` [0/1], in that order,
in the file's own units (no ``channel_map.scale`` is applied here; :func:`selfsense.io.read_log` does that,
and runs all the contract checks on the result).

The channel map is ``{canonical name: channel name in the file}``. A canonical name absent from the map is
looked up under its own name. ``laser`` and ``load_cell`` may be absent from both the map and the file
(they are then NaN, as in a trial whose reference is the other sensor); every other channel, and every
channel named explicitly in the map, must exist, else :class:`~selfsense.io.errors.ContractError` names the
file and the channel and lists the channels that do exist.

Time: from the channel mapped to ``t`` when there is one (numbers in the file's unit, or TDMS/NumPy
timestamps, which become seconds since the first sample); otherwise, for TDMS, from the waveform properties
``wf_start_offset + k * wf_increment`` of the ``u_cmd`` channel; for ``.mat``, from ``dt`` [s] given by the
caller or a scalar variable named by ``dt_var``.
"""
from __future__ import annotations

import io as _io
import os
import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from .atomic import atomic_write
from .errors import ContractError, Problem
from .rig import CANONICAL_COLUMNS

__all__ = ["read_tdms", "read_mat", "export_estimates_mat", "OPTIONAL_CHANNELS", "MAT_HEADER"]

#: channels that may be missing from a log (filled with NaN): the reference sensor not used in a trial
OPTIONAL_CHANNELS = ("laser", "load_cell")
#: fixed 116-byte text header of exported .mat files (scipy writes the wall-clock time there otherwise)
MAT_HEADER = b"MATLAB 5.0 MAT-file, written by selfsense.io.formats.export_estimates_mat"
_MATLAB_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,62}$")


def _check_map(name: str, channels: Mapping[str, str] | None) -> dict[str, str]:
    channels = dict(channels or {})
    bad = [k for k in channels if k not in CANONICAL_COLUMNS]
    if bad:
        raise ContractError([Problem(name, k, None, "a canonical channel name (" + ", ".join(CANONICAL_COLUMNS)
                                     + ") as channel-map key", "unknown key") for k in bad], name)
    return channels


def _missing(name: str, canon: str, wanted: str, available: list[str], where: str = "") -> Problem:
    avail = ", ".join(repr(a) for a in available[:20]) + (" ..." if len(available) > 20 else "")
    return Problem(name, wanted, None,
                   f"a channel {wanted!r}{where} for {canon!r} (available: {avail or 'none'})", "no such channel")


def _required(canon: str, cmap: Mapping[str, str], need: tuple[str, ...] | None) -> bool:
    """Whether a channel missing from the file is an error: the drive channels always, ``t`` where the map names
    it, a reference channel (``laser``, ``load_cell``) where the trial needs it (``need``: the trial's reference
    channels, from its ``reference`` in trials.csv) -- or, when the caller does not say (``need`` None), wherever
    the map names it."""
    if canon == "t":
        return canon in cmap
    if canon not in OPTIONAL_CHANNELS:
        return True
    return canon in need if need is not None else canon in cmap


def _as_float(name: str, canon: str, label: str, values: Any) -> tuple[np.ndarray | None, Problem | None]:
    a = np.asarray(values)
    if np.issubdtype(a.dtype, np.datetime64):
        if canon != "t":
            return None, Problem(name, label, None, "a numeric channel", "timestamps")
        ns = a.astype("datetime64[ns]").astype(np.int64)
        return (ns - ns[0]).astype(np.float64) * 1e-9, None
    if a.dtype == bool:
        a = a.astype(np.float64)
    if not (np.issubdtype(a.dtype, np.number)):
        return None, Problem(name, label, None, "a numeric channel", str(a.dtype))
    if a.ndim == 0 or sum(d > 1 for d in a.shape) > 1:
        # a 2-D matrix has no sample order that could be taken for granted (MATLAB stores columns first, NumPy
        # rows first): flattening it would silently scramble the samples
        return None, Problem(name, label, None, "a vector of samples (N, or a row or column matrix 1 x N / N x 1)",
                             "a single number" if a.ndim == 0 else "a matrix of shape " + " x ".join(map(str, a.shape)))
    a = np.ravel(a)
    return a.astype(np.float64, copy=True), None


def _assemble(name: str, cols: dict[str, np.ndarray], labels: dict[str, str]) -> pd.DataFrame:
    lengths = {c: len(v) for c, v in cols.items()}
    n = lengths.get("u_cmd", next(iter(lengths.values())))
    probs = [Problem(name, labels[c], None, f"{n} samples like the {labels['u_cmd']!r} channel", k)
             for c, k in lengths.items() if k != n]
    if probs:
        raise ContractError(probs, name)
    out = {}
    for c in CANONICAL_COLUMNS:
        out[c] = cols[c] if c in cols else np.full(n, np.nan)
    return pd.DataFrame(out)


# --------------------------------------------------------------------------------------------- TDMS
def read_tdms(path: str | os.PathLike, channels: Mapping[str, str] | None = None, group: str | None = None,
              need: tuple[str, ...] | None = None) -> pd.DataFrame:
    """Read an NI TDMS log (npTDMS) into the raw canonical channels.

    Parameters
    ----------
    path : the ``.tdms`` file.
    channels : ``{canonical: TDMS channel name}``, e.g. ``{"u_cmd": "AI0", "v_shunt": "AI1", "relay": "DO0"}``.
    group : the TDMS group holding the channels. ``None``: the only group of the file, or (several groups)
        the group where each channel name is found, which must be unambiguous.
    need : the reference channels this trial needs (``("laser",)`` for a displacement reference); the others may be
        absent even where the channel map names them (NaN). ``None``: every channel the map names must exist.

    Time ``t`` [s]: the channel mapped to ``t`` (numbers, or timestamps -> seconds since the first sample),
    else ``wf_start_offset + k * wf_increment`` of the ``u_cmd`` channel (NI waveform properties).

    Returns a float64 DataFrame with columns ``t, u_cmd, v_shunt, laser, load_cell, relay`` (RangeIndex).
    Raises :class:`ContractError` naming the file and the channel when a channel, the group or the time base
    is missing, a channel is not numeric, or the channels differ in length.
    """
    from nptdms import TdmsFile

    path = Path(path)
    name = path.name
    cmap = _check_map(name, channels)
    if not path.is_file():
        raise ContractError(Problem(name, None, None, "an existing TDMS file", "no such file"), str(path))
    try:
        fh = TdmsFile.open(path)
    except Exception as e:  # noqa: BLE001 - npTDMS raises ValueError/struct.error/... on bad files
        raise ContractError(Problem(name, None, None, "a readable TDMS file", f"{type(e).__name__}: {e}"),
                            str(path)) from e
    with fh:
        groups = {g.name: g for g in fh.groups()}
        if group is not None and group not in groups:
            raise ContractError(Problem(name, "group", None, f"a TDMS group {group!r} (groups: "
                                        + ", ".join(repr(g) for g in groups) + ")", "no such group"), str(path))
        search = [groups[group]] if group is not None else list(groups.values())
        if not any(True for g in search for _ in g.channels()):
            found = (f"no channel in group(s) {', '.join(repr(g.name) for g in search)}" if search else
                     "no group and no channel (not a TDMS file, or a corrupt one)")
            raise ContractError(Problem(name, None, None, "a TDMS file with channels", found), str(path))
        cols: dict[str, np.ndarray] = {}
        labels: dict[str, str] = {}
        probs: list[Problem] = []
        objs = {}
        for canon in CANONICAL_COLUMNS:
            wanted = cmap.get(canon, canon)
            hits = [g for g in search if wanted in [c.name for c in g.channels()]]
            if not hits:
                if _required(canon, cmap, need):
                    avail = [c.name if len(search) == 1 else f"{g.name}/{c.name}"
                             for g in search for c in g.channels()]
                    where = f" in group {search[0].name!r}" if len(search) == 1 else ""
                    probs.append(_missing(name, canon, wanted, avail, where))
                continue
            if len(hits) > 1:
                probs.append(Problem(name, wanted, None, "a channel name found in one group only (pass group=)",
                                     "in groups " + ", ".join(repr(g.name) for g in hits)))
                continue
            objs[canon] = hits[0][wanted]
            labels[canon] = wanted
        if probs:
            raise ContractError(probs, str(path))
        for canon, ch in objs.items():
            a, p = _as_float(name, canon, labels[canon], ch[:])
            if p is not None:
                probs.append(p)
            else:
                cols[canon] = a
        if "t" not in cols and not probs:
            ref = objs["u_cmd"]
            props = ref.properties
            if "wf_increment" not in props:
                probs.append(Problem(name, labels["u_cmd"], None,
                                     "a time channel in the channel map ('t') or the waveform property "
                                     "'wf_increment' on this channel", "neither"))
            else:
                dt = float(props["wf_increment"])
                t0 = props.get("wf_start_offset", 0.0)
                t0 = float(t0) if np.isscalar(t0) and not isinstance(t0, (np.datetime64, str)) else 0.0
                if not (np.isfinite(dt) and dt > 0):
                    probs.append(Problem(name, f"{labels['u_cmd']}.wf_increment", None, "a positive time step", dt))
                else:
                    cols["t"] = t0 + np.arange(len(cols["u_cmd"]), dtype=np.float64) * dt
                    labels["t"] = f"{labels['u_cmd']}.wf_increment"
        if probs:
            raise ContractError(probs, str(path))
    return _assemble(name, cols, labels)


# --------------------------------------------------------------------------------------------- MATLAB
def _load_mat(path: Path) -> tuple[dict[str, Any], str]:
    """Top-level variables of a .mat file as nested dicts / arrays, and the format ('v5' or 'v7.3')."""
    import scipy.io

    name = path.name
    try:
        data = scipy.io.loadmat(path, simplify_cells=True)
        return {k: v for k, v in data.items() if not k.startswith("__")}, "v5"
    except NotImplementedError:  # "Please use HDF reader for matlab v7.3 files"
        pass
    except Exception as e:  # noqa: BLE001 - scipy raises ValueError/TypeError/MatReadError on bad files
        raise ContractError(Problem(name, None, None, "a readable MATLAB .mat file", f"{type(e).__name__}: {e}"),
                            str(path)) from e
    try:
        import h5py
    except ImportError as e:
        raise ContractError(Problem(name, None, None, "a MATLAB v5/v7 .mat file (v7.3/HDF5 files need the "
                                    "optional package h5py: pip install h5py), or re-save it in MATLAB with "
                                    "save(..., '-v7')", "a v7.3 (HDF5) file"), str(path)) from e

    def walk(node):
        if isinstance(node, h5py.Dataset):
            return np.asarray(node[()])
        return {k: walk(node[k]) for k in node.keys() if not k.startswith("#")}

    with h5py.File(path, "r") as f:
        return walk(f), "v7.3"


def read_mat(path: str | os.PathLike, channels: Mapping[str, str] | None = None, group: str | None = None,
             dt: float | None = None, dt_var: str | None = None, need: tuple[str, ...] | None = None
             ) -> pd.DataFrame:
    """Read a MATLAB ``.mat`` log (scipy.io.loadmat; v7.3/HDF5 through h5py when installed).

    Parameters
    ----------
    path : the ``.mat`` file.
    channels : ``{canonical: variable name}``; each variable a numeric vector (row or column).
    group : optional name of a struct variable whose fields hold the channels (dots for nested structs,
        e.g. ``"data.daq"``); ``None``: top-level variables.
    dt : sample period [s] when no channel is mapped to ``t``; ``t = k * dt``.
    dt_var : name of a scalar variable (in ``group``) holding the sample period [s], instead of ``dt``.
    need : as for :func:`read_tdms`.

    Returns a float64 DataFrame with columns ``t, u_cmd, v_shunt, laser, load_cell, relay`` (RangeIndex).
    Raises :class:`ContractError` naming the file and the variable when a channel, the struct or the time base
    is missing, a variable is not numeric, or the vectors differ in length. MATLAB v7.3 files without h5py
    installed give a ContractError saying so.
    """
    path = Path(path)
    name = path.name
    cmap = _check_map(name, channels)
    if not path.is_file():
        raise ContractError(Problem(name, None, None, "an existing .mat file", "no such file"), str(path))
    data, _ = _load_mat(path)
    scope: Any = data
    if group:
        for part in group.split("."):
            if not isinstance(scope, dict) or part not in scope:
                keys = sorted(scope) if isinstance(scope, dict) else []
                raise ContractError(Problem(name, group, None, f"a struct variable {group!r} (variables: "
                                            + ", ".join(repr(k) for k in keys) + ")", "no such struct"), str(path))
            scope = scope[part]
        if not isinstance(scope, dict):
            raise ContractError(Problem(name, group, None, "a struct variable", type(scope).__name__), str(path))
    avail = sorted(scope)
    where = f" in struct {group!r}" if group else ""
    cols: dict[str, np.ndarray] = {}
    labels: dict[str, str] = {}
    probs: list[Problem] = []
    for canon in CANONICAL_COLUMNS:
        wanted = cmap.get(canon, canon)
        if wanted not in scope:
            if _required(canon, cmap, need):
                probs.append(_missing(name, canon, wanted, avail, where))
            continue
        a, p = _as_float(name, canon, wanted, scope[wanted])
        if p is not None:
            probs.append(p)
        else:
            cols[canon] = a
            labels[canon] = wanted
    if "t" not in cols and not probs:
        step = dt
        if dt_var is not None:
            if dt_var not in scope:
                probs.append(_missing(name, "t", dt_var, avail, where))
            else:
                v = np.ravel(np.asarray(scope[dt_var], dtype=float))
                step = float(v[0]) if v.size == 1 else None
                if step is None:
                    probs.append(Problem(name, dt_var, None, "a scalar sample period [s]", f"{v.size} values"))
        if step is None and not probs:
            probs.append(Problem(name, "t", None, "a time channel in the channel map ('t'), or dt / dt_var",
                                 "neither"))
        elif step is not None and not (np.isfinite(step) and step > 0):
            probs.append(Problem(name, dt_var or "dt", None, "a positive sample period [s]", step))
        elif step is not None:
            cols["t"] = np.arange(len(cols["u_cmd"]), dtype=np.float64) * step
            labels["t"] = dt_var or "dt"
    if probs:
        raise ContractError(probs, str(path))
    return _assemble(name, cols, labels)


def export_estimates_mat(df: pd.DataFrame, path: str | os.PathLike, name: str = "estimates",
                         meta: Mapping[str, Any] | None = None) -> Path:
    """Write an estimates table (e.g. ``t, dx_hat, f_hat, dx_ref, f_ref``) to a MATLAB ``.mat`` file, atomically.

    The file holds one struct ``name`` whose fields are the columns as double column vectors (SI units as in
    the table: s, m, N), and, when given, a struct ``meta`` (strings and numbers). In MATLAB:
    ``s = load('x.mat'); plot(s.estimates.t, s.estimates.dx_hat)``. MAT v5 format, zlib-compressed, with a
    fixed header text (no creation date), so the same frame gives the same bytes.
    Raises ``ValueError`` for column names that are not MATLAB identifiers or non-numeric columns.
    """
    import scipy.io

    for key in (name, *df.columns, *(meta or {})):
        if not isinstance(key, str) or not _MATLAB_NAME.match(key):
            raise ValueError(f"export_estimates_mat: {key!r} is not a valid MATLAB identifier")
    fields = {}
    for c in df.columns:
        if not (pd.api.types.is_numeric_dtype(df[c]) or pd.api.types.is_bool_dtype(df[c])):
            raise ValueError(f"export_estimates_mat: column {c!r} is not numeric ({df[c].dtype})")
        fields[c] = df[c].to_numpy(dtype=np.float64).reshape(-1, 1)
    payload: dict[str, Any] = {name: fields}
    if meta:
        payload["meta"] = dict(meta)
    buf = _io.BytesIO()
    scipy.io.savemat(buf, payload, format="5", do_compression=True, oned_as="column")
    raw = bytearray(buf.getvalue())
    raw[:116] = MAT_HEADER.ljust(116, b" ")  # v5 header: 116 bytes of text, then subsystem offset/version
    with atomic_write(path, "wb") as fh:
        fh.write(bytes(raw))
    return Path(path)
