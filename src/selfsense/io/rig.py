"""``rig.yaml``: how the signals of a dataset were acquired and scaled.

Schema (docs/data_format.md, every number SI; unknown keys are errors so that typos never pass silently)::

    dataset: tweezer_sim               # must equal the folder name
    sample_rate_hz: 1000.0             # nominal DAQ rate [Hz]
    shunt_resistance_ohm: 1000.0       # R of thesis eq. (57) [ohm]
    amplifier_gain: 15.0               # V_c = amplifier_gain * u_cmd (thesis eq. 56) [V/V]
    inamp_gain: 10.0                   # column v_shunt = inamp_gain * V_s [V/V]
    n_actuators: 5                     # actuators electrically in parallel
    reference: {laser_m_per_v: 2.0e-3, load_cell_n_per_v: 0.1}
    actuator_catalog: {free_displacement_m: 10.0e-6, blocked_force_n: 240.0,
                       stiffness_n_per_m: 24.0e6, capacitance_f: 0.25e-6, max_voltage_v: 150.0}
    tip_free_displacement_m: 6.3e-3

Optional keys (for DAQ logs that are not in the canonical layout, see docs/data_format.md)::

    format: auto | csv | parquet       # how to read the trial logs (auto: by file extension)
    adc_range_v: 10.0                  # +-full scale of the DAQ inputs, used for the saturation check
    amplifier_current_limit_a: 0.005   # HV amplifier's current limit (data sheet) [A]: its plateau is no clipping
    channel_map:
      columns: {t: Time_ms, v_shunt: AI1}   # canonical name -> the file's column name
      scale:   {t: 1.0e-3}                  # canonical = scale * file column (e.g. ms -> s, mV -> V)
    plausibility: {charge_ratio_max: 8.0}   # physical plausibility limits (selfsense.io.plausibility.DEFAULTS)

YAML aliases (``*name``) are refused (:mod:`selfsense.io.yamlsafe`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import ContractError, Problem
from .yamlsafe import NoAliasLoader

__all__ = ["Rig", "Reference", "ActuatorCatalog", "ChannelMap", "load_rig", "parse_rig", "rig_value",
           "CANONICAL_COLUMNS", "RIG_FILE"]

RIG_FILE = "rig.yaml"
#: raw DAQ channels of a trial log, in canonical order (docs/data_format.md)
CANONICAL_COLUMNS: tuple[str, ...] = ("t", "u_cmd", "v_shunt", "laser", "load_cell", "relay")
FORMATS = ("auto", "csv", "parquet", "tdms", "mat")


def rig_value(rig: Any, *path: str) -> float:
    """One number of a rig, from a :class:`Rig` or a plain rig.yaml mapping: ``rig_value(rig, "actuator_catalog",
    "capacitance_f")`` reads ``rig.actuator_catalog.capacitance_f`` or ``rig["actuator_catalog"]["capacitance_f"]``."""
    obj = rig
    for p in path:
        obj = obj[p] if isinstance(obj, Mapping) else getattr(obj, p)
    return float(obj)


@dataclass(frozen=True)
class Reference:
    laser_m_per_v: float      #: column laser [V] -> displacement of ONE arm [m]; sign = mounting direction
    load_cell_n_per_v: float  #: column load_cell [V] -> tip force [N]


@dataclass(frozen=True)
class ActuatorCatalog:
    """Data-sheet values of ONE actuator."""
    free_displacement_m: float
    blocked_force_n: float
    stiffness_n_per_m: float
    capacitance_f: float
    max_voltage_v: float


@dataclass(frozen=True)
class ChannelMap:
    """Map from canonical channel names to a foreign log's columns, and scale factors.

    ``canonical = scale[name] * file[columns.get(name, name)]``.
    """
    columns: dict[str, str] = field(default_factory=dict)
    scale: dict[str, float] = field(default_factory=dict)
    group: str | None = None  #: TDMS group, or MATLAB struct path such as ``data.daq`` (other formats: unused)

    def file_column(self, name: str) -> str:
        return self.columns.get(name, name)


@dataclass(frozen=True)
class Rig:
    dataset: str
    sample_rate_hz: float
    shunt_resistance_ohm: float
    amplifier_gain: float
    inamp_gain: float
    n_actuators: int
    reference: Reference
    actuator_catalog: ActuatorCatalog
    tip_free_displacement_m: float
    format: str = "auto"
    adc_range_v: float = 10.0
    channel_map: ChannelMap | None = None
    #: plausible range of the logged drive channel ``u_cmd`` [V] (rig.yaml ``drive``); the defaults describe a
    #: unipolar 0-10 V amplifier input (selfsense.io.logs.LIMITS)
    u_cmd_min_v: float = -1.0
    u_cmd_max_v: float = 10.5
    #: plausibility limits overriding :data:`selfsense.io.plausibility.DEFAULTS` (rig.yaml ``plausibility:``)
    plausibility: tuple[tuple[str, float], ...] = ()
    #: the HV amplifier's output current limit [A] from its data sheet (rig.yaml ``amplifier_current_limit_a``), or
    #: None: a plateau of the shunt current at this limit is the amplifier's, not a clipped channel
    amplifier_current_limit_a: float | None = None

    @property
    def plausibility_limits(self) -> dict[str, float]:
        """All plausibility limits: the defaults updated with rig.yaml ``plausibility:``."""
        from .plausibility import DEFAULTS

        return {**DEFAULTS, **dict(self.plausibility)}

    @property
    def dt(self) -> float:
        """Nominal sample period [s]."""
        return 1.0 / self.sample_rate_hz

    def at_current_limit(self, ext: float, zero: float, is_max: bool) -> bool:
        """Whether the extreme ``ext`` of ``v_shunt`` (its maximum where ``is_max``) is the HV amplifier's current limit
        declared in ``amplifier_current_limit_a``: within :data:`CURRENT_LIMIT_TOL` of ``zero + inamp_gain *
        shunt_resistance_ohm * limit`` (``zero - ...`` for the minimum), ``zero`` being the channel's level at zero
        current (its relay segment). An amplifier at its limit delivers a constant current, which an undithered ADC
        reads as one code: a plateau there is not a clipped channel."""
        if not self.amplifier_current_limit_a:
            return False
        level = self.inamp_gain * self.shunt_resistance_ohm * float(self.amplifier_current_limit_a)
        target = zero + level if is_max else zero - level
        return abs(ext - target) <= CURRENT_LIMIT_TOL * level


#: a v_shunt plateau within this share of the declared current limit's level is the amplifier's
#: (:meth:`Rig.at_current_limit`; data-sheet limits are nominal)
CURRENT_LIMIT_TOL = 0.15


def shunt_zero(v_shunt: np.ndarray, relay: np.ndarray) -> float:
    """The ``v_shunt`` level at zero current: its mean over the relay segment at the start of the log (0 without
    one)."""
    rel = np.asarray(relay, float) >= 0.5
    n = int(np.argmin(rel)) if not rel.all() else rel.size
    x = np.asarray(v_shunt, float)[:n]
    x = x[np.isfinite(x)]
    return float(np.mean(x)) if x.size else 0.0


# --- schema: key -> (type, lo, hi, positive) ------------------------------------------------------
# lo/hi are plausibility bounds on the value (or on |value| when positive is False and the sign is free)
_NUM = "number"
_INT = "integer"
_STR = "string"
_REQUIRED: dict[str, Any] = {
    "dataset": (_STR,),
    "sample_rate_hz": (_NUM, 1.0, 1e6, True),
    "shunt_resistance_ohm": (_NUM, 1.0, 1e7, True),
    "amplifier_gain": (_NUM, 0.1, 1e4, True),
    "inamp_gain": (_NUM, 0.1, 1e4, True),
    "n_actuators": (_INT, 1, 1000, True),
    "reference": {
        "laser_m_per_v": (_NUM, 1e-9, 1.0, False),
        "load_cell_n_per_v": (_NUM, 1e-6, 1e4, False),
    },
    "actuator_catalog": {
        "free_displacement_m": (_NUM, 1e-9, 1e-2, True),
        "blocked_force_n": (_NUM, 1e-3, 1e5, True),
        "stiffness_n_per_m": (_NUM, 1e3, 1e10, True),
        "capacitance_f": (_NUM, 1e-9, 1e-3, True),
        "max_voltage_v": (_NUM, 1.0, 1e4, True),
    },
    "tip_free_displacement_m": (_NUM, 1e-7, 0.1, True),
}
_OPTIONAL = {"format", "adc_range_v", "amplifier_current_limit_a", "channel_map", "drive", "plausibility"}


_Loader = NoAliasLoader  # aliases refused (a YAML alias bomb under a known key cannot expand)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_value(key: str, v: Any, spec: tuple, probs: list[Problem]) -> Any:
    kind = spec[0]
    if kind == _STR:
        if not isinstance(v, str) or not v:
            probs.append(Problem(RIG_FILE, key, None, "a non-empty string", v))
            return None
        return v
    if kind == _INT:
        if not (isinstance(v, int) and not isinstance(v, bool)):
            if _is_number(v) and float(v).is_integer():
                v = int(v)
            else:
                probs.append(Problem(RIG_FILE, key, None, "an integer", v))
                return None
    elif not _is_number(v):
        probs.append(Problem(RIG_FILE, key, None, "a number", v))
        return None
    lo, hi, positive = spec[1], spec[2], spec[3]
    x = float(v)
    if not math.isfinite(x):
        probs.append(Problem(RIG_FILE, key, None, "a finite number", v))
        return None
    if positive and x <= 0:
        probs.append(Problem(RIG_FILE, key, None, "a value > 0" if kind == _NUM else f"an integer >= {lo}", v))
        return None
    if not positive and x == 0:
        probs.append(Problem(RIG_FILE, key, None, "a non-zero value", v))
        return None
    if not (lo <= abs(x) <= hi):
        probs.append(Problem(RIG_FILE, key, None,
                             f"a plausible value, {'|value|' if not positive else 'value'} in [{lo:g}, {hi:g}]", v))
        return None
    return int(v) if kind == _INT else x


def _check_mapping(prefix: str, d: Any, schema: dict, optional: set[str], probs: list[Problem]) -> dict:
    out: dict[str, Any] = {}
    if not isinstance(d, dict):
        probs.append(Problem(RIG_FILE, prefix or None, None, "a mapping of keys", type(d).__name__))
        return out
    for k in d:
        if k not in schema and k not in optional:
            import difflib
            close = difflib.get_close_matches(str(k), list(schema) + sorted(optional), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            probs.append(Problem(RIG_FILE, f"{prefix}{k}", None, "no unknown keys" + hint, "unknown key"))
    for k, spec in schema.items():
        key = f"{prefix}{k}"
        if k not in d:
            probs.append(Problem(RIG_FILE, key, None, "this required key", "missing"))
            continue
        if isinstance(spec, dict):
            out[k] = _check_mapping(key + ".", d[k], spec, set(), probs)
        else:
            out[k] = _check_value(key, d[k], spec, probs)
    return out


def _check_channel_map(d: Any, probs: list[Problem]) -> ChannelMap | None:
    if not isinstance(d, dict):
        probs.append(Problem(RIG_FILE, "channel_map", None, "a mapping with 'columns', 'scale' and/or 'group'", d))
        return None
    for k in d:
        if k not in ("columns", "scale", "group"):
            probs.append(Problem(RIG_FILE, f"channel_map.{k}", None, "only 'columns', 'scale' and 'group'",
                                 "unknown key"))
    group = d.get("group")
    if group is not None and (not isinstance(group, str) or not group):
        probs.append(Problem(RIG_FILE, "channel_map.group", None, "a TDMS group or MATLAB struct path (string)", group))
        group = None
    cols: dict[str, str] = {}
    scale: dict[str, float] = {}
    for sub in ("columns", "scale"):
        m = d.get(sub, {}) or {}
        if not isinstance(m, dict):
            probs.append(Problem(RIG_FILE, f"channel_map.{sub}", None, "a mapping canonical name -> value", m))
            continue
        for name, val in m.items():
            key = f"channel_map.{sub}.{name}"
            if name not in CANONICAL_COLUMNS:
                probs.append(Problem(RIG_FILE, key, None,
                                     "a canonical channel name (" + ", ".join(CANONICAL_COLUMNS) + ")",
                                     "unknown key"))
                continue
            if sub == "columns":
                if not isinstance(val, str) or not val:
                    probs.append(Problem(RIG_FILE, key, None, "a column name (string)", val))
                else:
                    cols[name] = val
            else:
                if not _is_number(val) or not math.isfinite(float(val)) or float(val) == 0:
                    probs.append(Problem(RIG_FILE, key, None, "a finite non-zero scale factor", val))
                elif name == "relay" and float(val) != 1.0:
                    probs.append(Problem(RIG_FILE, key, None, "no scale on the 0/1 relay column", val))
                elif name == "t" and float(val) < 0:
                    probs.append(Problem(RIG_FILE, key, None, "a positive time scale", val))
                else:
                    scale[name] = float(val)
    if len(set(cols.values())) != len(cols):
        probs.append(Problem(RIG_FILE, "channel_map.columns", None, "distinct file columns", cols))
    return ChannelMap(cols, scale, group)


def parse_rig(data: Any, dataset_name: str | None = None) -> tuple[Rig | None, list[Problem]]:
    """Check a parsed ``rig.yaml`` mapping; return ``(Rig or None, problems)``. Never raises on bad data."""
    probs: list[Problem] = []
    if not isinstance(data, dict):
        probs.append(Problem(RIG_FILE, None, None, "a YAML mapping of keys", type(data).__name__))
        return None, probs
    vals = _check_mapping("", data, _REQUIRED, _OPTIONAL, probs)
    fmt = data.get("format", "auto")
    if fmt not in FORMATS:
        probs.append(Problem(RIG_FILE, "format", None, "'auto', 'csv', 'parquet', 'tdms' or 'mat'", fmt))
    adc = data.get("adc_range_v", 10.0)
    adc = _check_value("adc_range_v", adc, (_NUM, 0.1, 1000.0, True), probs)
    i_lim = None
    if "amplifier_current_limit_a" in data:   # written, it must be a number (an empty value is refused, not ignored)
        i_lim = _check_value("amplifier_current_limit_a", data["amplifier_current_limit_a"],
                             (_NUM, 1e-6, 100.0, True), probs)
    cmap = _check_channel_map(data["channel_map"], probs) if "channel_map" in data else None
    u_lo, u_hi = _check_drive(data.get("drive"), probs)
    from .plausibility import DEFAULTS as _PD, check_plausibility_keys

    plaus, pprobs = check_plausibility_keys(data.get("plausibility"), RIG_FILE)
    probs += pprobs
    if dataset_name is not None and isinstance(vals.get("dataset"), str) and vals["dataset"] != dataset_name:
        probs.append(Problem(RIG_FILE, "dataset", None, f"the folder name {dataset_name!r}", vals["dataset"]))
    if probs:
        return None, probs
    rig = Rig(
        dataset=vals["dataset"],
        sample_rate_hz=vals["sample_rate_hz"],
        shunt_resistance_ohm=vals["shunt_resistance_ohm"],
        amplifier_gain=vals["amplifier_gain"],
        inamp_gain=vals["inamp_gain"],
        n_actuators=vals["n_actuators"],
        reference=Reference(**vals["reference"]),
        actuator_catalog=ActuatorCatalog(**vals["actuator_catalog"]),
        tip_free_displacement_m=vals["tip_free_displacement_m"],
        format=fmt,
        adc_range_v=adc,
        channel_map=cmap,
        u_cmd_min_v=u_lo,
        u_cmd_max_v=u_hi,
        plausibility=tuple(sorted((k, v) for k, v in plaus.items() if v != _PD[k])),
        amplifier_current_limit_a=None if i_lim is None else float(i_lim),
    )
    return rig, probs


def _check_drive(d: Any, probs: list[Problem]) -> tuple[float, float]:
    """rig.yaml ``drive: {u_cmd_min_v, u_cmd_max_v}``: the plausible range of the logged ``u_cmd`` [V].

    A bipolar drive (``u_cmd_min_v: -10``) or a rig that logs the amplifier *output* in ``u_cmd`` (then
    ``amplifier_gain: 1`` and e.g. ``u_cmd_max_v: 160``) is described here instead of failing the default
    0-10 V check."""
    lo, hi = -1.0, 10.5
    if d is None:
        return lo, hi
    if not isinstance(d, dict):
        probs.append(Problem(RIG_FILE, "drive", None, "a mapping with 'u_cmd_min_v' and/or 'u_cmd_max_v'", d))
        return lo, hi
    for k in d:
        if k not in ("u_cmd_min_v", "u_cmd_max_v"):
            probs.append(Problem(RIG_FILE, f"drive.{k}", None, "only 'u_cmd_min_v' and 'u_cmd_max_v'", "unknown key"))
    vals = {}
    for k, default in (("u_cmd_min_v", lo), ("u_cmd_max_v", hi)):
        v = d.get(k, default)
        if not _is_number(v) or not math.isfinite(float(v)) or abs(float(v)) > 1e4:
            probs.append(Problem(RIG_FILE, f"drive.{k}", None, "a finite number of volts, |x| <= 10 kV", v))
            v = default
        vals[k] = float(v)
    if vals["u_cmd_min_v"] >= vals["u_cmd_max_v"]:
        probs.append(Problem(RIG_FILE, "drive", None, "u_cmd_min_v < u_cmd_max_v",
                             f"{vals['u_cmd_min_v']:g} >= {vals['u_cmd_max_v']:g}"))
    return vals["u_cmd_min_v"], vals["u_cmd_max_v"]


_MAX_RIG_BYTES = 1 << 20


def check_rig(dataset_dir: str | Path) -> tuple[Rig | None, list[Problem]]:
    """Read and check ``<dataset_dir>/rig.yaml``; return ``(Rig or None, problems)``."""
    d = Path(dataset_dir)
    p = d / RIG_FILE
    if not p.is_file():
        return None, [Problem(RIG_FILE, None, None, "a rig.yaml file in the dataset folder", "no such file")]
    if p.stat().st_size > _MAX_RIG_BYTES:
        return None, [Problem(RIG_FILE, None, None, f"a small YAML file (< {_MAX_RIG_BYTES} bytes)",
                              f"{p.stat().st_size} bytes")]
    try:
        text = p.read_text(encoding="utf-8")
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 (SafeLoader subclass)
    except UnicodeDecodeError as e:
        return None, [Problem(RIG_FILE, None, None, "UTF-8 text", f"undecodable byte at {e.start}")]
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "unknown position"
        prob = str(getattr(e, "problem", "") or "")
        if "aliases" in prob:
            return None, [Problem(RIG_FILE, None, None, "no YAML aliases (*name)", f"an alias at {where}")]
        if prob.startswith("duplicate key"):   # NoAliasLoader: a second value would silently replace the first
            key = prob.split("'")[1] if prob.count("'") >= 2 else None
            return None, [Problem(RIG_FILE, key, None, "each key once", prob.split(": each")[0])]
        return None, [Problem(RIG_FILE, None, None, "valid YAML", f"syntax error at {where}")]
    return parse_rig(data, d.resolve().name)


def load_rig(dataset_dir: str | Path) -> Rig:
    """Load ``<dataset_dir>/rig.yaml`` as a :class:`Rig`; raise :class:`ContractError` listing all problems."""
    rig, probs = check_rig(dataset_dir)
    if probs or rig is None:
        raise ContractError(probs, str(dataset_dir))
    return rig
