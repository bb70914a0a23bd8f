"""The self-sensing estimator: H(q) calibration, sensing-coefficient regression, estimation.

The method of ``000_18d138f03f1777c3.txt`` (thesis) sec. 4.3 with the on-site calibration of
``001_972cacfaa08ad91a.txt`` (paper) eqs. (16)-(23):

* Goldfarb-Celanovic actuator, thesis eqs. (24)-(27): ``V_p = V - H(q)``.
* Tip response, thesis eq. (52) (approximation of eq. (46))::

      dx_tip = A1 * (n_A q) + A2 * V_p
      f_tip  = (A3 / n_A) * (n_A q) - C_p * A3 * V_p

  Here ``n_A q`` is the total charge ``Q`` seen by the shunt (thesis: "the charge will be n_A times that of a single
  actuator") and ``C_p`` is the clamped capacitance of ONE actuator, so ``f_tip = (A3 / n_A) (Q - n_A C_p V_p)``.
* Free-tip calibration of H, thesis eq. (55): ``H(q) = V - Q / (n_A C_p)`` (the convention that folds the piezo
  displacement term into H), or the paper's on-site calibration eq. (23):
  ``H(q) = V - (1 - alpha B A_q) q / C_p`` with per-actuator charge ``q = Q / n_A``, ``alpha`` from the catalog
  (blocked force / max voltage), ``B = dx_pzt_free / dx_tip_free`` (paper eq. 20) and ``A_q`` the free-tip
  displacement per unit per-actuator charge [m/C].
* Regression of A1, A2 (and A3) on *calibration trials only*, jointly over loading conditions:
  dx on displacement-reference trials plus dx = 0 on blocked-tip trials; f on
  force-reference trials plus f = 0 on free-tip trials. ``regression="full"`` fits the four free terms of the
  unapproximated eq. (46) instead (A1, A2, B21, B22).
* Post-processing of thesis sec. 5.2 / Fig. 24: limiting to the physical range, and a sliding DC offset on the
  displacement that resets whenever the input voltage is zero.

Units: SI throughout (C, V, m, N, s).
"""
from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Mapping, NamedTuple

import numpy as np
import pandas as pd

from selfsense.hysteresis.models import LinearParamH, ridge_lstsq
from selfsense.hysteresis.models import searches_holds as _searches_holds  # (the joint hold search, docs/method.md 6b')
from selfsense.io.rig import rig_value
from selfsense.mechanics.piezo import force_row  # thesis eq. (46): the two-port force row
from selfsense.sensing.core import (force_coefficients, force_regressor, h_target, piezo_voltage, tip_displacement,
                                    tip_force)
from selfsense.signals import limit_to_range, sliding_dc_offset

log = logging.getLogger(__name__)

__all__ = [
    "SensingConfig",
    "SelfSensingEstimator",
    "CalibrationError",
    "h_target",
    "scaled_lstsq",
]

H_MODES = ("thesis", "onsite")
H_MODELS = ("auto", "linear", "pi", "preisach", "ri", "modified_pi", "duhem")
DRIFT = ("auto", "off")
#: the chain members ``SelfSensingEstimator(members=...)`` can force: charge link (leakage, offset drift, absorption,
#: quantiser), H link (hold rows), voltage link (amplifier), load link (stress: :mod:`selfsense.chain.load`)
CHAIN_MEMBER_NAMES = ("leakage", "offset_drift", "hold_rows", "amplifier", "absorption", "quantiser", "stress",
                      "tip_creep", "temperature", "amplifier_lag")
REGRESSIONS = ("auto", "approx", "twoport", "full")
#: refits of H on the drift-free charge (the drift is always estimated with the H of the drift-column fit)
N_DRIFT_ALTERNATIONS = 1


class CalibrationError(ValueError):
    """The calibration trials cannot determine the model (missing trial roles, degenerate data...)."""


@dataclass
class SensingConfig:
    """Configuration of the estimator (the ``calibration`` / ``estimation`` keys of ``config.yaml``)."""

    h_mode: str = "thesis"
    h_model: str = "auto"
    n_play: int = 15
    n_sup: int = 15
    n_creep: int | str = "auto"
    creep: bool = True
    solver: str = "CLARABEL"
    regression: str = "auto"
    limit: bool = True
    dc_offset: bool = False
    dc_offset_force: bool = False
    zero_input_v: float = 0.5
    fit_z0: bool = False
    max_fit_samples: int = 20000
    n_creep_thresholds: int = 8
    drift: str = "auto"
    cv_blocks: int = 5
    h_identification: str = "joint"
    rest_offset: str = "auto"
    hold_rows: str = "auto"
    amplifier: str = "auto"
    absorption: str = "auto"
    #: the quantiser member: "auto" (the default since it is identified on the free-tip laser, docs/method.md 1b')
    #: where the shunt channel is undithered and the calibration supports it, "off" never
    quantiser: str = "auto"
    #: the offset-drift member: "auto" where the calibration rows support it, "on" on every trial's rest segments
    #: (docs/cross_device.md, "The offset-drift member forced on"), "off" never
    offset_drift: str = "auto"
    #: the load link's stress member (docs/method.md 6f): "auto" where the force-reference calibration rows support
    #: it, "off" never. Off by default: on the bundled dataset the member finds the simulator's stress (s_H 0.45 per
    #: N against 0.5) and makes the contact trials' displacement worse (docs/method.md 6f)
    stress: str = "off"
    #: the load link's charge-free creep member (:mod:`selfsense.chain.creep`; not the creep of H(q), ``creep``): a
    #: bank of lags on Q and V_p at both tip outputs, "auto" where it lowers the displacement calibration rows'
    #: blocked-CV error by more than 10 %, "off" never
    tip_creep: str = "auto"
    #: the charge link's temperature member (:mod:`selfsense.chain.temperature`): the charge scale drifting over the
    #: campaign, "auto" where the free- and blocked-tip trials' reference-free relation shows a drift of at least
    #: 8e-4 over the campaign, "off" never. Off by default: adopted on the bundled dataset (whose device warms by 1 K)
    #: it lowers the free- and blocked-tip trials' error and raises the contact trials' (Table 3 2.05 / 3.62 % ->
    #: 2.14 / 3.91 %), and its joint identification calibrates the chain twice more (docs/method.md 6i). The gap
    #: diagnostic forces it on to predict how far a named temperature drift's gap shrinks
    temperature: str = "off"
    #: the voltage link's lag member (:func:`selfsense.chain.amplifier.lag_column`, docs/method.md 1a'): the HV
    #: amplifier's bandwidth (or a DAQ clock skew) delays the actuator voltage behind the command, ``V = gain
    #: u_cmd(t - tau) - V_s``; "auto" where the lag column lowers the selected H(q) form's blocked-CV error by at
    #: least 2 % with 0 < tau <= 5 ms, "off" never
    amplifier_lag: str = "auto"

    def __post_init__(self) -> None:
        if self.h_mode not in H_MODES:
            raise ValueError(f"SensingConfig.h_mode: expected one of {H_MODES}, found {self.h_mode!r}")
        if self.h_model not in H_MODELS:
            raise ValueError(f"SensingConfig.h_model: expected one of {H_MODELS}, found {self.h_model!r}")
        if self.h_identification not in ("joint", "thesis"):
            raise ValueError(f"SensingConfig.h_identification: expected 'joint' or 'thesis', found "
                             f"{self.h_identification!r}")
        if self.h_identification == "thesis" and self.h_model not in ("modified_pi", "ri"):
            raise ValueError(f"SensingConfig: h_identification 'thesis' fits h_model 'modified_pi' or 'ri' on the "
                             f"free-tip trial(s) only, found h_model {self.h_model!r}")
        if self.drift not in DRIFT:
            raise ValueError(f"SensingConfig.drift: expected one of {DRIFT}, found {self.drift!r}")
        if self.rest_offset not in ("auto", "off"):
            raise ValueError(f"SensingConfig.rest_offset: expected 'auto' or 'off', found {self.rest_offset!r}")
        if self.hold_rows not in ("auto", "off"):
            raise ValueError(f"SensingConfig.hold_rows: expected 'auto' or 'off', found {self.hold_rows!r}")
        if self.amplifier not in ("auto", "off"):
            raise ValueError(f"SensingConfig.amplifier: expected 'auto' or 'off', found {self.amplifier!r}")
        if self.amplifier_lag not in ("auto", "off"):
            raise ValueError(f"SensingConfig.amplifier_lag: expected 'auto' or 'off', found {self.amplifier_lag!r}")
        if self.absorption not in ("auto", "off"):
            raise ValueError(f"SensingConfig.absorption: expected 'auto' or 'off', found {self.absorption!r}")
        if self.quantiser not in ("auto", "off"):
            raise ValueError(f"SensingConfig.quantiser: expected 'auto' or 'off', found {self.quantiser!r}")
        if self.stress not in ("auto", "off"):
            raise ValueError(f"SensingConfig.stress: expected 'auto' or 'off', found {self.stress!r}")
        if self.tip_creep not in ("auto", "off"):
            raise ValueError(f"SensingConfig.tip_creep: expected 'auto' or 'off', found {self.tip_creep!r}")
        if self.temperature not in ("auto", "off"):
            raise ValueError(f"SensingConfig.temperature: expected 'auto' or 'off', found {self.temperature!r}")
        if self.offset_drift not in ("auto", "on", "off"):
            raise ValueError(f"SensingConfig.offset_drift: expected 'auto', 'on' or 'off', found {self.offset_drift!r}")
        if self.offset_drift == "on" and self.drift == "off":
            raise ValueError("SensingConfig: offset_drift 'on' needs drift 'auto' (drift 'off' turns the charge link's "
                             "leakage and offset-drift members off)")
        if int(self.cv_blocks) < 2:
            raise ValueError(f"SensingConfig.cv_blocks: expected an integer >= 2, found {self.cv_blocks!r}")
        if self.regression not in REGRESSIONS:
            raise ValueError(f"SensingConfig.regression: expected one of {REGRESSIONS}, found {self.regression!r}")
        for name in ("n_play", "n_sup"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"SensingConfig.{name}: expected a positive integer, found {getattr(self, name)!r}")
        if self.n_creep != "auto" and (not isinstance(self.n_creep, (int, np.integer)) or int(self.n_creep) < 0):
            raise ValueError(f"SensingConfig.n_creep: expected 'auto' or an integer >= 0, found {self.n_creep!r}")

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> "SensingConfig":
        cfg = dict(cfg or {})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ValueError(f"sensing config: unknown keys {unknown}; expected some of {sorted(known)}")
        if isinstance(cfg.get("offset_drift"), bool):   # YAML 1.1 reads an unquoted on / off as true / false
            cfg["offset_drift"] = "on" if cfg["offset_drift"] else "off"
        for k in ("stress", "tip_creep", "temperature"):
            if cfg.get(k) is False:   # an unquoted off
                cfg[k] = "off"
        return cls(**cfg)


def _rig_params(rig: Any) -> dict[str, float]:
    """The rig quantities the estimator needs, from a ``selfsense.io.Rig`` or a plain rig.yaml mapping."""
    return {
        "n_A": rig_value(rig, "n_actuators"),
        "C_p": rig_value(rig, "actuator_catalog", "capacitance_f"),
        "blocked_force": rig_value(rig, "actuator_catalog", "blocked_force_n"),
        "max_voltage": rig_value(rig, "actuator_catalog", "max_voltage_v"),
        "dx_pzt_free": rig_value(rig, "actuator_catalog", "free_displacement_m"),
        "dx_tip_free": rig_value(rig, "tip_free_displacement_m"),
    }


from selfsense.hysteresis.models import loop_orientation  # noqa: E402,F401  (public here since v0.1)


class GaugedH:
    """``H(Q) = sign * (G[Q] - c Q)``: an operator ``G`` fitted to ``sign * H + c Q``. Model JSON files written before
    the thesis identification became the registry's ``ModifiedPIH`` hold this type; it is still read and evaluated
    (and streamed), and hand-made operators can be wrapped in it.

    Play operators with non-negative weights (thesis eq. 32, constraints 68-75) only make counter-clockwise loops
    with rising branches; a piezo's H(q) runs clockwise with increasing charge (paper Fig. 12) and, in the eq. (55)
    convention, falls with q. Negating (``sign``) and adding a linear term ``c Q`` (a play operator of zero
    threshold) is an exact reparametrisation that brings H into the operator's class; it is undone on evaluation.
    """

    def __init__(self, inner, sign: float = 1.0, c: float = 0.0):
        self.inner, self.sign, self.c = inner, float(sign), float(c)

    def __call__(self, Q):
        Q = np.asarray(Q, dtype=float)
        if type(self.inner).__name__ == "RIModel":
            g = np.asarray(self.inner(np.maximum(Q, 0.0)), dtype=float)
        else:
            g = np.asarray(self.inner(Q), dtype=float)
        return self.sign * (g - self.c * Q)

    def to_dict(self) -> dict:
        return {"sign": self.sign, "c": self.c, "inner": {"kind": type(self.inner).__name__, "params": self.inner.to_dict()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "GaugedH":
        return cls(_h_from_dict(d["inner"]), d["sign"], d["c"])


def auto_creep_count(duration_s: float, dt: float) -> int:
    """Number m of log(t) creep eigenvalues a_j = 1/(10^(j-1) T_s) (thesis eq. 40) whose slowest time constant
    10^(m-1) T_s reaches the calibration trial's duration: m = ceil(log10(duration / T_s)) + 1."""
    return int(np.ceil(np.log10(max(duration_s / dt, 1.0)))) + 1


def _fit_thesis_modified_pi(cfg: SensingConfig, Q: np.ndarray, y: np.ndarray, dt: float):
    """``h_identification: thesis`` with ``h_model: modified_pi``: Kuhnen's modified PI operator (thesis App. A) fitted
    to the H(q) calibration target of the first free-tip trial, the method as the thesis states it. The model is
    the registry's :class:`~selfsense.hysteresis.models.ModifiedPIH` (one modified-PI identification for both
    identifications: the QP of ``hysteresis.identify``, the sign / linear gauge built in); a fit no better than a
    straight line is kept, as the thesis would, with a warning in the report. Returns (model, report dict)."""
    from selfsense.hysteresis.models import DegenerateFitError, ModifiedPIH

    t0 = time.perf_counter()
    model = ModifiedPIH(n_play=cfg.n_play, n_sup=cfg.n_sup, creep=cfg.creep, n_creep=cfg.n_creep, solver=cfg.solver,
                        fit_z0=cfg.fit_z0)
    warnings = []
    try:
        model.fit(Q, y, dt)
    except DegenerateFitError as exc:
        warnings.append(str(exc))
    report = {k: (float(v) if isinstance(v, np.floating) else v) for k, v in model.fit_report_.items()}
    report.pop("seconds", None)   # wall-clock time goes to the log, never into an artefact
    report["warnings"] = warnings
    log.info("H(q) fit: %s, %d samples, %.2f s, RMS %.3f %% / max %.3f %% of range", cfg.h_model, len(Q),
             time.perf_counter() - t0, report["rms_pct"], report["max_pct"])
    report["h_model"] = cfg.h_model
    return model, report


def _h_to_dict(model) -> dict:
    if hasattr(model, "kind") and hasattr(model, "predict"):
        return {"kind": "registry", "params": model.to_dict()}
    return {"kind": type(model).__name__, "params": model.to_dict()}


def _h_from_dict(d: Mapping[str, Any]):
    kind = d["kind"]
    if kind == "registry":
        from selfsense.hysteresis.models import h_from_dict

        return h_from_dict(d["params"])
    if kind == "RICreepH":
        from selfsense.sensing.hmodels import RICreepH

        return RICreepH.from_dict(d["params"])
    if kind == "GaugedH":
        return GaugedH.from_dict(d["params"])
    if kind == "ModifiedPI":
        from selfsense.hysteresis.pi import ModifiedPI

        return ModifiedPI.from_dict(d["params"])
    if kind == "RIModel":
        from selfsense.hysteresis.ri import RIModel

        return RIModel.from_dict(d["params"])
    raise ValueError(f"hysteresis model: unknown kind {kind!r}; expected 'GaugedH', 'ModifiedPI' or 'RIModel'")


def _eval_h(model, Q: np.ndarray, dt: float | None = None) -> np.ndarray:
    """H(Q) [V] of any stored model; registry models are evaluated at the sample time ``dt`` [s]."""
    if hasattr(model, "predict") and hasattr(model, "kind"):
        return np.asarray(model.predict(Q, dt), dtype=float)
    if isinstance(model, GaugedH) and dt is not None and hasattr(model.inner, "with_dt") and model.inner.dt != dt:
        # creep eigenvalues are in 1/s: evaluate at the trial's own sample time
        model = GaugedH(model.inner.with_dt(float(dt)), model.sign, model.c)
    if type(model).__name__ == "RIModel":
        return np.asarray(model(np.maximum(Q, 0.0)), dtype=float)
    return np.asarray(model(Q), dtype=float)


def scaled_lstsq(X: np.ndarray, y: np.ndarray, rcond: float | None = None) -> np.ndarray:
    """Least squares on column-scaled regressors (charges ~1e-4 C and voltages ~1e2 V differ by 1e6): each column
    divided by its RMS (a zero column left as it is), ``numpy.linalg.lstsq`` with ``rcond``, the scale undone."""
    scale = np.sqrt(np.mean(X**2, axis=0))
    scale[scale == 0] = 1.0
    coef, *_ = np.linalg.lstsq(X / scale, y, rcond=rcond)
    return coef / scale


def _decimate(df: pd.DataFrame, max_samples: int) -> pd.DataFrame:
    step = max(1, int(np.ceil(len(df) / max_samples)))
    return df.iloc[::step] if step > 1 else df


def _with_column(df: pd.DataFrame, col: str, values: np.ndarray) -> pd.DataFrame:
    """A copy of ``df`` (attrs kept) with ``col`` replaced."""
    out = df.copy()
    out[col] = values
    return out


def _trial_dt(df: pd.DataFrame) -> float:
    t = df["t"].to_numpy(dtype=float)
    return float(np.median(np.diff(t))) if len(t) > 1 else 1e-3


def integral_v(df: pd.DataFrame) -> np.ndarray:
    """``int_0^t V dtau`` [V s] restarted wherever the relay shorts the leads (like the charge, thesis eq. 57): the
    charge a leakage conductance g draws through the shunt is ``g * integral_v``."""
    from selfsense.signals import charge_from_shunt

    V = df["V"].to_numpy(dtype=float)
    relay = (df["relay"].to_numpy(dtype=float) >= 0.5).astype(float)
    iv, _ = charge_from_shunt(df["t"].to_numpy(dtype=float), V, relay, 1.0, offset=None)
    return iv


def _leakage_inputs_sha256(cal_trials: Mapping[str, pd.DataFrame], cal: pd.DataFrame, slope: float) -> str:
    """SHA-256 of everything the leakage search reads: the gauge slope and, per calibration trial in order, its id,
    tip and reference and the bits of its ``t``, ``V``, ``q``, ``relay`` and ``f_ref`` (float64). Equal digests: the
    search gives the same numbers (it is deterministic), so an earlier one can be reused."""
    import hashlib

    h = hashlib.sha256(np.float64(slope).tobytes())
    for tid, row in cal.iterrows():
        h.update(repr((str(tid), str(row.get("tip")), str(row.get("reference")))).encode())
        df = cal_trials[tid]
        for c in ("t", "V", "q", "relay", "f_ref"):
            h.update(c.encode())
            if c in df:
                h.update(np.ascontiguousarray(df[c].to_numpy(dtype=np.float64)).tobytes())
    return h.hexdigest()


def _candidates_for(h_model: str, cfg: "SensingConfig") -> tuple:
    from selfsense.hysteresis.models.select import DEFAULT_CANDIDATES

    base = (("linear", {}), ("pi", {"n_play": 20, "ridge": 1e-3}))
    if h_model == "auto":
        return DEFAULT_CANDIDATES
    if h_model == "modified_pi":
        own = (("modified_pi", {"n_play": cfg.n_play, "n_sup": cfg.n_sup, "creep": cfg.creep,
                                "n_creep": cfg.n_creep, "solver": cfg.solver, "fit_z0": cfg.fit_z0}),)
    elif h_model == "linear":
        own = ()
    else:
        own = tuple(c for c in DEFAULT_CANDIDATES if c[0] == h_model) or ((h_model, {}),)
    return base + own


def _insample(model, qs, ys, dt, extras, thin: int = 16, drop=None, design=None) -> float:
    """RMS [V] of the least-squares residual of ``model`` on every ``thin``-th calibration row (leakage search);
    ``extras`` per segment; ``drop``: boolean over the stacked rows of all samples, rows left out of the fit.
    ``design``: ``(X, y, penalised)`` of :func:`insample_design` with the same arguments, already built (not
    modified here)."""
    from selfsense.hysteresis.models import fit_stride, ridge_lstsq
    from selfsense.hysteresis.models.select import split_rows

    lengths = [len(q) for q in qs]
    X, y, pen = insample_design(model, qs, ys, dt, extras, thin) if design is None else design
    k = max(thin, fit_stride(lengths))
    if drop is not None:
        keep = ~np.concatenate([d[::k] for d in split_rows(np.asarray(drop, bool), lengths)])
        X, y = X[keep], y[keep]
    w = ridge_lstsq(X, y, pen, model.ridge)
    return float(np.sqrt(np.mean((X @ w - y) ** 2)))


def insample_design(model, qs, ys, dt, extras, thin: int = 16):
    """``(X, y, penalised)``: the stacked rows :func:`_insample` fits (every ``max(thin, fit_stride)``-th sample)."""
    from selfsense.hysteresis.models import fit_stride
    from selfsense.hysteresis.models.select import stacked_design

    return stacked_design(model, qs, ys, dt, extras, max(thin, fit_stride([len(q) for q in qs])))


#: entries of the memo of one leakage search (:meth:`SelfSensingEstimator._leakage`): the calibration rows and the
#: reference model's stacked rows at a conductance g, a few MB each on the bundled datasets
LEAK_MEMO_ENTRIES = 32


def member_modes(members: Mapping[str, str] | None, configured: Mapping[str, str] | None = None) -> dict:
    """Every chain member's mode: the forced value of ``members``, else the configuration's (``configured``), else
    "auto". An unknown member or a mode other than "auto", "on" or "off" raises a ValueError naming it."""
    members = dict(members or {})
    unknown = sorted(set(members) - set(CHAIN_MEMBER_NAMES))
    if unknown:
        raise ValueError(f"SelfSensingEstimator.members: unknown members {unknown}; expected "
                         f"{', '.join(CHAIN_MEMBER_NAMES)}")
    out = {}
    for k in CHAIN_MEMBER_NAMES:
        m = str(members.get(k, (configured or {}).get(k, "auto")))
        if m not in ("auto", "on", "off"):
            raise ValueError(f"SelfSensingEstimator.members[{k!r}]: expected 'auto', 'on' or 'off', found {m!r}")
        out[k] = m
    return out


def _held_linear_form(candidates) -> bool:
    """Whether ``candidates`` hold one form (:meth:`SelfSensingEstimator.selected_form`: the straight line and at most
    one other form) whose model is linear in its parameters -- the forms :attr:`SelfSensingEstimator.h_selection_cv`
    lets a refit take without the blocked CV."""
    from selfsense.hysteresis.models import LinearParamH, make_model

    forms = [c for c in candidates if c[0] != "linear"]
    if not candidates or len(forms) > 1:
        return False
    kind, params = forms[0] if forms else candidates[0]
    return isinstance(make_model(kind, **dict(params)), LinearParamH)


def _reference_h():
    """The reference H(q) of the charge-link searches (leakage, quantiser, amplifier rows): a 12 x 12 Preisach grid
    with 6 plays, creep and ridge 1e-4, fixed whatever H(q) the configuration selects, so that a search's numbers
    depend on the calibration inputs alone."""
    from selfsense.hysteresis.models import PreisachH

    return PreisachH(n_grid=12, n_play=6, ridge=1e-4)


#: the slew searches of this process (:meth:`SelfSensingEstimator._slew_link`), by :func:`_slew_key` of their rows:
#: the gap diagnostic's recalibrations and ``compare_modes`` fit the same trials again
_SLEW_SEARCHES: dict = {}


def _slew_key(trials, rows_meta, gain: float, slope: float) -> str:
    """SHA-256 of everything the slew search reads: the rows' trials' time, command, V, charge, relay (and a
    calibration trial's force reference), their roles / tips / references, the amplifier gain and the gauge slope."""
    import hashlib

    h = hashlib.sha256(repr((float(gain), float(slope))).encode())
    for t, row in rows_meta.iterrows():
        h.update(repr((t, row["role"], row["tip"], row["reference"])).encode())
        df = trials[t]
        for c in ("t", "u_cmd", "V", "q", "relay") + (("f_ref",) if row["reference"] == "force" else ()):
            h.update(np.ascontiguousarray(df[c].to_numpy(dtype=float)).tobytes())
    return h.hexdigest()


def _reference_insample(qs, ys, ex, dt, drop=None, design=None) -> float:
    """:func:`_insample` of the reference model (:func:`_reference_h`): the objective of the charge-link searches.
    ``design``: its :func:`insample_design` on these rows, already built."""
    return _insample(_reference_h(), qs, ys, dt, ex, drop=drop, design=design)


def _reference_cv(qs, ys, ex, dt) -> float:
    """Mean blocked-CV RMS [V] of the reference model (:func:`_reference_h`) on the calibration rows, 3 folds, every
    8th row held out: the gate of the charge-link members."""
    from selfsense.hysteresis.models import fit_stride
    from selfsense.hysteresis.models.select import _cv_linear, blocked_folds

    k = fit_stride([len(q) for q in qs])
    folds = blocked_folds([len(q[::k]) for q in qs], 3)
    return float(np.mean(_cv_linear(_reference_h(), qs, ys, dt, ex, folds, 8)))


# ---- the charge-link and rest-offset gates (docs/method.md 6c, 6c'): adopted on the calibration rows' blocked CV --
#: leakage from the calibration rows: the blocked-CV error with g must not be higher than without (ratio <= 1) ...
LEAK_CAL_MAX_CV_RATIO = 1.0
#: ... and a majority of the leave-one-block-out estimates of g (2 of 3) must agree with g within this fraction of g
#: (one block left out can remove most of a trial's ramp of int V dt: one stray estimate of three is common on
#: devices with leakage, docs/method.md 6c)
LEAK_FOLD_AGREEMENT = 0.5
#: leakage from the holds of every trial: the calibration rows' blocked-CV error may grow by at most 2 % with it
LEAK_HOLD_MAX_CV_RATIO = 1.02
#: leakage from the calibration rows is contradicted by the holds of every trial when it exceeds the conductance the
#: holds measure (z >= Z_SUPPORT at >= 2 voltage levels) by more than this factor
LEAK_HOLD_CONTRADICTION = 1.5
#: leakage corroborated by two independent measurements: where neither the calibration rows nor the holds support it
#: on their own, the calibration rows' g and the conductance the holds of every trial measure agree within this
#: fraction of the larger, and the calibration rows' blocked-CV error is not higher with g than without
LEAK_CORROBORATION = 0.25
#: leakage the reference model rejected, decided again by the H(q) selection itself: where the calibration rows' g
#: (not contradicted by the holds) gives a best candidate whose blocked-CV error is below this fraction of the best
#: without leakage, leakage is adopted with that candidate (0 switches the rule off). The reference Preisach model's
#: creep bank can take up the ramp g int V dt of a few-second trial, so its CV misses a leakage that the selected
#: form's does not (docs/method.md 6c)
LEAK_SELECTED_FORM_RATIO = 0.8
#: offset-drift compensation: the columns must lower the calibration rows' blocked-CV error by more than 1 %
OFFSET_DRIFT_MIN_GAIN = 0.01
#: rest offset: the constant must lower the displacement rows' blocked-CV error by more than 2 %
REST_OFFSET_MIN_GAIN = 0.02


def leakage_supported_by_calibration(g: float, g_folds, cv_with: float, cv_without: float) -> bool:
    """Leakage ``g`` [S] from the calibration rows is supported when it is above 0.1 nS, its blocked-CV error is not
    higher than without it, and more than half of the leave-one-block-out estimates (2 of 3) lie within 50 % of it."""
    g_folds = list(g_folds)
    agree = sum(abs(x - g) <= LEAK_FOLD_AGREEMENT * g for x in g_folds)
    return bool(g > 0.1e-9 and cv_with <= LEAK_CAL_MAX_CV_RATIO * cv_without and 2 * agree > len(g_folds))


def leakage_supported_by_holds(hold_supported: bool, cv_with: float, cv_without: float) -> bool:
    """Leakage estimated from the holds of every trial is used when the holds support it and the calibration rows'
    blocked-CV error grows by at most 2 % with it."""
    return bool(hold_supported and cv_with <= LEAK_HOLD_MAX_CV_RATIO * cv_without)


def leakage_measured_by_holds(ev: Mapping) -> float | None:
    """The conductance [S] the holds of every trial measure (:func:`selfsense.chain.charge.hold_evidence`), or
    None: g > 0 with z >= ``Z_SUPPORT`` over holds at >= 2 voltage levels in >= 2 trials. A measurement, not support:
    a slow relaxation over holds short against it can still move it (that is what ``supported`` checks), so it serves
    as a bound on the calibration rows' estimate, never as the conductance of a device on its own."""
    from selfsense.chain.charge import Z_SUPPORT

    g, z = float(ev.get("g_s") or 0.0), float(ev.get("z") or 0.0)
    ok = (g > 0 and z >= Z_SUPPORT and int(ev.get("n_levels") or 0) >= 2 and int(ev.get("n_trials") or 0) >= 2
          and bool(ev.get("resolved", True)))   # an undithered shunt channel does not resolve it (method.md 1b)
    return g if ok else None


def leakage_corroborated(g_cal: float | None, g_holds: float | None, cv_with: float | None,
                         cv_without: float) -> bool:
    """Leakage that neither source supports on its own is adopted when two independent measurements of it agree:
    the calibration rows' g (references of the calibration trials) and the conductance the holds of every trial
    measure (:func:`leakage_measured_by_holds`: V and Q only) lie within ``LEAK_CORROBORATION`` (25 %) of the larger
    of the two, g is above 0.1 nS, and the calibration rows' blocked-CV error is not higher with g than without.
    (The calibration gate also asks its leave-one-block-out estimates to agree, which one block holding most of a
    trial's ramp of int V dt defeats; the holds' own gate asks them to be long against a slow relaxation. Each
    failure is a reason for doubt that the other, independent, measurement answers.)"""
    if g_cal is None or g_holds is None or cv_with is None:
        return False
    return bool(g_cal > 0.1e-9 and abs(g_cal - g_holds) <= LEAK_CORROBORATION * max(g_cal, g_holds)
                and cv_with <= LEAK_CAL_MAX_CV_RATIO * cv_without)


def leakage_contradicted_by_holds(g_cal: float, g_holds: float | None) -> bool:
    """The calibration rows' leakage ``g_cal`` [S] is contradicted when the holds of every trial measure a conductance
    ``g_holds`` and ``g_cal`` exceeds it by more than ``LEAK_HOLD_CONTRADICTION`` (1.5x): the calibration rows have
    then taken up more than leakage (a creep of the mechanism, or an H the reference model misfits, drives the
    search's g up; measured in docs/method.md)."""
    return bool(g_holds is not None and g_cal > LEAK_HOLD_CONTRADICTION * g_holds)


#: a calibration-row leakage at or below this conductance [S] is none found (the support gates ask for more)
LEAK_FOUND_S = 0.1e-9


def leakage_bounded_by_holds(g_cal: float | None, g_bound: float | None) -> bool:
    """The calibration rows' leakage ``g_cal`` [S] is contradicted where the holds of every trial measure no
    conductance but bound it (:func:`selfsense.chain.charge.leakage_upper_bound`: their estimate plus ``Z_SUPPORT``
    standard errors, with and without a slow relaxation) and ``g_cal`` exceeds ``LEAK_HOLD_CONTRADICTION`` (1.5x) that
    bound (at least 0.1 nS). Measured on an independently written clean device: the calibration rows found
    15-24 nS where 62 holds in 8 trials give -0.008 +- 0.054 nS (docs/method.md 6c)."""
    return bool(g_cal is not None and g_bound is not None and g_cal > LEAK_FOUND_S
                and g_cal > LEAK_HOLD_CONTRADICTION * max(g_bound, LEAK_FOUND_S))


def leakage_understated_by_holds(g_cal: float, g_holds: float | None) -> bool:
    """With leakage forced on (``members={"leakage": "on"}``: the gap diagnostic's recalibration of a confirmed
    leakage, or a user's configuration), the calibration rows' ``g_cal`` [S] gives way to the conductance ``g_holds``
    the holds of every trial measure where the rows found none (``g_cal <= LEAK_FOUND_S``, 0.1 nS): sines at one rate
    excite leakage too little for the search (their charge ramp ``g int V dt`` averages out over each period), while
    a hold at a constant voltage integrates it. Left to the calibration rows, the member forced on would carry next
    to no leakage (0.02 nS against the holds' 58 nS, 36 nS injected, on tip case 41 of seed 20261219; docs/gap.md).
    A calibration ``g`` that found something stands, however far below the holds' value: a decaying relaxation
    inflates theirs (the bundled ``tweezer_sim``: 0.5 nS true, 1.6 nS from its calibration rows, 3.2 nS from its
    holds). Not used in ``auto``: there the holds' measurement alone is no support."""
    return bool(g_holds is not None and g_holds > LEAK_FOUND_S and g_cal <= LEAK_FOUND_S)


def leakage_search_of(fitted) -> dict | None:
    """The leakage search of a fitted estimator's last H(q) calibration (``fit_report_["hysteresis"]["drift"]
    ["search"]``), to be reused by a calibration on the same inputs, or None (not fitted, or no such report)."""
    rep = getattr(fitted, "fit_report_", None) or {}
    return (rep.get("hysteresis", {}).get("drift") or {}).get("search")


def offset_drift_supported(cv_with: float, cv_without: float) -> bool:
    """The offset-drift columns are adopted when they lower the blocked-CV error by more than 1 %."""
    return bool(cv_with < (1.0 - OFFSET_DRIFT_MIN_GAIN) * cv_without)


def rest_offset_supported(cv_with: float, cv_without: float) -> bool:
    """The rest offset is adopted when it lowers the displacement rows' blocked-CV error by more than 2 %."""
    return bool(cv_with < (1.0 - REST_OFFSET_MIN_GAIN) * cv_without)


def _blocked_cv_rms(A: np.ndarray, y: np.ndarray, held: list) -> float:
    """Blocked cross-validated RMS of the least-squares fit ``y ~ A``: each mask of ``held`` (from
    :func:`selfsense.hysteresis.models.select.blocked_folds`) is predicted from the rows outside it. The score with
    which the chain's members of the sensing regression are adopted (rest offset, creep bank, offset drift beside
    it)."""
    err = np.concatenate([A[h] @ scaled_lstsq(A[~h], y[~h]) - y[h] for h in held])
    return float(np.sqrt(np.mean(err ** 2)))


def _rest_offset(X: np.ndarray, y: np.ndarray, lengths: list, n_blocks: int = 5) -> tuple[bool, dict]:
    """Whether the displacement row gets a constant ``dx0`` [m], the tip's closing at rest.

    A remanent polarisation leaves charge on the actuators that the charge integrator, started at the relay, never
    saw (thesis 000_18d138f03f1777c3.txt eq. 57 integrates from the known initial state): eq. (52) then holds for
    the total charge ``Q + q_0``, i.e. ``dx = A1 Q + A2 V_p + A1 q_0``, a tip that rests open or closed. Adopted when
    it lowers the blocked cross-validated RMS of the displacement rows (fold i holds out the i-th of ``n_blocks``
    contiguous blocks of every calibration trial, as the H selection does) by more than 2 %. ``X``, ``y``: the
    stacked displacement rows, ``lengths``: the rows of each calibration segment in stacking order."""
    from selfsense.hysteresis.models.select import blocked_folds

    held = blocked_folds(lengths, n_blocks, rotate=False)
    without = _blocked_cv_rms(X, y, held)
    with_ = _blocked_cv_rms(np.column_stack([X, np.ones(len(X))]), y, held)
    ok = rest_offset_supported(with_, without)
    return ok, {"applied": ok, "cv_rms_m_without": without, "cv_rms_m_with": with_,
                "note": ("rest offset applied" if ok else "rest offset not supported by the calibration trials")
                + f" (blocked-CV RMS of the displacement rows {with_:.3g} m with, {without:.3g} m without)"}


def _force_only_selected(table: list, kind: str) -> list:
    """Re-mark the selection table when the configuration names one model kind: its best variant is used."""
    own = [r for r in table if r["kind"] == kind and r.get("status", "ok") == "ok"
           and r["cv_rms_mean_v"] is not None and np.isfinite(r["cv_rms_mean_v"])]
    if not own:
        return table
    best = min(own, key=lambda r: r["cv_rms_mean_v"])
    for r in table:
        r["selected"] = r is best
    return table


def _json_safe_report(rep: Mapping[str, Any]) -> dict:
    """The fit report with the H(q) selection table JSON-safe (a failed candidate's NaN fold errors as null), and
    its major-loop checks too (a model whose output on a trial is not finite has an infinite excursion: null)."""
    from selfsense.hysteresis.models.select import json_safe_table

    out = dict(rep)
    h = out.get("hysteresis")
    if isinstance(h, Mapping) and h.get("selection"):
        out["hysteresis"] = h = {**h, "selection": json_safe_table(list(h["selection"]))}
    if isinstance(h, Mapping) and h.get("envelope"):
        out["hysteresis"] = {**h, "envelope": json_safe_table(list(h["envelope"]))}
    return out


class CoefficientRows(NamedTuple):
    """The rows of the sensing-coefficient regression (:meth:`SelfSensingEstimator._coefficient_rows`)."""

    Xd: np.ndarray           #: ``[Q, V_p]`` of the displacement rows (free-tip laser, the blocked tip's dx = 0)
    yd: np.ndarray           #: their targets [m]
    Xf: np.ndarray           #: ``[Q, V_p]`` of the force rows (load cell, the free tip's f = 0)
    yf: np.ndarray           #: their targets [N]
    lengths_d: list          #: displacement rows per segment
    rest_ok: bool            #: the rest offset adopted (:func:`_rest_offset`)
    rest_info: dict          #: its numbers and note
    base: np.ndarray         #: the displacement rows' two-port columns (with the rest offset's where adopted)
    Kd: np.ndarray           #: the creep bank's columns of the displacement rows (none without lags)
    Kf: np.ndarray           #: and of the force rows
    lengths_f: list          #: force rows per segment


@dataclass
class SelfSensingEstimator:
    """Simultaneous tip displacement and force estimation from voltage and charge (thesis eq. 52).

    Scikit-learn style: configuration in the constructor, :meth:`fit` on calibration trials only,
    :meth:`estimate` on any prepared trial; fitted attributes end with an underscore.
    """

    config: SensingConfig = field(default_factory=SensingConfig)
    rig: Any = None
    #: chain members forced on or off: the charge link's ``"leakage"`` and ``"offset_drift"``
    #: (:mod:`selfsense.chain.charge`; "auto" | "on" | "off"), the voltage link's ``"amplifier"`` (the actuator voltage
    #: rebuilt where the HV amplifier sits at its current limit, :mod:`selfsense.chain.amplifier`) and the H link's
    #: ``"hold_rows"`` (the creep of H from the holds of every trial, docs/method.md 6b'; "off" drops them whatever
    #: ``hold_rows`` configures); "auto" (the
    #: default) lets the calibration data and the reference-free hold evidence decide; the gap diagnostic forces a
    #: member off to score the chain without it
    members: Mapping[str, str] = field(default_factory=dict)
    #: the H(q) candidates ``((kind, params), ...)`` of the blocked-CV selection; empty (the default): those of the
    #: configured ``h_model``. ``compare_modes`` passes the straight line and the pipeline's selected candidate, so that
    #: a second calibration mode refits the selected form instead of repeating the whole selection
    h_candidates: tuple = ()
    #: False: a held form (``h_candidates`` = :meth:`selected_form`, a form linear in its parameters) is refitted
    #: without the blocked CV that would only decide between it and the straight line
    #: (``select_h_model(..., cv=False)``): the final fit of the selection reads no CV number, so the model is the one
    #: the CV gives, bit for bit, wherever the form beats the straight line -- as it did in the fit it was taken from.
    #: The fit report records it (``fit_report_["hysteresis"]["selection_cv"]``). The gap diagnostic's
    #: recalibrations set it (:func:`selfsense.gap.counterfactual._make`): each held form is fitted, never the
    #: straight line in its place. A form not linear in its parameters keeps the CV (the leakage check of
    #: :meth:`_leakage_check_with_selected` reads its CV error)
    h_selection_cv: bool = True
    #: True: the blocked-CV selection of ``h_model: auto`` stops a candidate fitted fold by fold (the Duhem form, the
    #: modified PI) as soon as it can no longer beat the best convex candidate (``select_h_model(..., prune=True)``):
    #: the selected model and its row are those of the full selection, the other rows may lack folds. For a fit whose
    #: table is not published: the gap diagnostic's recalibrations set it (:func:`selfsense.gap.counterfactual._make`)
    h_selection_prune: bool = False
    #: the leakage search of an earlier fit (its ``fit_report_["hysteresis"]["drift"]["search"]``): reused, not
    #: searched again, when it was made on the same calibration inputs (``inputs_sha256``: the charge, voltage, force
    #: and relay of the calibration trials and the gauge slope, bit for bit). The search does not depend on the
    #: configured H(q) or on the forced members, so the gap diagnostic's recalibrations that change only a member
    #: pass the pipeline's; a fit on other inputs ignores it and searches
    leakage_search_reuse: Mapping | None = None
    #: True: :attr:`leakage_search_reuse` is also taken when it was made on the same calibration inputs in the other
    #: H(q) gauge (thesis eq. 55 against the on-site eq. 23: the gauge slopes differ, so the digests do). The search's
    #: target ``V - slope Q`` then differs by a term linear in the charge, which the reference model's unpenalised
    #: linear and offset columns absorb: the same objective up to rounding (measured on tweezer_sim: the on-site
    #: search found g = 1.6243377313417883 nS against the thesis gauge's 1.6243377313454275 nS, a relative 2e-12, and
    #: the blocked-CV errors agree to 2e-14). ``compare_modes`` sets it for the selected model's other calibration mode
    leakage_search_any_gauge: bool = False
    #: the amplifier member's slew record of an earlier fit of the same trials (its ``amplifier_["slew"]``): taken over
    #: instead of searched again where the member is "auto" or the record applies a rate (a recalibration that changes
    #: another member: the lag member's, :meth:`_lag_link`); None: searched
    slew_reuse: Mapping | None = None

    # fitted
    hysteresis_: Any = field(default=None, init=False, repr=False)
    h_slope_: float = field(default=float("nan"), init=False)
    onsite_: dict = field(default_factory=dict, init=False)
    coef_: dict = field(default_factory=dict, init=False)
    ranges_: dict = field(default_factory=dict, init=False)
    fit_report_: dict = field(default_factory=dict, init=False)
    calibration_trials_: list = field(default_factory=list, init=False)
    leakage_s_: float = field(default=0.0, init=False)
    offset_drift_: bool = field(default=False, init=False)
    hold_evidence_: dict = field(default_factory=dict, init=False)
    #: the H(q) fitted beside the per-trial drift columns; the rest-segment drift estimate uses it (None: hysteresis_)
    drift_hysteresis_: Any = field(default=None, init=False, repr=False)
    #: the voltage link's amplifier member: the current limit found in the data and whether it is applied
    amplifier_: dict = field(default_factory=dict, init=False)
    #: the H(q) the current-limited voltage is rebuilt with (fitted where V is observed; None: not applied)
    voltage_hysteresis_: Any = field(default=None, init=False, repr=False)
    #: the charge link's absorption member: the R-C branch found on the free-tip laser and whether it is applied
    absorption_: dict = field(default_factory=dict, init=False)
    #: the charge link's quantiser member: the offset current an undithered shunt channel's short leaves, whether applied
    quantiser_: dict = field(default_factory=dict, init=False)
    #: the load link's stress member (:mod:`selfsense.chain.load`): V_H = H(q) + w f, whether applied and its weights
    stress_: dict = field(default_factory=dict, init=False)
    #: the load link's charge-free creep member (:mod:`selfsense.chain.creep`): the bank's lags and coefficients,
    #: whether applied
    tip_creep_: dict = field(default_factory=dict, init=False)
    #: the charge link's temperature member (:mod:`selfsense.chain.temperature`): the campaign's charge-scale slope,
    #: each trial's scale, whether applied
    temperature_: dict = field(default_factory=dict, init=False)
    #: the voltage link's lag member (:func:`selfsense.chain.amplifier.lag_column`): the lag tau [s], its blocked-CV
    #: evidence, whether applied
    amplifier_lag_: dict = field(default_factory=dict, init=False)

    # ------------------------------------------------------------------ fitting
    def _without_hold_map(self) -> tuple:
        """The configured H(q) candidates without the forms whose map is fitted to the hold rows (``hold_nfev``)."""
        return tuple(c for c in _candidates_for(self.config.h_model, self.config) if not _searches_holds(c))

    def selected_form(self) -> tuple:
        """The fitted H(q) form as a candidate list for a refit of this estimator's configuration on changed data
        or with a member toggled: ``(("linear", {}), (kind, params))`` -- the straight line the form must beat and
        the form the blocked CV selected -- or ``()`` (the whole selection again) when the configuration names no
        selection or the fit recorded none. ``compare_modes`` and the gap diagnostic's recalibrations pass it as
        ``h_candidates``."""
        if self.config.h_model != "auto":
            return ()
        chosen = next((r for r in (self.fit_report_ or {}).get("hysteresis", {}).get("selection") or []
                       if r.get("selected")), None)
        if chosen is None:
            return ()
        return (("linear", {}),) + (((chosen["kind"], dict(chosen["params"])),) if chosen["kind"] != "linear" else ())

    def _calibration_set(self, trials, meta):
        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        cal = meta[meta["role"] == "calibration"]
        missing = [t for t in cal.index if t not in trials]
        if missing:
            raise CalibrationError(f"calibration trials {missing} were not provided to fit()")
        return cal, {t: trials[t] for t in cal.index}

    def fit_hysteresis(self, trials: Mapping[str, pd.DataFrame], meta: pd.DataFrame) -> "SelfSensingEstimator":
        """Calibrate H(q) on the free-tip calibration trial (thesis eq. 55 or paper eq. 23).

        ``trials`` maps trial id -> prepared DataFrame (``selfsense.signals.prepare_trial``); ``meta`` is trials.csv
        indexed by trial id (or with a ``trial`` column). Only calibration trials are fitted on; every trial's
        V, Q and relay feed the reference-free hold evidence (:func:`selfsense.chain.charge.hold_evidence`).
        """
        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        self.amplifier_lag_ = {}   # decided after the coefficients (fit_coefficients); a refit starts without it
        cal = meta[meta["role"] == "calibration"]
        if cal.empty:
            raise CalibrationError("trials.csv: no trial with role 'calibration'; at least one is required")
        free = cal[cal["tip"] == "free"]
        if free.empty:
            raise CalibrationError("trials.csv: no calibration trial with tip 'free'; H(q) is calibrated on one")
        missing = [t for t in cal.index if t not in trials]
        if missing:
            raise CalibrationError(f"calibration trials {missing} were not provided to fit()")
        self.calibration_trials_ = list(cal.index)
        self.stress_ = {"applied": False, "note": "stress member not identified (H(q) identification is not joint)"}
        # the voltage link (V, Q, u_cmd and V_s of every trial, never a reference): where the amplifier sits at its
        # current limit the actuator voltage is rebuilt before anything reads V
        trials = self._voltage_link(trials, meta)
        # the charge link's quantiser member (V_s and the relay of the calibration trials, the reference-free channel
        # check, and their V-Q rows): where the shunt channel is not dithered, the offset current that the relay
        # short's code leaves is taken out of every trial's Q first (docs/method.md 1b')
        trials = self._quantiser_link(trials, meta)
        # the charge link's absorption member (calibration free-tip laser): the charge an absorption branch parks is
        # taken out of every trial's Q before anything reads it (hold evidence, H(q), coefficients)
        trials = self._absorption_link(trials, meta)
        # reference-free evidence of the charge link from EVERY trial given (V, Q and the relay only: no reference
        # of a validation trial is read), before any calibration-only transform
        from selfsense.chain.charge import hold_evidence

        # (the same V, Q and relay of every trial give the hold rows of the H(q) fit, _hold_set)
        self._all_trials = {t: df[["t", "V", "q", "relay"]] for t, df in trials.items() if t in meta.index}
        self.hold_evidence_ = hold_evidence(
            {t: df[[c for c in ("t", "V", "q", "relay", "V_s") if c in df]] for t, df in trials.items()
             if t in meta.index}, R=self._shunt_resistance()).to_dict()
        cal_trials = {t: trials[t] for t in cal.index}

        p = _rig_params(self.rig)
        n_A, C_p = p["n_A"], p["C_p"]
        cfg = self.config

        # --- H(q) on the free-tip calibration trial(s) (thesis eq. 55 / paper eq. 23)
        free_id = free.index[0]
        df_free = cal_trials[free_id]
        act = df_free["relay"].to_numpy() < 0.5
        slope = 1.0 / (n_A * C_p)
        if cfg.h_mode == "onsite":
            alpha = p["blocked_force"] / p["max_voltage"]  # catalog transformer ratio [N/V]
            B = p["dx_pzt_free"] / p["dx_tip_free"]  # paper eq. (20)
            dx = df_free["dx_ref"].to_numpy()
            ok = act & np.isfinite(dx)
            if ok.sum() < 10:
                raise CalibrationError(
                    f"trial {free_id!r}: the on-site calibration needs the free-tip displacement reference (dx_ref)"
                )
            q_act = df_free["q"].to_numpy()[ok] / n_A
            A_q = float(np.dot(q_act, dx[ok]) / np.dot(q_act, q_act))  # free tip: dx = A_q q (paper, before eq. 23)
            factor = 1.0 - alpha * B * A_q
            slope = factor / (n_A * C_p)
            self.onsite_ = {"alpha": alpha, "B": B, "A_q": A_q, "factor": factor}
        self.h_slope_ = float(slope)
        if cfg.h_identification == "joint":
            self.hysteresis_, rep = self._identify_h(cal_trials, cal, free, slope)
        else:
            if cfg.h_model == "ri":
                # RI model (third seed) + creep bank: linear in its parameters, fitted jointly on ALL free-tip
                # calibration trials (each from the relaxed state the relay establishes)
                from selfsense.sensing.hmodels import fit_ri_creep

                segs = []
                for tid in free.index:
                    d = cal_trials[tid]
                    d = d[d["relay"].to_numpy() < 0.5]
                    segs.append((d["q"].to_numpy(), h_target(d["V"].to_numpy(), d["q"].to_numpy(), slope)))
                t = df_free["t"].to_numpy()
                dt = float(np.median(np.diff(t)))
                n_creep = cfg.n_creep if cfg.n_creep != "auto" else auto_creep_count(dt * max(len(q) for q, _ in segs), dt)
                t0 = time.perf_counter()
                self.hysteresis_, rep = fit_ri_creep(segs, dt, n_thresholds=cfg.n_creep_thresholds,
                                                     n_creep=int(n_creep), creep=cfg.creep)
                Q, y = segs[0]
                pred = self.hysteresis_(Q)
                rng = float(np.ptp(y)) or 1.0
                rep.update({"rms_pct": float(np.sqrt(np.mean((pred - y) ** 2)) / rng * 100),
                            "max_pct": float(np.max(np.abs(pred - y)) / rng * 100),
                            "rms_v": float(np.sqrt(np.mean((pred - y) ** 2))), "n_creep": int(n_creep),
                            "h_model": "ri", "trials": list(free.index)})
                log.info("H(q) fit: RI + creep on %d free-tip trials, %.2f s, RMS %.3f %% of range on %s", len(segs),
                         time.perf_counter() - t0, rep["rms_pct"], free_id)
            else:
                df_fit = _decimate(df_free[act], cfg.max_fit_samples)
                t = df_fit["t"].to_numpy()
                dt = float(np.median(np.diff(t))) if len(t) > 1 else 1e-3
                Q = df_fit["q"].to_numpy()
                y = h_target(df_fit["V"].to_numpy(), Q, slope)
                self.hysteresis_, rep = _fit_thesis_modified_pi(cfg, Q, y, dt)
        rep["trial"] = free_id
        self._all_trials = None
        self.fit_report_ = {"hysteresis": rep, "warnings": list(rep.get("warnings", []))}
        self._fit_ranges(cal_trials, cal)
        return self

    # ------------------------------------------------------------------ H(q) identification
    def _h_segments(self, cal_trials, cal, slope, g_leak, drift_cols: bool | None = None,
                    stress_col: bool | None = None):
        """Calibration rows of the joint H(q) fit: every free-tip trial (V_p = slope Q in the eq. 55 gauge, f = 0)
        and every trial with a force reference (V_p shifted by f / B22: a column -f_ref), relay excluded.
        ``stress_col`` (default: the adopted stress member): the load link's stress columns ``H_0(q) f, Q f`` (0 on a
        free tip, :func:`selfsense.chain.load.stress_columns`; ``H_0`` the reference model :meth:`_stress_member`
        fitted on the free-tip rows) right after the force column."""
        from selfsense.chain.load import stress_columns

        if stress_col is None:
            stress_col = bool((self.stress_ or {}).get("applied"))
        qs, ys, ex, free, names, dts, raw = [], [], [], [], [], [], []
        for tid, row in cal.iterrows():
            if not (row["tip"] == "free" or row["reference"] == "force"):
                continue
            df = cal_trials[tid]
            m = df["relay"].to_numpy() < 0.5
            Q = self._charge(df, g_leak)[m]
            y = h_target(df["V"].to_numpy()[m], Q, slope)
            if row["reference"] == "force":
                f = df["f_ref"].to_numpy(dtype=float)[m]
                if not np.isfinite(f).all():
                    f = np.where(np.isfinite(f), f, 0.0)
            else:
                f = np.zeros(len(Q))
            if stress_col:
                h0 = (_eval_h(self._stress_h0, Q, _trial_dt(df)) if row["reference"] == "force"
                      else np.zeros(len(Q)))
                raw.append((f, stress_columns(h0, Q, f)))
            qs.append(Q); ys.append(y); ex.append(-f[:, None]); free.append(row["tip"] == "free"); names.append(tid)
            dts.append(_trial_dt(df))
        if stress_col:
            # the part of the stress columns along f itself is the two-port's own (linear in the load: the force
            # column's), so the columns are taken orthogonal to f over the loaded rows: w f = (s_H (H - a_H) +
            # s_Q (Q - a_Q)) f, with a = <column, f> / <f, f> (chain.load)
            F = np.concatenate([f for f, _ in raw])
            SC = np.vstack([c for _, c in raw])
            ff = float(F @ F)
            alpha = (SC.T @ F) / ff if ff > 0 else np.zeros(SC.shape[1])
            self._stress_alpha = alpha
            ex = [np.column_stack([e, c - f[:, None] * alpha]) for e, (f, c) in zip(ex, raw)]
        if self.offset_drift_ if drift_cols is None else drift_cols:
            # per-trial charge drift b t^2 (a linear in-amp offset drift) as free columns of the joint fit, so that it
            # does not bend H (a t term would be collinear with the leakage column g int V dt at a steady mean V);
            # every trial then gets its own drift from its rest segments (rest_drift)
            n = len(qs)
            for i, (q, tid) in enumerate(zip(qs, names)):
                df = cal_trials[tid]
                t = df["t"].to_numpy(dtype=float)[df["relay"].to_numpy() < 0.5]
                t = t - t[0]
                D = np.zeros((len(q), n))
                D[:, i] = t * t
                ex[i] = np.column_stack([ex[i], D])
        return qs, ys, ex, np.asarray(free, bool), names, float(np.median(dts))

    def _leakage(self, cal_trials, cal, slope, holds_fallback: bool = True) -> tuple[float, dict]:
        """Leakage conductance g [S] of the actuator set and whether to compensate offset drift, from the calibration
        trials: g in 0..50 nS (beyond, where the data reach that bound) is the value for which a reference Preisach
        model (12 x 12 grid + 6 plays + creep, with the per-trial drift columns) fits the joint calibration rows best
        on the corrected charge ``Q - g int V dt`` (bounded scalar search of the least-squares residual). Leakage is applied when the calibration rows support
        it (blocked-CV error not higher, a majority of the leave-one-block-out estimates within 50 %) or when the reference-free holds
        of every trial do (:func:`selfsense.chain.charge.hold_evidence`, then with the hold-estimated g, provided the
        calibration rows' blocked-CV error grows by at most 2 %; when both support it, the estimate with the lower
        calibration error). A calibration g more than 1.5x the conductance the holds measure (z >= 4 at >= 2 levels, even
        where a slow relaxation keeps the holds from supporting leakage on their own) is contradicted: the holds' g
        takes its place if the calibration rows' blocked-CV error is not higher with it than without leakage, else
        leakage is not applied. Where neither source supports leakage on its own, the calibration rows' g is applied
        when the conductance the holds measure agrees with it (:func:`leakage_corroborated`). The offset-drift columns are applied when they lower that error by more than 1 %. ``members``
        forces either on or off; forced on, a calibration g of at most 0.1 nS gives way to the conductance the holds
        measure (:func:`leakage_understated_by_holds`) unless ``holds_fallback`` is False (the selection's second look
        at the search's own g). Every decision and its numbers are reported (``fit_report_["hysteresis"]["drift"]``).
        """
        from scipy.optimize import minimize_scalar

        from selfsense.hysteresis.models.select import blocked_folds, cv_worker_count
        from selfsense.parallel import fork_map

        # the searches (all rows, then each leave-one-block-out) start at the same conductances (the bounded
        # search's first golden-section points do not depend on the rows left out) and the CVs revisit the found
        # ones: the calibration rows at g and the reference model's stacked rows at g are pure functions of g here
        # (the calibration inputs are fixed), kept in a bounded memo keyed by g's exact bits -- the same arrays as
        # built again, so the same numbers (measured on tweezer_sim: 94 objective evaluations at 29 distinct g)
        memo: OrderedDict = OrderedDict()

        def memoised(key, make):
            if key in memo:
                memo.move_to_end(key)
                return memo[key]
            memo[key] = val = make()
            while len(memo) > LEAK_MEMO_ENTRIES:
                memo.popitem(last=False)
            return val

        def rows(g, cols=False):
            def make():
                qs, ys, ex, free, names, dt = self._h_segments(cal_trials, cal, slope, g, drift_cols=cols)
                return qs, ys, ex, dt
            return memoised(("rows", float(g).hex(), bool(cols)), make)

        def insample(g, drop=None):
            r = rows(g, True)
            qs, ys, ex, dt = r
            design = memoised(("design", float(g).hex()), lambda: insample_design(_reference_h(), qs, ys, dt, ex))
            return _reference_insample(qs, ys, ex, dt, drop=drop, design=design)

        def cv(g, cols=False):
            return _reference_cv(*rows(g, cols))

        # the search runs over 0-50 nS; where it ends at that bound it continues up to the conductance whose charge
        # g int V dt would reach half of the largest calibration charge range (a bound from the data, not a prior)
        spans = []
        for tid in cal.index:
            d = cal_trials[tid]
            m = d["relay"].to_numpy() < 0.5
            iv = integral_v(d)[m]
            if len(iv):
                spans.append((float(np.ptp(d["q"].to_numpy()[m])), float(np.max(np.abs(iv)))))
        g_max = max([50e-9] + [0.5 * q / iv for q, iv in spans if iv > 0])

        def search(drop=None):
            res = minimize_scalar(lambda g: insample(g, drop), bounds=(0.0, 50e-9), method="bounded",
                                  options={"xatol": 0.05e-9})
            if res.x > 49e-9 and g_max > 50e-9:
                res = minimize_scalar(lambda g: insample(g, drop), bounds=(49e-9, g_max), method="bounded",
                                      options={"xatol": 0.05e-9})
            return float(res.x)

        modes = self._member_modes()
        ev = self.hold_evidence_ or {}
        # the search's numbers depend on the calibration inputs alone (a fixed reference model, not the configured
        # H(q)): an earlier search on the same inputs is reused. Forced modes skip what they do not read: "off"
        # the whole search, "on" the leave-one-block-out estimates (they only gate the calibration rows' support)
        key = _leakage_inputs_sha256(cal_trials, cal, slope)
        reuse = dict(self.leakage_search_reuse or {})
        same = reuse.get("inputs_sha256") == key
        if not same and reuse and self.leakage_search_any_gauge:
            p_ = _rig_params(self.rig)
            same = reuse.get("inputs_sha256") == _leakage_inputs_sha256(cal_trials, cal, 1.0 / (p_["n_A"] * p_["C_p"]))
        if same and (reuse.get("g_folds") is not None or modes["leakage"] != "auto") \
                and (reuse.get("g_cal") is not None or modes["leakage"] == "off"):
            g_cal, g_folds, base, best_cal = reuse["g_cal"], reuse["g_folds"], reuse["cv_without"], reuse["cv_with_g_cal"]
            reused = True
        else:
            # the searches (all rows, then each leave-one-block-out) and the error without leakage are independent
            # of each other: up to cv_worker_count() of them at a time in forked workers (the calibration job, whose
            # second core is otherwise idle here), one after the other elsewhere; the same bits either way
            n_rows = [len(q) for q in rows(0.0)[0]]
            tasks = ([("search", None)] if modes["leakage"] != "off" else []) + \
                ([("search", drop) for drop in blocked_folds(n_rows, 3)] if modes["leakage"] == "auto" else []) + \
                [("cv", None)]
            got = fork_map(lambda task: search(task[1]) if task[0] == "search" else cv(0.0, True), tasks,
                           cv_worker_count())
            g_cal = got.pop(0) if modes["leakage"] != "off" else None
            base = got.pop()
            g_folds = got if modes["leakage"] == "auto" else None
            best_cal = cv(g_cal, True) if g_cal is not None else None
            reused = False
        info = {"leakage_s_calibration": g_cal, "leakage_s_folds": g_folds, "cv_rms_v_without": base,
                "cv_rms_v_with_calibration_g": best_cal, "hold_evidence": ev, "leakage_mode": modes["leakage"],
                "offset_drift_mode": modes["offset_drift"],
                "search": {"inputs_sha256": key, "g_cal": g_cal, "g_folds": g_folds, "cv_without": base,
                           "cv_with_g_cal": best_cal, "reused": reused}}
        notes = []
        # supported by the calibration rows when it does not worsen their blocked CV and a majority of the
        # leave-one-block-out estimates agree within 50 %
        cal_ok = modes["leakage"] == "auto" and leakage_supported_by_calibration(g_cal, g_folds, best_cal, base)
        # the calibration rows' g must not exceed what the holds of every trial measure by more than 1.5x; where it
        # does, the holds' conductance takes its place, provided the calibration rows' blocked CV is not higher with
        # it than without leakage
        g_meas = leakage_measured_by_holds(ev)
        info["leakage_s_holds_measured"] = g_meas
        cal_label = "calibration"
        # where the holds measure no conductance, they still bound it: a calibration g far above everything they
        # leave possible has taken up more than leakage (auto only: a member forced on keeps its g)
        from selfsense.chain.charge import Z_SUPPORT, leakage_upper_bound

        g_ub = leakage_upper_bound(ev)
        info["leakage_s_holds_upper_bound"] = g_ub
        if modes["leakage"] == "auto" and g_meas is None and leakage_bounded_by_holds(g_cal, g_ub):
            info["leakage_calibration_contradicted"] = True
            notes.append(f"the calibration rows' g ({g_cal * 1e9:.3g} nS) exceeds {LEAK_HOLD_CONTRADICTION:g}x the "
                         f"largest conductance the holds of all trials leave possible ({g_ub * 1e9:.3g} nS: their "
                         f"estimate plus {Z_SUPPORT:g} standard errors, with and without a slow relaxation): the "
                         "calibration rows' g is not used")
            cal_ok = False
        if (cal_ok or modes["leakage"] == "on") and leakage_contradicted_by_holds(g_cal, g_meas):
            cv_meas = cv(g_meas, True)
            info.update({"leakage_calibration_contradicted": True, "cv_rms_v_with_holds_measured_g": cv_meas})
            takes = cv_meas <= LEAK_CAL_MAX_CV_RATIO * base or modes["leakage"] == "on"
            notes.append(f"the calibration rows' g ({g_cal * 1e9:.3g} nS) exceeds the {g_meas * 1e9:.3g} nS the holds "
                         f"of all trials measure by more than {LEAK_HOLD_CONTRADICTION:g}x: "
                         + ("the holds' g takes its place" if takes else
                            "the calibration rows' g is not used (their blocked-CV error is higher with the holds' g)"))
            if takes:
                g_cal, best_cal, cal_label = g_meas, cv_meas, "holds' measurement"
            else:
                cal_ok = False
        elif holds_fallback and modes["leakage"] == "on" and leakage_understated_by_holds(g_cal, g_meas):
            # forced on: the calibration rows that barely see leakage do not set it to next to nothing where the
            # holds of every trial measure it (not for the selection's second look at the search's own g in auto,
            # :meth:`_leakage_by_selection`, which forces the member on inside the fit: ``holds_fallback=False``)
            cv_meas = cv(g_meas, True)
            info.update({"leakage_calibration_understated": True, "cv_rms_v_with_holds_measured_g": cv_meas})
            notes.append(f"the calibration rows found no leakage ({g_cal * 1e9:.3g} nS) where the holds of all trials "
                         f"measure {g_meas * 1e9:.3g} nS: the holds' g takes its place (leakage forced on)")
            g_cal, best_cal, cal_label = g_meas, cv_meas, "holds' measurement"
        # supported by the holds of every trial (reference-free, selfsense.chain.charge.hold_evidence) when the
        # calibration rows are not made worse by more than 2 % with the hold-estimated conductance
        g_hold = float(ev.get("g_s") or 0.0)
        best_hold = cv(g_hold, True) if ev.get("supported") else float("inf")
        info["cv_rms_v_with_hold_g"] = best_hold if np.isfinite(best_hold) else None
        hold_ok = leakage_supported_by_holds(bool(ev.get("supported")), best_hold, base)
        g, best, source = 0.0, base, "none"
        corroborated = (modes["leakage"] == "auto" and not (hold_ok or cal_ok)
                        and leakage_corroborated(g_cal, g_meas, best_cal, base))
        info["leakage_corroborated"] = corroborated
        if modes["leakage"] == "off":
            notes.append("leakage compensation off (forced)")
        elif corroborated:
            g, best, source = g_cal, best_cal, "calibration and holds agree"
            notes.append(f"leakage supported by two independent measurements that agree: the calibration rows' "
                         f"{g_cal * 1e9:.3g} nS and the {g_meas * 1e9:.3g} nS the holds of all trials measure (within "
                         f"{LEAK_CORROBORATION:.0%}; blocked-CV error {best_cal:.4g} V against {base:.4g} V without): "
                         "the calibration rows' g applied")
        elif hold_ok or cal_ok or modes["leakage"] == "on":
            # the supported estimates (both when forced on) compete on the calibration rows' blocked CV
            cands = [(best_hold, 0, g_hold, "holds")] if (hold_ok or (modes["leakage"] == "on" and ev.get("supported"))) \
                else []
            if cal_ok or modes["leakage"] == "on":
                cands.append((best_cal, 1, g_cal, cal_label))
            best, _, g, source = min(cands)
        else:
            why = ["calibration rows: contradicted by the holds' measurement" if info.get(
                "leakage_calibration_contradicted") else "calibration rows: blocked-CV error not lower with g, or the "
                   "leave-one-block-out estimates of g disagree by > 50 %"]
            if ev.get("note"):
                why.append("holds of all trials: " + ev["note"])
            if ev.get("supported") and not hold_ok:
                why.append(f"the hold-estimated g makes the calibration rows' blocked-CV error worse by > 2 % "
                           f"({best_hold:.4g} V against {base:.4g} V)")
            notes.append("leakage compensation not supported (" + "; ".join(why) + "): not applied")
        info.update({"leakage_s": g, "applied": source != "none", "source": source, "cv_rms_v_with": best})
        if modes["leakage"] == "on" and source != "none":
            notes.append(f"leakage compensation forced on (g from the {source})")
        # in-amp offset drift: per-trial t^2 charge columns in the H fit, and each trial's own rest segments
        # (rest_drift) -- applied if the columns lower the calibration rows' blocked-CV error by more than 1 %. The
        # holds' per-trial offset rates (F test) are reported, not used: on virtual devices without any offset drift
        # the F test also fires on relaxation the hold regression does not model, and the rest-segment estimate then
        # takes that relaxation for drift (measured in docs/gap.md, "The charge link")
        without_cols = cv(g, False)
        info["offset_drift_cv_rms_v_without"] = without_cols
        cal_gain = offset_drift_supported(best, without_cols)
        applied = {"off": False, "on": True}.get(modes["offset_drift"], cal_gain)
        info["offset_drift_applied"] = bool(applied)
        info["offset_drift_source"] = ("forced" if modes["offset_drift"] != "auto" else
                                       "calibration" if cal_gain else "none")
        if not applied:
            notes.append("offset-drift compensation " + ("forced off" if modes["offset_drift"] == "off" else
                                                         "not supported (calibration blocked-CV gain < 1 %)")
                         + ": not applied")
        if notes:
            info["note"] = "; ".join(notes)
        return g, info

    def _member_modes(self) -> dict:
        """The chain members' modes (charge link: leakage, offset drift; H link: hold rows; voltage link: amplifier):
        the ``members`` forced values, else the configuration's (``SensingConfig.offset_drift``), "auto" where
        neither forces one."""
        return member_modes(self.members, {"offset_drift": getattr(self.config, "offset_drift", "auto"),
                                           "stress": getattr(self.config, "stress", "off"),
                                           "tip_creep": getattr(self.config, "tip_creep", "auto"),
                                           "temperature": getattr(self.config, "temperature", "off"),
                                           "amplifier_lag": getattr(self.config, "amplifier_lag", "auto")})

    def _identify_h(self, cal_trials, cal, free, slope):
        """H(q) of the configured ``h_model`` (``auto``: chosen by blocked CV among the registry's candidates),
        identified jointly on free-tip and force-reference calibration trials, after leakage compensation."""
        from selfsense.hysteresis.models.select import configured_envelope, select_h_model

        cfg = self.config
        t0 = time.perf_counter()
        self.leakage_s_ = 0.0
        drift_info = {"applied": False, "note": "drift compensation off (config drift: off)"}
        self.offset_drift_ = False
        self.drift_hysteresis_ = None
        # the charge link's search runs with drift: auto, or where one of its own members is forced (the other
        # members' modes -- a configured "off" of the stress member, say -- do not switch it on)
        if cfg.drift == "auto" or any(self._member_modes()[k] != "auto" for k in ("leakage", "offset_drift")):
            self.leakage_s_, drift_info = self._leakage(cal_trials, cal, slope)
            self.offset_drift_ = bool(drift_info["offset_drift_applied"])
        # the load link's stress member, decided on the reference model's blocked CV (_stress_member): where adopted,
        # its columns join the rows of the H(q) selection (identified jointly with H)
        self.stress_ = self._stress_member(cal_trials, cal, slope)
        qs, ys, ex, free_mask, names, dt = self._h_segments(cal_trials, cal, slope, self.leakage_s_)
        if not free_mask.any():
            raise CalibrationError("trials.csv: no calibration trial with tip 'free'; H(q) is calibrated on one")
        candidates = tuple(self.h_candidates) or _candidates_for(cfg.h_model, cfg)
        holds = self._hold_set(slope, drift_cols=self.offset_drift_)
        use_cv = self.h_selection_cv or not _held_linear_form(self.h_candidates)
        prune = self.h_selection_prune and cfg.h_model == "auto"   # (another h_model reads its kind's rows)
        sel = select_h_model(qs, ys, dt, extras=ex, free=free_mask, candidates=candidates,
                             n_blocks=int(cfg.cv_blocks), trial_names=names, holds=holds, cv=use_cv, prune=prune,
                             probes=self._h_probes(self.leakage_s_) if cfg.h_model == "auto" else None)
        model = sel.model
        if cfg.h_model not in ("auto",) and model.kind != cfg.h_model and cfg.h_model != "linear":
            from selfsense.hysteresis.models import make_model

            table = _force_only_selected(sel.table, cfg.h_model)
            chosen = next(r for r in table if r["selected"])
            if chosen["kind"] != cfg.h_model:   # every variant of the configured kind failed: said, not silent
                why = "; ".join(sorted({str(r.get("status")) for r in table if r["kind"] == cfg.h_model})) or \
                    "not among the candidates"
                sel.warnings.append(f"H(q) on calibration trials {names}: the configured h_model {cfg.h_model!r} "
                                    f"could not be fitted ({why}); {chosen['label']} is used instead")
                log.warning(sel.warnings[-1])
            model = make_model(chosen["kind"], **chosen["params"])
            i0 = int(np.flatnonzero(free_mask)[0])
            if chosen["kind"] == "modified_pi":
                model.fit(qs[i0], ys[i0], dt)
            elif isinstance(model, LinearParamH) or getattr(model, "joint_extra", False):
                model.fit(qs, ys, dt, extra=ex, holds=holds)
            else:
                model.fit(qs, ys, dt, extra=ex)
            sel.table = table
            lin = next(r for r in table if r["kind"] == "linear")
            if not chosen["cv_rms_mean_v"] < lin["cv_rms_mean_v"]:
                sel.warnings.append(f"H(q) on calibration trials {names}: the configured {chosen['label']} does not "
                                    f"beat a straight line out of sample ({chosen['cv_rms_mean_v']:.4g} V vs "
                                    f"{lin['cv_rms_mean_v']:.4g} V): expect poor force estimates")
                log.warning(sel.warnings[-1])
        if self.leakage_s_ and self._member_modes()["leakage"] == "auto" and not isinstance(model, LinearParamH) \
                and drift_info.get("source") == "calibration":
            # the leakage search's reference is a Preisach model (linear in its parameters); a selected H of another
            # class (the Duhem model) may fit the calibration rows better without the leakage that the reference took
            # up for its own misfit. The selected form's blocked CV decides: leakage is kept only when its error is not
            # higher with g than without; else the calibration is repeated without leakage. A g measured by the holds
            # of every trial (reference-free: V and Q only, no H model) is not the search's and is not re-checked
            check = self._leakage_check_with_selected(sel, cal_trials, cal, slope, dt)
            drift_info["selected_form_check"] = check
            if not check["kept"]:
                # without leakage, the offset-drift decision is made again on the rows without it (leakage forced
                # off: no search, the blocked CV with and without the drift columns at g = 0; the error without
                # leakage is taken from this fit's own search, same inputs)
                with self._inputs_overridden(members={**dict(self.members), "leakage": "off"},
                                             leakage_search_reuse=drift_info["search"]):
                    _, off = self._leakage(cal_trials, cal, slope)
                drift_info.update({"leakage_s": 0.0, "applied": False, "source": "none",
                                   "cv_rms_v_with": off["cv_rms_v_with"],
                                   **{k: off[k] for k in ("offset_drift_cv_rms_v_without", "offset_drift_applied",
                                                          "offset_drift_source")}})
                od_note = [x for x in off.get("note", "").split("; ") if x.startswith("offset-drift")]
                drift_info["note"] = "; ".join([check["note"]] + od_note)
                self.leakage_s_ = 0.0
                self.offset_drift_ = bool(off["offset_drift_applied"])
                qs, ys, ex, free_mask, names, dt = self._h_segments(cal_trials, cal, slope, 0.0)
                holds = self._hold_set(slope, drift_cols=self.offset_drift_)
                sel = select_h_model(qs, ys, dt, extras=ex, free=free_mask, candidates=candidates,
                                     n_blocks=int(cfg.cv_blocks), trial_names=names, holds=holds, prune=prune,
                                     probes=self._h_probes(0.0) if cfg.h_model == "auto" else None)
                model = sel.model
        elif (not self.leakage_s_ and LEAK_SELECTED_FORM_RATIO > 0 and cfg.h_model == "auto"
              and self._member_modes()["leakage"] == "auto" and drift_info.get("source") == "none"
              and (drift_info.get("leakage_s_calibration") or 0.0) > 0.0
              and not drift_info.get("leakage_calibration_contradicted")):
            # the reference model rejected the calibration rows' g: the selection itself decides (its candidates'
            # blocked CV with g against without), so that leakage is identified jointly with the H(q) form. A
            # recalibration that holds the form decides on the held form's CV, so it reproduces the decision
            sel0 = sel if use_cv else select_h_model(qs, ys, dt, extras=ex, free=free_mask, candidates=candidates,
                                                     n_blocks=int(cfg.cv_blocks), trial_names=names, holds=holds,
                                                     prune=prune, probes=self._h_probes(self.leakage_s_))
            got = self._leakage_by_selection(sel0, cal_trials, cal, slope, dt, candidates, drift_info)
            if got is not None:
                sel, qs, ys, ex, free_mask, names, holds = got
                model = sel.model
        if self.offset_drift_:
            model, qs, ys, ex, sel.extra_coef, drift_info["joint_refit"] = self._refit_on_drift_free_charge(
                model, sel, cal_trials, names, slope, dt, qs, ys, ex, holds)
        if cfg.h_model != "auto" and model.kind != "linear":
            # a kind the configuration names is not rejected by the major-loop check (docs/method.md 6b), but the user
            # is told where it leaves its own major loop on a trial's measured charge
            probes = self._h_probes(self.leakage_s_)
            if probes:
                env, warn = configured_envelope(model, qs, probes, dt, names)
                sel.envelope = [env]
                if warn:
                    sel.warnings.append(warn)
                    log.warning(warn)
        if self.stress_.get("applied") and len(sel.extra_coef) > 2:
            # s_H, s_Q: the stress columns' coefficients in the final joint fit (the columns right after -f_ref)
            self.stress_.update({"s_h_per_n": float(sel.extra_coef[1]), "s_q_v_per_c_n": float(sel.extra_coef[2]),
                                 "a_h_v": float(self._stress_alpha[0]), "a_q_c": float(self._stress_alpha[1])})
        elif self.stress_.get("applied"):
            self.stress_.update({"applied": False, "note": self.stress_["note"] + "; the selected H(q) form took no "
                                 "joint columns: not applied"})
        rms = []
        for q, y, e in zip(qs, ys, ex):
            pred = model.predict(q, dt)
            rms.append(float(np.sqrt(np.mean((pred - y + (e @ sel.extra_coef[:e.shape[1]] if
                                                           len(sel.extra_coef) else 0.0)) ** 2))))
        y0 = ys[int(np.flatnonzero(free_mask)[0])]
        rng = float(np.ptp(y0)) or 1.0
        rep = {"h_model": cfg.h_model, "selected": model.label(), "kind": model.kind,
               "trials": names, "selection": sel.table, "warnings": list(sel.warnings),
               "rms_v": float(np.sqrt(np.mean(np.square(rms)))), "rms_v_per_trial": dict(zip(names, rms)),
               "rms_pct": float(rms[int(np.flatnonzero(free_mask)[0])] / rng * 100), "dt_s": dt,
               "max_pct": float(np.max(np.abs(model.predict(qs[int(np.flatnonzero(free_mask)[0])], dt)
                                              - y0 + (ex[int(np.flatnonzero(free_mask)[0])] @ sel.extra_coef
                                                      if len(sel.extra_coef) else 0.0))) / rng * 100),
               "drift": drift_info, "stress": dict(self.stress_), "extra_coef": [float(c) for c in sel.extra_coef],
               "hold_rows": self._hold_rows_report(holds, model), "envelope": sel.envelope,
               "n_samples_fit": int(sum(len(q) for q in qs))}
        if not use_cv:
            rep["selection_cv"] = (f"held: {model.label()} refitted without blocked CV (h_selection_cv off; "
                                   "the held form is not compared with the straight line)")
        log.info("H(q): %s %s on %s (%.1f s), leakage %.3g S", model.label(),
                 "selected by blocked CV" if use_cv else "held (refitted without blocked CV)", names,
                 time.perf_counter() - t0, self.leakage_s_)
        return model, rep

    def _stress_member(self, cal_trials, cal, slope) -> dict:
        """The load link's stress member (:mod:`selfsense.chain.load`): ``V_H = H(q) + w f``, decided
        on the calibration rows (with the adopted leakage and offset-drift columns): the charge-link reference model
        (:func:`_reference_h`) fitted on the free-tip rows gives ``H_0``; the member is adopted when the columns
        ``H_0(q) f_ref, Q f_ref`` lower the reference model's blocked-CV error by more than
        :data:`~selfsense.chain.load.STRESS_MIN_GAIN` (``members`` forces it on or off). Needs a calibration trial with
        a force reference that carries a load."""
        from selfsense.chain.load import STRESS_MIN_GAIN

        mode = self._member_modes()["stress"]
        if mode == "off":
            forced = dict(self.members or {}).get("stress") == "off"
            return {"applied": False, "mode": mode, "source": "forced" if forced else "config",
                    "note": "stress member off (forced)" if forced else "stress member off (config stress: off, the "
                    "default: docs/method.md 6f)"}
        loaded = [t for t, r in cal.iterrows() if r["reference"] == "force"
                  and np.nanmax(np.abs(cal_trials[t]["f_ref"].to_numpy(dtype=float)), initial=0.0) > 0.0]
        if not loaded:
            return {"applied": False, "mode": mode, "source": "none",
                    "note": "no calibration trial with a loaded force reference: the stress member is not identifiable"}
        qs, ys, ex, free, _, dt = self._h_segments(cal_trials, cal, slope, self.leakage_s_,
                                                   drift_cols=self.offset_drift_, stress_col=False)
        # H_0 from the free-tip rows alone (no tip load: no stress), evaluated on the loaded trials' charge
        fi = np.flatnonzero(free)
        keep = np.flatnonzero(np.any(np.vstack([ex[i] for i in fi]) != 0.0, axis=0))  # their drift columns
        self._stress_h0 = _reference_h().fit([qs[i] for i in fi], [ys[i] for i in fi], dt,
                                             extra=[ex[i][:, keep] for i in fi] if len(keep) else None)
        cvs = [_reference_cv(qs, ys, ex, dt)]
        qs, ys, ex, _, _, dt = self._h_segments(cal_trials, cal, slope, self.leakage_s_,
                                                drift_cols=self.offset_drift_, stress_col=True)
        cvs.append(_reference_cv(qs, ys, ex, dt))
        gain = bool(cvs[1] < (1.0 - STRESS_MIN_GAIN) * cvs[0])
        applied = mode == "on" or gain
        note = (f"stress member {'forced on' if mode == 'on' else 'adopted' if gain else 'not supported'}: the columns "
                f"H_0(q) f_ref, Q f_ref of {loaded} give a blocked-CV error of {cvs[1]:.4g} V against {cvs[0]:.4g} V "
                "without"
                + ("" if applied else f" (a gain of at least {STRESS_MIN_GAIN:.0%} is needed)"))
        return {"applied": applied, "mode": mode, "source": "forced" if mode == "on" else
                ("calibration" if gain else "none"), "cv_rms_v_with": cvs[1], "cv_rms_v_without": cvs[0],
                "trials": loaded, "note": note}

    def _rows_at(self, cal_trials, cal, slope, g: float, drift_cols: bool):
        """The H(q) selection's rows with the charge corrected by leakage ``g``: the calibration segments
        (:meth:`_h_segments`) and the hold rows of every trial (:meth:`_hold_set`, read with ``g`` for the time of
        the call), ``(qs, ys, extras, free, names, holds)``."""
        qs, ys, ex, free, names, _ = self._h_segments(cal_trials, cal, slope, g, drift_cols=drift_cols)
        kept = self.leakage_s_
        self.leakage_s_ = g
        try:
            holds = self._hold_set(slope, drift_cols=drift_cols)
        finally:
            self.leakage_s_ = kept
        return qs, ys, ex, free, names, holds

    def _leakage_by_selection(self, sel, cal_trials, cal, slope, dt, candidates, drift_info):
        """The H(q) selection repeated with leakage on, which the leakage search's reference model rejected: the
        conductance and the offset-drift decision are those of ``leakage: on`` (:meth:`_leakage` forced on, reusing
        this fit's search), the candidates the same. Where its best candidate's blocked-CV error is below
        :data:`LEAK_SELECTED_FORM_RATIO` of the best without leakage, leakage is adopted with that selection: returns
        ``(sel, qs, ys, ex, free, names, holds)`` of it; else None. Either way the comparison is recorded in
        ``drift_info["selected_form_decision"]``."""
        from selfsense.hysteresis.models.select import select_h_model

        with self._inputs_overridden(members={**dict(self.members or {}), "leakage": "on"},
                                     leakage_search_reuse=drift_info.get("search")):
            g, on = self._leakage(cal_trials, cal, slope, holds_fallback=False)
        od = bool(on["offset_drift_applied"])
        cv_0 = float(next(r for r in sel.table if r["selected"])["cv_rms_mean_v"])
        decision = {"leakage_s": g, "source": on.get("source"), "offset_drift_applied": od,
                    "cv_rms_v_without": cv_0, "adopted": False}
        drift_info["selected_form_decision"] = decision
        if not g > 0.0:
            return None
        qs, ys, ex, free, names, holds = self._rows_at(cal_trials, cal, slope, g, od)
        sel_g = select_h_model(qs, ys, dt, extras=ex, free=free, candidates=candidates,
                               n_blocks=int(self.config.cv_blocks), trial_names=names, holds=holds,
                               prune=self.h_selection_prune, probes=self._h_probes(g))
        row = next(r for r in sel_g.table if r["selected"])
        cv_g = float(row["cv_rms_mean_v"])
        adopted = bool(np.isfinite(cv_g) and np.isfinite(cv_0) and cv_g < LEAK_SELECTED_FORM_RATIO * cv_0)
        decision.update({"cv_rms_v_with": cv_g, "form_with": row["label"], "adopted": adopted})
        if not adopted:
            return None
        self.leakage_s_, self.offset_drift_ = g, od
        drift_info.update({"leakage_s": g, "applied": True, "source": "H(q) selection",
                           "cv_rms_v_with": on.get("cv_rms_v_with"),
                           **{k: on[k] for k in ("offset_drift_cv_rms_v_without", "offset_drift_applied",
                                                 "offset_drift_source") if k in on}})
        drift_info["note"] = (f"leakage {g * 1e9:.3g} nS (from the {on.get('source')}), rejected by the search's "
                              f"reference model, adopted by the H(q) selection: its best candidate ({row['label']}) "
                              f"has a blocked-CV error of {cv_g:.4g} V with it against {cv_0:.4g} V without (ratio below "
                              f"{LEAK_SELECTED_FORM_RATIO:g})" + "".join(
                                  "; " + x for x in on.get("note", "").split("; ") if x.startswith("offset-drift")))
        return sel_g, qs, ys, ex, free, names, holds

    def _leakage_check_with_selected(self, sel, cal_trials, cal, slope, dt) -> dict:
        """Blocked-CV error of the selected H(q) form on the calibration rows with the adopted leakage and without it
        (the same folds, hold rows and extra columns as the selection; the charge and the H target change with g)."""
        from selfsense.hysteresis.models.select import select_h_model

        row = next(r for r in sel.table if r["selected"])
        form = tuple((r["kind"], r["params"]) for r in sel.table if r["kind"] == "linear") + ((row["kind"],
                                                                                              row["params"]),)
        g = self.leakage_s_
        qs0, ys0, ex0, free0, names0, holds0 = self._rows_at(cal_trials, cal, slope, 0.0, self.offset_drift_)
        sel0 = select_h_model(qs0, ys0, dt, extras=ex0, free=free0, candidates=form, n_blocks=int(self.config.cv_blocks),
                              trial_names=names0, holds=holds0)
        cv_g = float(row["cv_rms_mean_v"])
        cv_0 = float(next(r for r in sel0.table if r["label"] == row["label"])["cv_rms_mean_v"])
        kept = bool(cv_g <= cv_0)
        note = ("" if kept else
                f"leakage {g * 1e9:.3g} nS not kept: the selected {row['label']} (not of the leakage search's "
                f"reference class) has a lower blocked-CV error without it ({cv_0:.4g} V against {cv_g:.4g} V)")
        return {"form": row["label"], "cv_rms_v_with": cv_g, "cv_rms_v_without": cv_0, "leakage_s": g, "kept": kept,
                "note": note}

    def _h_probes(self, g: float) -> list | None:
        """The charge paths the H(q) selection's envelope check runs the selected model on
        (:func:`~selfsense.hysteresis.models.select.envelope_excursion`): every trial's charge, corrected by leakage
        ``g``, after the relay opens (``(trial, Q)`` pairs; reference-free: V and Q are logged in operation, and no
        reference of any trial is read). None where the trials are not at hand. The selection is given them with
        ``h_model: auto`` only: a kind the configuration names is the user's choice, not the selection's, and is only
        checked against them for a warning (:func:`~selfsense.hysteresis.models.select.configured_envelope`)."""
        return [(tid, self._charge(df, g)[m]) for tid, df, m in self._relay_open_trials()] or None

    def _relay_open_trials(self):
        """``(trial, prepared frame, relay-open mask)`` of every trial at hand (sorted by id) with at least 10 samples
        after the relay opens: the records the reference-free evidence of the holds and the major-loop check read."""
        trials = getattr(self, "_all_trials", None) or {}
        for tid in sorted(trials):
            m = trials[tid]["relay"].to_numpy() < 0.5
            if m.sum() >= 10:
                yield tid, trials[tid], m

    def _hold_set(self, slope: float, drift_free: bool = False, drift_cols: bool = False):
        """The reference-free hold rows of every trial (:mod:`selfsense.hysteresis.models.holds`): each trial's
        record after the relay opens, its H target ``V - slope Q`` on the leakage-corrected charge, and its holds
        (:func:`selfsense.chain.charge.find_holds`); None with ``hold_rows: off`` or where no trial holds.
        ``drift_free``: each trial's offset drift, estimated from its own rest segments with the current H
        (:meth:`rest_drift`), taken out of its charge first. ``drift_cols``: each trial's drift ramp ``t, t^2``
        (scaled by the gauge slope) as hold-only columns fitted jointly, so that the creep of H does not take up the
        drift while the member is being identified (the rest segments are holds too)."""
        from selfsense.chain.charge import find_holds
        from selfsense.hysteresis.models.holds import HoldSet

        if self.config.hold_rows == "off" or self._member_modes()["hold_rows"] == "off":
            return None
        hs = HoldSet(extras=[] if drift_cols else None)
        for tid, df, m in self._relay_open_trials():
            V = df["V"].to_numpy(dtype=float)[m]
            found = find_holds(df["t"].to_numpy(dtype=float)[m], V)
            if not found:
                continue
            Q = self._charge(df, self.leakage_s_)
            if drift_free:
                Q = Q - self.rest_drift(df, Q)[0]
            end = max(b for _, b in found)   # the operators run from the relaxed state up to the last hold's end
            Q = Q[m][:end]
            hs.qs.append(Q); hs.ys.append(h_target(V[:end], Q, slope)); hs.holds.append(found); hs.names.append(tid)
            if drift_cols:
                tt = df["t"].to_numpy(dtype=float)[m]
                tt = (tt - tt[0])[:end]
                hs.extras.append(slope * np.column_stack([tt, tt * tt]))
        return hs if hs else None

    def _hold_rows_report(self, holds, model) -> dict:
        if holds is None:
            why = ("off (config hold_rows: off)" if self.config.hold_rows == "off" else
                   "off (member forced off)" if self._member_modes()["hold_rows"] == "off" else "no hold in any trial")
            return {"applied": False, "note": why}
        fitted = isinstance(model, LinearParamH) or getattr(model, "joint_extra", False)
        return {**holds.summary(), "applied": True, "fitted": fitted,
                "note": (f"{holds.summary()['n_holds']} holds of {len(holds.names)} trials "
                         + ("fitted with the calibration rows and scored in the selection" if fitted else
                            "scored in the selection; the selected model does not take them in its fit"))}

    def _refit_on_drift_free_charge(self, model, sel, cal_trials, names, slope, dt, qs, ys, ex, holds=None):
        """H(q) and the offset drift identified jointly: the drift columns of the selection's fit stand in for the
        drift while H is chosen, but H still sees the drifting charge; here each calibration trial's drift is
        estimated from its rest segments with that H (:meth:`rest_drift`), taken out of its charge, and the selected
        model is refitted on the drift-free rows (without the drift columns). Models that are not linear in their
        parameters (the modified PI fitted on one trial, the non-convex Duhem model) keep their fit."""
        from selfsense.hysteresis.models import LinearParamH, make_model

        row = next((r for r in sel.table if r.get("selected")), None)
        if row is None or not isinstance(model, LinearParamH) or not getattr(model, "convex", True):
            # a non-convex fit (the Duhem model) started again on other rows can land elsewhere (measured: Bouc-Wen
            # devices went from 12 to 62 % displacement); it keeps the fit beside the drift columns
            return model, qs, ys, ex, sel.extra_coef, {"applied": False, "note": f"{model.kind}: not refitted"}
        n_tr = len(names)
        ex2 = [e[:, :e.shape[1] - n_tr] for e in ex]  # the per-trial drift columns are the last n_tr
        refit = model
        self.drift_hysteresis_ = model
        for _ in range(N_DRIFT_ALTERNATIONS):
            self.hysteresis_ = refit
            qs2, ys2, moved = [], [], {}
            for tid in names:
                df = cal_trials[tid]
                m = df["relay"].to_numpy() < 0.5
                Q = self._charge(df, self.leakage_s_)  # leakage only (g given: no drift correction yet)
                dQ, info = self.rest_drift(df, Q)
                Qc = (Q - dQ)[m]
                qs2.append(Qc)
                ys2.append(h_target(df["V"].to_numpy()[m], Qc, slope))
                moved[tid] = {"max_abs_c": float(np.max(np.abs(dQ))), "form": info.get("form", info.get("note", ""))}
            refit = make_model(row["kind"], **row["params"])
            refit.fit(qs2, ys2, dt, extra=ex2, holds=self._hold_set(slope, drift_free=True) if holds else None)
        self.hysteresis_ = None
        return refit, qs2, ys2, ex2, np.asarray(refit.extra_coef_, float), {
            "applied": True, "alternations": N_DRIFT_ALTERNATIONS, "drift": moved}

    def _charge(self, df: pd.DataFrame, g_leak: float | None = None, drift: bool = True) -> np.ndarray:
        """Measured charge corrected for the leakage conductance (``Q - g int V dt``) and, once H(q) is known and
        ``drift: auto``, for the in-amp offset drift estimated from the trial's own rest segments
        (:meth:`rest_drift`) [C]."""
        g = self.leakage_s_ if g_leak is None else g_leak
        Q = df["q"].to_numpy(dtype=float)
        if g:
            Q = Q - g * integral_v(df)
        if drift and self.offset_drift_ and self.hysteresis_ is not None and g_leak is None:
            dQ, _ = self.rest_drift(df, Q)
            Q = Q - dQ
        return Q

    def rest_drift(self, df: pd.DataFrame, Q: np.ndarray) -> tuple[np.ndarray, dict]:
        """Charge drift ``dQ(t)`` [C] (t since the relay opened) of one trial from its rest segments: ``a t + b t^2``
        (a thermal ramp of the in-amp offset) or, where the rest segments show it by blocked CV, an offset that
        wanders (:func:`selfsense.chain.charge.offset_bases`, :func:`~selfsense.chain.charge.select_offset_form`).

        At rest (|V| below 1 % of the trial's peak, at least 0.5 V, relay open) the tip is open and force-free, so the
        free-tip relation of the eq. (55) gauge, ``V - H(Q) = Q / (n_A C_p)``, must hold (thesis
        000_18d138f03f1777c3.txt eqs. 52, 55): its residual there is charge drift from the in-amp offset drift
        (0.3 mV over the shunt integrates to volts of V_p). Coefficients by two Gauss-Newton steps. Returns zeros and
        the reason when the rest samples are too few (< 0.3 s) or do not span 40 % of the trial."""
        V = df["V"].to_numpy(dtype=float)
        relay = df["relay"].to_numpy(dtype=float) >= 0.5
        t = df["t"].to_numpy(dtype=float)
        zero = np.zeros_like(Q)
        if relay.all() or len(t) < 10:
            return zero, {"applied": False, "note": "no relay-open samples"}
        i_open = int(np.argmax(~relay)) if relay.any() else 0
        tt = np.where(relay, 0.0, t - t[i_open])
        dt = _trial_dt(df)
        vmax = float(np.max(np.abs(V[~relay]))) if (~relay).any() else 0.0
        rest = (~relay) & (np.abs(V) < max(0.5, 0.01 * vmax))
        dur = float(tt.max()) or 1.0
        if not rest.any() or rest.sum() * dt < 0.3 or np.ptp(tt[rest]) < 0.4 * dur:
            return zero, {"applied": False, "note": "too little rest (|V| ~ 0) spread over the trial to estimate "
                                                    "the offset drift: not compensated"}
        from selfsense.chain.charge import offset_bases, select_offset_form

        slope = self.h_slope_
        # the H identified beside the drift columns (where drift and H are told apart), not the one refitted on the
        # drift-free charge (:meth:`_refit_on_drift_free_charge`): alternating the two lets H's creep bank and the
        # drift trade a slow trend between them (measured: b grew 2x over three alternations)
        h_drift = self.drift_hysteresis_ if self.drift_hysteresis_ is not None else self.hysteresis_

        def resid_of(B):
            def resid(c):
                Qc = Q - B @ c
                return (V - _eval_h(h_drift, Qc, dt) - slope * Qc)[rest]
            return resid

        # the form of the drift (selfsense.chain.charge): the thermal ramp a t + b t^2, or an offset that wanders,
        # chosen by blocked CV over the rest segments in the linearised problem (the residual's sensitivity to a
        # 10 nC charge shift at each rest sample)
        bases = offset_bases(tt, dur)
        open_ = (~relay).astype(float)
        r_0 = resid_of(open_[:, None])(np.zeros(1))
        sens = (resid_of(open_[:, None])(np.array([1e-8])) - r_0) / 1e-8
        runs = np.cumsum(np.diff(np.concatenate([[0], rest.astype(int)])) == 1)[rest]
        form, form_cv = select_offset_form(r_0, sens, {n: b[rest] for n, b in bases.items()}, runs)
        if form == "ramp":
            B = np.column_stack([tt, tt * tt])
            scale = np.array([1e-8 / max(dur, 1e-9), 1e-8 / max(dur, 1e-9) ** 2])  # ~10 nC perturbations
        else:
            B = np.where(relay[:, None], 0.0, bases[form])
            scale = np.full(B.shape[1], 1e-8)
        resid = resid_of(B)
        m = B.shape[1]
        c = np.zeros(m)
        for _ in range(2):
            r0 = resid(c)
            J = np.column_stack([(resid(c + scale[j] * np.eye(m)[j]) - r0) / scale[j] for j in range(m)])
            if form == "ramp":
                step, *_ = np.linalg.lstsq(J, -r0, rcond=None)
            else:  # the same light ridge as the form's selection
                A = np.vstack([J, 1e-3 * np.linalg.norm(J) / np.sqrt(m) * np.eye(m)])
                step, *_ = np.linalg.lstsq(A, np.concatenate([-r0, np.zeros(m)]), rcond=None)
            c = c + step
        dQ = np.where(relay, 0.0, B @ c)
        info = {"applied": True, "form": form, "form_cv_rms_v": form_cv, "max_abs_c": float(np.max(np.abs(dQ))),
                "rest_s": float(rest.sum() * dt)}
        if form == "ramp":
            info.update({"a_c_per_s": float(c[0]), "b_c_per_s2": float(c[1])})
        return dQ, info

    # ------------------------------------------------------------------ voltage link
    def _voltage_link(self, trials, meta):
        """The amplifier member of the voltage link (:mod:`selfsense.chain.amplifier`): the current limit from the
        shunt current of every trial (a reference-free plateau test) and, where that is not supported, the slew limit
        from the V-Q rows (:meth:`_slew_link`; every trial then reads the delivered command; forced on, the current
        limit is rebuilt where no slew rate is found). Where the current limit is supported (``members['amplifier']``
        "auto") or forced ("on"), the actuator voltage of the current-limited samples is rebuilt with ``V - H(q)``
        linear in the charge between the anchors (thesis eqs. 24-27: V_p is affine in q at a given load) and the
        reference H(q) of :meth:`_anchor_h`. Returns the trials to fit on."""
        from selfsense.chain.amplifier import identify_current_limit

        mode = self._member_modes()["amplifier"]
        if mode == "auto" and self.config.amplifier == "off":
            mode = "off"
        self.voltage_hysteresis_ = None
        self.amplifier_ = {"mode": mode, "applied": False}
        if mode == "off":
            self.amplifier_["note"] = ("amplifier member off (config amplifier: off or member forced off): "
                                       "V = amplifier_gain u_cmd - V_s (eq. 56)")
            return trials
        if any("V_s" not in df or "u_cmd" not in df for df in trials.values()):
            self.amplifier_["note"] = "no V_s / u_cmd columns: V as given"
            return trials
        try:
            R, gain = rig_value(self.rig, "shunt_resistance_ohm"), rig_value(self.rig, "amplifier_gain")
        except (KeyError, AttributeError, TypeError):
            self.amplifier_["note"] = "the rig gives no shunt resistance or amplifier gain: V as given"
            return trials
        every = {t: df for t, df in trials.items() if t in meta.index}
        lim = identify_current_limit(every, R, gain)
        self.amplifier_.update(lim.to_dict())
        if lim.supported:   # a current limit into the actuators' capacitance is a rate limit too: the rebuild's
            self.amplifier_["slew"] = {"applied": False, "note": "the current limit is supported: the rebuild on its "
                                                                 "plateau carries the amplifier, no slew search"}
        else:
            self._slew_link(trials, meta, mode, gain)
        if self.slew_rate() > 0:   # carried only where the current limit is not supported: no rebuild on top
            return {t: self._with_slew(df) for t, df in trials.items()}
        if not (lim.supported or (mode == "on" and lim.i_lim > 0)):
            return trials
        self.voltage_hysteresis_ = self._anchor_h(trials, meta, lim)
        self.amplifier_.update({"applied": True, "source": "forced" if mode == "on" else "current plateau"})
        return {t: self._with_voltage(df) for t, df in trials.items()}

    def _slew_link(self, trials, meta, mode, gain) -> None:
        """The slew part of the amplifier member (:func:`selfsense.chain.amplifier.identify_slew`): the slew rate for
        which the reference Preisach model (:func:`_reference_h`) fits the V-Q rows best, the rows being those of the
        joint calibration fit (the eq. 55 gauge, no leakage, no drift columns; a calibration trial's force reference
        is a column there) and of every other free-tip trial (``V - slope Q`` against ``Q``: V, Q and the relay only,
        no validation reference); supported where the rows' blocked-CV error (3 folds) falls to
        :data:`~selfsense.chain.amplifier.SLEW_CV_RATIO` of the error without it, forced ("on") wherever a rate was
        found; :attr:`slew_reuse` taken over instead where given. Sets ``amplifier_["slew"]``."""
        from selfsense.chain.amplifier import identify_slew

        info: dict = {"applied": False}
        self.amplifier_["slew"] = info
        reuse = dict(self.slew_reuse or {})
        if reuse and (mode == "auto" or reuse.get("applied")):
            info.update(reuse)
            info["reused"] = True
            return
        rows_meta = meta[((meta["role"] == "calibration") | ((meta["tip"] == "free") & (meta["reference"] != "force")))
                         & meta.index.isin(list(trials))]
        if not (rows_meta["tip"] == "free").any():
            info["note"] = "no free-tip trial: not assessed"
            return
        p = _rig_params(self.rig)
        slope = 1.0 / (p["n_A"] * p["C_p"])

        def rows(tr):
            qs, ys, ex, _, _, dt = self._h_segments(tr, rows_meta, slope, 0.0, drift_cols=False, stress_col=False)
            return qs, ys, ex, dt

        sub = {t: trials[t] for t in rows_meta.index}
        key = _slew_key(sub, rows_meta, gain, slope)
        ev = _SLEW_SEARCHES.get(key)
        if ev is None:   # a pure function of the rows: searched once per process for the same inputs
            ev = identify_slew(sub, gain, lambda tr: _reference_insample(*rows(tr)), lambda tr: _reference_cv(*rows(tr)))
            while len(_SLEW_SEARCHES) >= 8:
                _SLEW_SEARCHES.pop(next(iter(_SLEW_SEARCHES)))
            _SLEW_SEARCHES[key] = ev
        applied = bool(ev.supported or (mode == "on" and ev.rate_v_per_s > 0))
        info.update(ev.to_dict())
        info.update({"applied": applied, "source": ("forced" if applied and not ev.supported else
                                                    "V-Q rows" if applied else ""),
                     "note": ev.note + (": applied" if applied else "")})

    def _anchor_h(self, trials, meta, lim):
        """The reference H(q) of the voltage rebuild: a Preisach model (12 x 12 grid, 6 plays, creep) fitted on the
        joint calibration rows (:meth:`_h_segments`, the eq. 55 gauge) of the samples where V is observed, i.e. off
        the current plateau; the limited samples give no row, their charge still drives the operators. With the
        Preisach memory the reversal points the anchors sit on carry the Everett function between them. A linear
        term in q is a gauge of H and does not change the rebuild (V - H is interpolated linearly in q)."""
        from selfsense.chain.amplifier import limited_mask

        R = rig_value(self.rig, "shunt_resistance_ohm")
        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        cal = meta[meta["role"] == "calibration"]
        seen = {t: _with_column(trials[t], "V", np.where(limited_mask(trials[t], R, lim.i_lim, lim.band), np.nan,
                                                         trials[t]["V"].to_numpy(dtype=float))) for t in cal.index}
        p = _rig_params(self.rig)
        qs, ys, ex, _, _, dt = self._h_segments(seen, cal, 1.0 / (p["n_A"] * p["C_p"]), 0.0, drift_cols=False)
        model = _reference_h()
        model.fit(qs, ys, dt, extra=ex)
        self.amplifier_["h_rows"] = int(model.fit_report_.get("n_samples", 0))
        return model

    def _absorption_link(self, trials, meta):
        """The absorption member of the charge link (:func:`selfsense.chain.charge.fit_absorption`): a series R-C
        branch in parallel with the actuators (dielectric absorption) takes charge through the shunt that polarises
        nothing. Identified on the free-tip calibration trials' laser (the only references it reads); where it is
        supported (``members['absorption']`` "auto", config ``absorption: auto``) or forced ("on", with the best
        positive branch of the grid), every trial's charge becomes ``Q - c LP_tau(V)``. Returns the trials to fit on."""
        from selfsense.chain.charge import fit_absorption

        mode = self._member_modes()["absorption"]
        if mode == "auto" and self.config.absorption == "off":
            mode = "off"
        self.absorption_ = {"mode": mode, "applied": False}
        if mode == "off":
            self.absorption_["note"] = "absorption member off (config absorption: off or member forced off)"
            return trials
        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        free = [t for t, r in meta.iterrows() if r["role"] == "calibration" and r["tip"] == "free"
                and r["reference"] == "displacement" and t in trials]
        fit = fit_absorption({t: trials[t] for t in free})
        self.absorption_.update(fit.to_dict())
        if not (fit.supported or (mode == "on" and fit.c_f > 0)):
            self.absorption_["note"] = fit.note + ": not applied"
            return trials
        self.absorption_.update({"applied": True, "source": "forced" if mode == "on" else "free-tip laser",
                                 "note": fit.note + ": applied"})
        return {t: self._with_absorption(df) for t, df in trials.items()}

    def _quantiser_link(self, trials, meta):
        """The quantiser member of the charge link (docs/method.md 1b'): where the shunt channel is not dithered in
        any calibration trial (:func:`selfsense.chain.charge.charge_resolution`, reference-free), the relay short's
        code leaves an offset error ``e`` of up to half an ADC step, and every sample that reads another code carries
        the current ``e / R`` besides the actuator's (:func:`selfsense.chain.charge.quantiser_column`). The current is
        one for the device, bounded by half a step over R, and identified on the free-tip calibration trials' laser
        with the charge link's other slow paths beside it (:func:`selfsense.chain.charge.fit_quantiser`; no H(q) is
        involved, so a rate-dependent or misfitted H cannot take the column over). Adopted ("auto") when the blocked-CV
        RMS of those rows with the column is at most :data:`~selfsense.chain.charge.QUANTISER_CV_RATIO` of the RMS
        without it, the current lies inside its bound (:data:`~selfsense.chain.charge.QUANTISER_AT_BOUND`: an
        optimum at the bound means the rows want more than an offset rounding can give) and the CV folds agree on it
        (:data:`~selfsense.chain.charge.QUANTISER_FOLD_SPREAD`: the drive separates the column from a leakage or a
        drift); forced ("on") whenever the channel is undithered and the laser rows give a current (clipped to the
        bound). Returns the trials to fit on (every trial's Q corrected where adopted)."""
        from selfsense.chain.charge import (
            QUANTISER_AT_BOUND,
            QUANTISER_CV_RATIO,
            QUANTISER_FOLD_SPREAD,
            charge_resolution,
            fit_quantiser,
        )

        mode = self._member_modes()["quantiser"]
        if mode == "auto" and self.config.quantiser == "off":
            mode = "off"
        self.quantiser_ = {"mode": mode, "applied": False}
        if mode == "off":
            self.quantiser_["note"] = "quantiser member off (config quantiser: off or member forced off)"
            return trials
        R = self._shunt_resistance()
        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        cal = meta[meta["role"] == "calibration"]
        if R is None or not R > 0 or any("V_s" not in trials[t] for t in cal.index):
            self.quantiser_["note"] = "no V_s column or shunt resistance: not assessed"
            return trials
        res = [charge_resolution(trials[t], R)[0] for t in cal.index]
        steps = [r.step_v for r in res]
        if not all(x > 0 for x in steps) or max(steps) > min(steps) * (1 + 1e-6):
            self.quantiser_["note"] = ("the shunt channel is not quantised on one lattice in every calibration trial "
                                       "(a floating-point or resampled record): not applicable")
            return trials
        if any(r.dithered for r in res):
            self.quantiser_["note"] = ("the noise dithers the shunt channel's ADC step in a calibration trial: the "
                                       "short's mean is unbiased, not applied")
            return trials
        half = 0.5 * float(np.median(steps))
        bound = half / R
        free = [t for t in cal.index if cal.loc[t, "tip"] == "free" and cal.loc[t, "reference"] == "displacement"]
        fit = fit_quantiser({t: trials[t] for t in free}, half)
        self.quantiser_.update({"step_v": 2.0 * half, "current_step_a": 2.0 * bound, "half_step_v": half,
                                "identified_on": fit.trials, "n_rows": fit.n_rows})
        if not fit.trials or not np.isfinite(fit.cv_rms_m_with) or fit.i_q_a == 0.0:
            self.quantiser_["note"] = f"undithered shunt channel (ADC step {2 * bound * 1e9:.3g} nA): {fit.note}"
            return trials
        i_q = fit.i_q_a
        cv0, cv1 = fit.cv_rms_m_without, fit.cv_rms_m_with
        interior = abs(i_q) < QUANTISER_AT_BOUND * bound
        folds = np.asarray(fit.i_q_folds_a, float)
        spread = float(np.ptp(folds)) if folds.size and np.all(np.isfinite(folds)) else float("inf")
        separated = spread <= QUANTISER_FOLD_SPREAD * bound
        ok = bool(cv1 <= QUANTISER_CV_RATIO * cv0 and interior and separated)
        applied = ok or mode == "on"
        if applied and not interior:   # forced on: the current is still an offset rounding, within its bound
            i_q = float(np.clip(i_q, -bound, bound))
        self.quantiser_.update({"i_q_a": i_q, "i_q_folds_a": [float(x) for x in folds], "fold_spread_a": spread,
                                "cv_rms_m_without": cv0, "cv_rms_m_with": cv1, "supported": bool(ok),
                                "at_bound": not interior, "separated": bool(separated), "applied": bool(applied)})
        verdict = ("applied" if ok else "forced on" if applied else
                   f"not applied (the CV folds' currents spread over {spread / bound:.2g} of the bound, more than "
                   f"{QUANTISER_FOLD_SPREAD:g}: the drive does not separate the column from a leakage or a drift)"
                   if not separated else
                   "not applied (the current reaches its bound, half an ADC step over R: the rows ask for more "
                   "than an offset rounding can give, so the column stands in for another misfit)"
                   if not interior else
                   f"not applied (the blocked-CV RMS with the column is above {QUANTISER_CV_RATIO:g} x the RMS "
                   "without it)")
        self.quantiser_["note"] = (f"undithered shunt channel (ADC step {2 * bound * 1e9:.3g} nA): offset current "
                                   f"{fit.i_q_a * 1e9:.3g} nA on the samples off the short's code, free-tip laser "
                                   f"rows' blocked-CV RMS {cv0:.4g} -> {cv1:.4g} m: {verdict}")
        if not applied:
            return trials
        return {t: self._with_quantiser(df) for t, df in trials.items()}

    def _with_quantiser(self, df: pd.DataFrame) -> pd.DataFrame:
        """The trial with the quantiser member's offset current taken out of ``q`` (unchanged when not applied)."""
        if not self.quantiser_.get("applied"):
            return df
        if "V_s" not in df:
            raise ValueError("the model carries the quantiser member (an offset current on the samples whose shunt "
                             "voltage reads another ADC code than the relay short): the trial needs its V_s column")
        from selfsense.chain.charge import quantiser_column

        a = self.quantiser_
        return _with_column(df, "q", df["q"].to_numpy(dtype=float)
                            - float(a["i_q_a"]) * quantiser_column(df, float(a["half_step_v"])))

    def _with_absorption(self, df: pd.DataFrame) -> pd.DataFrame:
        """The trial with the charge of the absorption branch taken out of ``q`` (unchanged when not applied)."""
        if not self.absorption_.get("applied"):
            return df
        from selfsense.chain.charge import absorption_column

        a = self.absorption_
        col = absorption_column(df["V"].to_numpy(dtype=float), _trial_dt(df), float(a["tau_s"]))
        return _with_column(df, "q", df["q"].to_numpy(dtype=float) - float(a["c_f"]) * col)

    def _with_links(self, df: pd.DataFrame) -> pd.DataFrame:
        """The trial through the fitted voltage link (amplifier rebuild) and the charge link's absorption member."""
        return self._with_absorption(self._with_quantiser(self._with_voltage(df)))

    def _with_voltage(self, df: pd.DataFrame) -> pd.DataFrame:
        """The trial with its slew-limited and current-limited actuator voltage rebuilt (unchanged when the member is
        not applied)."""
        df = self._with_lag(self._with_slew(df))
        if not self.amplifier_.get("applied") or "V_s" not in df or "u_cmd" not in df:
            return df
        from selfsense.chain.amplifier import AmplifierLimit, rebuild_voltage

        lim = AmplifierLimit(**{k: self.amplifier_[k] for k in ("i_lim", "band", "fraction", "longest_run_s",
                                                                "lag", "supported", "note")})
        H0 = self.voltage_hysteresis_
        h_of = None if H0 is None else (lambda d: _eval_h(H0, d["q"].to_numpy(dtype=float), _trial_dt(d)))
        V = rebuild_voltage(df, rig_value(self.rig, "shunt_resistance_ohm"), rig_value(self.rig, "amplifier_gain"),
                            lim, h_of)
        return _with_column(df, "V", V)

    def _with_slew(self, df: pd.DataFrame) -> pd.DataFrame:
        """The trial with the delivered command and voltage of the amplifier member's slew limit
        (:func:`selfsense.chain.amplifier.with_slew`; unchanged when not applied)."""
        rate = self.slew_rate()
        if not rate > 0:
            return df
        if "u_cmd" not in df:
            raise ValueError("the model carries the amplifier member's slew limit (the actuator voltage behind a fast "
                             "command): the trial needs its u_cmd column")
        from selfsense.chain.amplifier import with_slew

        return with_slew(df, rig_value(self.rig, "amplifier_gain"), rate)

    def _start_member(self, name: str, default: str) -> dict:
        """The record of a member decided after the coefficients (``amplifier_lag``, ``temperature``): its mode (the
        forced one, else the configuration's, whose default is ``default``; "auto" with the configuration "off" is
        off), set as ``self.<name>_`` and ``fit_report_[name]`` before anything is decided."""
        mode = self._member_modes()[name]
        if mode == "auto" and getattr(self.config, name, default) == "off":
            mode = "off"
        info: dict = {"mode": mode, "applied": False}
        setattr(self, f"{name}_", info)
        self.fit_report_[name] = info
        return info

    def _take_fitted_state(self, est: "SelfSensingEstimator") -> None:
        """Every fitted attribute of ``est`` (a recalibration of this configuration on corrected signals) taken over
        by this estimator; what the caller gave (configuration, rig, members) stays."""
        for f in dataclasses.fields(self):
            if not f.init:
                setattr(self, f.name, getattr(est, f.name))

    def _with_lag(self, df: pd.DataFrame) -> pd.DataFrame:
        """The trial with the lag member's voltage ``V - tau gain du_cmd/dt`` (unchanged when not applied)."""
        lag = self.amplifier_lag_ or {}
        if not lag.get("applied"):
            return df
        if "u_cmd" not in df:
            raise ValueError("the model carries the amplifier lag member (the actuator voltage behind the command by "
                             "tau): the trial needs its u_cmd column")
        from selfsense.chain.amplifier import lag_column

        return _with_column(df, "V", df["V"].to_numpy(dtype=float)
                            - float(lag["tau_s"]) * lag_column(df, rig_value(self.rig, "amplifier_gain")))

    def _lag_link(self, trials, meta) -> bool:
        """The lag member of the voltage link (:func:`selfsense.chain.amplifier.lag_column`): ``tau`` identified
        jointly with H(q), as the coefficient of the column ``gain du_cmd/dt`` among the extra columns of the selected
        form's fit on the calibration rows (the rows of the fitted chain: leakage, offset drift, the other members);
        adopted ("auto") where the calibration separates the column from the hysteresis (at most
        :data:`~selfsense.chain.amplifier.LAG_MAX_R2` of it reproduced by the reference operator's design,
        :func:`~selfsense.chain.amplifier.lag_r2`; otherwise the blocked CV is not run), that column lowers the form's
        blocked-CV error (no hold rows, the same folds) by at least :data:`~selfsense.chain.amplifier.LAG_MIN_GAIN`
        and ``0 < tau <=`` :data:`~selfsense.chain.amplifier.LAG_MAX_S`; "on" wherever tau is in that range. Where adopted, the chain
        is calibrated again on every trial's ``V - tau gain du_cmd/dt`` (the selection the fit ran: the configured
        candidates with the blocked CV, or the caller's held form) and this estimator takes that state. Returns
        whether it was adopted."""
        from selfsense.chain.amplifier import LAG_MAX_R2, LAG_MAX_S, LAG_MIN_GAIN, lag_column, lag_r2
        from selfsense.hysteresis.models import fit_stride
        from selfsense.hysteresis.models.select import select_h_model, stacked_design

        info = self._start_member("amplifier_lag", "auto")
        mode = info["mode"]
        if mode == "off":
            info["note"] = "amplifier lag member off (config amplifier_lag: off or member forced off)"
            return False
        form = self.selected_form()
        try:
            gain = float(rig_value(self.rig, "amplifier_gain"))
        except (KeyError, AttributeError, TypeError):
            gain = float("nan")
        if not form or any("u_cmd" not in df for df in trials.values()) or not gain > 0:
            info["note"] = ("not assessed: " + ("no H(q) form selected by the blocked CV (h_model auto)" if not form
                                                else "no u_cmd column or amplifier gain"))
            return False
        try:
            meta_i = meta.set_index("trial") if "trial" in meta.columns else meta
            cal, _ = self._calibration_set(trials, meta_i)
            linked = {t: self._with_links(trials[t]) for t in cal.index}
            p = _rig_params(self.rig)
            slope = 1.0 / (p["n_A"] * p["C_p"])
            qs, ys, ex, free, names, _ = self._rows_at(linked, cal, slope, self.leakage_s_, self.offset_drift_)
            dt = float(np.median([_trial_dt(linked[n]) for n in names]))
            cols = [lag_column(linked[n], gain)[linked[n]["relay"].to_numpy() < 0.5] for n in names]
            ex1 = [np.column_stack([e, w]) for e, w in zip(ex, cols)]
            k = max(4, fit_stride([len(q) for q in qs]))
            r2 = lag_r2(stacked_design(_reference_h(), qs, ys, dt, ex, k)[0], np.concatenate([w[::k] for w in cols]))
            info["column_r2"] = r2
            if r2 > LAG_MAX_R2 and mode != "on":   # not separable: the blocked CV is not run
                info["note"] = (f"{r2 * 100:.1f} % of the lag column reproduced by a rate-independent operator on the "
                                f"calibration rows: not applied (the calibration does not separate a lag from the "
                                f"hysteresis, e.g. sines at one rate; a drive with holds or another rate would; needs "
                                f"<= {LAG_MAX_R2 * 100:g} %)")
                return False
            nb = int(self.config.cv_blocks)
            s0 = select_h_model(qs, ys, dt, extras=ex, free=free, candidates=form, n_blocks=nb, trial_names=names)
            s1 = select_h_model(qs, ys, dt, extras=ex1, free=free, candidates=form, n_blocks=nb, trial_names=names)
        except Exception as exc:   # noqa: BLE001 -- evidence that cannot be computed leaves the chain without the member
            info["note"] = f"amplifier lag member not assessed ({type(exc).__name__}: {exc})"
            self.fit_report_.setdefault("warnings", []).append(info["note"])
            return False
        r0 = next(r for r in s0.table if r["selected"])
        r1 = next(r for r in s1.table if r["selected"])
        cv0, cv1 = float(r0["cv_rms_mean_v"]), float(r1["cv_rms_mean_v"])
        tau = float(s1.extra_coef[-1]) if len(s1.extra_coef) == ex1[0].shape[1] else float("nan")
        gain_cv = 1.0 - cv1 / cv0 if cv0 > 0 else 0.0
        in_range = bool(np.isfinite(tau) and 0.0 < tau <= LAG_MAX_S)
        separable = bool(r2 <= LAG_MAX_R2)
        supported = bool(in_range and separable and gain_cv >= LAG_MIN_GAIN and r1["label"] == r0["label"])
        info.update({"tau_s": tau, "form": r1["label"], "cv_rms_v_without": cv0, "cv_rms_v_with": cv1,
                     "cv_gain": gain_cv, "column_r2": r2, "supported": supported})
        what = (f"lag column on {r1['label']}: tau {tau * 1e3:.3g} ms, blocked-CV error {cv0:.4g} -> {cv1:.4g} V "
                f"({gain_cv * 100:+.1f} %), {r2 * 100:.1f} % of the column reproduced by a rate-independent operator "
                f"on the calibration rows")
        if not (supported or (mode == "on" and in_range)):
            why = ("the calibration does not separate a lag from the hysteresis (sines at one rate: a drive with "
                   f"holds or another rate would; needs <= {LAG_MAX_R2 * 100:g} %)" if not separable else
                   f"needs 0 < tau <= {LAG_MAX_S * 1e3:g} ms and a gain of at least {LAG_MIN_GAIN * 100:g} %")
            info["note"] = what + f": not applied ({why})"
            return False
        # the lag of the delivered command (the amplifier member's slew limit, if carried, comes first, as in
        # _with_voltage); the recalibration takes this fit's slew limit over instead of searching it again
        slew = dict((self.amplifier_ or {}).get("slew") or {})
        corrected = {t: _with_column(df, "V", df["V"].to_numpy(dtype=float)
                                     - tau * lag_column(self._with_slew(df), gain)) for t, df in trials.items()}
        cands, cv = (self.h_candidates, True) if self.h_selection_cv else (form, False)
        est = type(self)(config=self.config, rig=self.rig,
                         members={**dict(self.members or {}), "amplifier_lag": "off"},
                         h_candidates=cands, h_selection_cv=cv, h_selection_prune=self.h_selection_prune,
                         leakage_search_any_gauge=self.leakage_search_any_gauge, slew_reuse=slew or None)
        try:
            est.fit(corrected, meta)
        except Exception as exc:   # noqa: BLE001 -- a failed recalibration leaves the chain without the member
            info["note"] = what + f": not applied, the recalibration failed ({type(exc).__name__}: {exc})"
            self.fit_report_.setdefault("warnings", []).append(info["note"])
            return False
        self._take_fitted_state(est)
        info.update({"applied": True, "source": "forced" if mode == "on" else "calibration rows",
                     "note": what + ": applied"})
        self.amplifier_lag_ = info
        self.fit_report_["amplifier_lag"] = info
        return True

    def _voltage_observed(self, df: pd.DataFrame) -> np.ndarray:
        """Samples whose V is observed (off the current plateau when the amplifier member is applied): the rows of the
        coefficient regression, so that the rebuild's error does not enter the coefficients."""
        if not self.amplifier_.get("applied") or "V_s" not in df:
            return np.ones(len(df), bool)
        from selfsense.chain.amplifier import limited_mask

        return ~limited_mask(df, rig_value(self.rig, "shunt_resistance_ohm"), self.amplifier_["i_lim"],
                             self.amplifier_["band"])

    def _h(self, Q: np.ndarray, df: pd.DataFrame) -> np.ndarray:
        return _eval_h(self.hysteresis_, Q, _trial_dt(df))

    def fit_coefficients(self, trials: Mapping[str, pd.DataFrame], meta: pd.DataFrame) -> "SelfSensingEstimator":
        """Regress the sensing coefficients (:meth:`_fit_coefficients`), then decide the voltage link's lag member
        (:meth:`_lag_link`) and the charge link's temperature member (:meth:`_temperature_link`); each calibrates the
        whole chain again on its corrected signals where it is adopted (the lag's recalibration decides the
        temperature member itself)."""
        self._fit_coefficients(trials, meta)
        if (self.amplifier_lag_ or {}).get("applied"):
            # H(q) shared from a chain calibrated on the lag-corrected voltage (fitted_copy): the lag stays with it
            return self._temperature_link(trials, meta)
        if self._lag_link(trials, meta):
            return self   # the chain calibrated again on the lag-corrected voltage (its own temperature link ran)
        return self._temperature_link(trials, meta)

    def _fit_coefficients(self, trials: Mapping[str, pd.DataFrame], meta: pd.DataFrame) -> "SelfSensingEstimator":
        """Regress the sensing coefficients (thesis eq. 52, or eq. 46 with ``regression='full'``) on calibration
        trials only, with H(q) already calibrated (:meth:`fit_hysteresis`). Where the creep member is carried beside
        an offset-drift member adopted by the H(q) fit, H(q) is calibrated again without the drift to decide it
        (docs/method.md 6h): the H(q) of the result can then differ from the one it started from."""
        if self.hysteresis_ is None:
            raise RuntimeError("fit_coefficients: calibrate H(q) first (fit_hysteresis)")
        cal, cal_trials = self._calibration_set(trials, meta)
        cal_trials = {t: self._with_links(df) for t, df in cal_trials.items()}
        p = _rig_params(self.rig)
        n_A, C_p = p["n_A"], p["C_p"]
        cfg = self.config
        # the load link's creep member (chain.creep): its bank columns beside [Q, V_p] (decided below)
        creep_mode = self._member_modes()["tip_creep"]
        self.tip_creep_ = {"mode": creep_mode, "applied": False}
        if not (cal["reference"] == "displacement").any() or not (cal["reference"] == "force").any():
            raise CalibrationError(
                "trials.csv: the A-coefficient regression needs at least one calibration trial with reference "
                "'displacement' and one with reference 'force' (thesis: free tip + laser, blocked tip + load cell)")
        # --- sensing coefficients, jointly over loading conditions
        from selfsense.chain.creep import identifiable_taus

        # the bank's lags that the calibration trials of the displacement rows can identify (chain.creep)
        taus = () if creep_mode == "off" else identifiable_taus(
            [len(df) * _trial_dt(df) for tid, df in cal_trials.items()
             if cal.loc[tid, "reference"] == "displacement" or cal.loc[tid, "tip"] == "blocked"])
        if creep_mode != "off":
            self.tip_creep_["taus_s"] = list(taus)
        rows = self._coefficient_rows(cal_trials, cal, taus)
        creep_on = self._tip_creep_decision(creep_mode, rows)
        if creep_on and not self.h_candidates and any(map(_searches_holds, self.selected_form())):
            # under a tip that creeps, the holds' charge is not H's (the creep moves charge through the coupling):
            # the H(q) form whose map was fitted to the hold rows (the joint hold search, docs/method.md 6b') is
            # not carried beside the creep member -- H(q) is calibrated again without those candidates and the
            # coefficients regressed on that chain (the second pass selects none of them: no loop)
            with self._inputs_overridden(h_candidates=self._without_hold_map(),
                                         leakage_search_reuse=leakage_search_of(self)):
                self.fit_hysteresis(trials, meta)
                self._fit_coefficients(trials, meta)
            self.fit_report_["hysteresis"]["hold_map"] = (
                "the H(q) form fitted jointly with the hold rows was selected first; H(q) calibrated again without "
                "the joint hold search beside the load link's creep member (its holds are not H's)")
            return self
        if creep_on and self.offset_drift_ and self._member_modes()["offset_drift"] == "auto":
            # creep and the offset-drift member both explain a slow mismatch of charge and strain, and the drift's
            # rest-segment estimate assumes the free-tip relation at rest, which creep breaks (a mechanism that loads
            # the actuator turns charge-free creep into charge at rest): where the creep member is carried, the
            # offset drift is decided again against the chain calibrated without it -- H(q) fitted again with the
            # member forced off (its per-trial drift columns had taken part of the misfit away from H), the sensing
            # regression on that chain -- and kept only if it lowers the displacement rows' blocked-CV error (with
            # the bank) by more than OFFSET_DRIFT_BESIDE_CREEP_GAIN (docs/method.md 6h). The force rows' blocked-CV
            # errors are recorded beside it: they do not tell the cases apart where keeping the drift helps from
            # those where it costs (benchmarks/gap_tip/drift_beside_creep.md), so they do not decide.
            from selfsense.chain.creep import OFFSET_DRIFT_BESIDE_CREEP_GAIN

            cv_od, f_od = self.tip_creep_["cv_rms_m_with"], self._force_rows_cv(rows, True)
            # the fitted state of the chain with the drift (the caller's rig, configuration and forced members are
            # the same objects on both sides, never copies)
            with_drift = self.fitted_copy().__dict__

            def restore():
                self.__dict__.clear()
                self.__dict__.update(with_drift)

            # the leakage search reads the calibration inputs only (its reference carries the drift columns either
            # way): this fit's search is reused; the chain it is decided against carries the creep member: no map
            # fitted to the holds (above) unless the caller gave the candidates
            refit_error = None
            with self._inputs_overridden(members={**dict(self.members or {}), "offset_drift": "off"},
                                         leakage_search_reuse=leakage_search_of(self),
                                         h_candidates=self.h_candidates or self._without_hold_map()):
                try:
                    self.fit_hysteresis(trials, meta)
                except Exception as exc:   # noqa: BLE001 -- any failure of the refit leaves the chain with the drift
                    refit_error = exc
            if refit_error is not None:
                restore()
                check = {"cv_rms_m_with_offset_drift": cv_od, "offset_drift_kept": True,
                         "h_refitted_without_offset_drift": False,
                         "note": "offset drift kept beside the creep member: H(q) could not be calibrated without it "
                                 f"({type(refit_error).__name__}: {refit_error})"}
                self.fit_report_.setdefault("warnings", []).append(check["note"])
            else:
                cal, alt_trials = self._calibration_set(trials, meta)
                alt_trials = {t: self._with_links(df) for t, df in alt_trials.items()}
                alt = self._coefficient_rows(alt_trials, cal, taus)
                self.tip_creep_ = {"mode": creep_mode, "applied": False, "taus_s": list(taus)}
                alt_on = self._tip_creep_decision(creep_mode, alt)
                # the error of the chain without the drift as it would be adopted: with the bank where its gate passes
                cv_no = self.tip_creep_["cv_rms_m_with" if alt_on else "cv_rms_m_without"]
                f_no = self._force_rows_cv(alt, alt_on)
                keep = bool(cv_od < (1.0 - OFFSET_DRIFT_BESIDE_CREEP_GAIN) * cv_no)
                check = {"cv_rms_m_with_offset_drift": cv_od, "cv_rms_m_without_offset_drift": cv_no,
                         "cv_rms_n_with_offset_drift": f_od, "cv_rms_n_without_offset_drift": f_no,
                         "offset_drift_kept": keep, "h_refitted_without_offset_drift": not keep,
                         "note": ("offset drift kept beside the creep member" if keep else
                                  "offset drift dropped and H(q) calibrated again without it: with the creep member "
                                  "it does not lower the displacement rows' blocked-CV error by more than "
                                  f"{OFFSET_DRIFT_BESIDE_CREEP_GAIN:.0%} against the chain calibrated without it")
                         + f" (displacement rows {cv_od:.3g} m with it, {cv_no:.3g} m without; force rows, not "
                           f"deciding, {f_od:.3g} N with it, {f_no:.3g} N without)"}
                if keep:
                    restore()
                else:
                    rows, creep_on, cal_trials = alt, alt_on, alt_trials
                    drift = self.fit_report_.setdefault("hysteresis", {}).setdefault("drift", {})
                    drift["offset_drift_applied"] = False
                    drift["offset_drift_source"] = "dropped beside the creep member"
                    drift["offset_drift_mode"] = "auto"
                    drift["note"] = "; ".join(
                        [x for x in str(drift.get("note", "")).split("; ") if x and not x.startswith("offset-drift")]
                        + ["offset-drift compensation adopted by the H(q) fit's gate, then dropped beside the creep "
                           "member: H(q) calibrated again without it (tip_creep.offset_drift_check)"])
            self.tip_creep_["offset_drift_check"] = check
        Xd, yd, Xf, yf, lengths_d, rest_ok, rest_info, base, Kd, Kf, _ = rows
        dx0 = 0.0
        cd = scaled_lstsq(np.column_stack([base, Kd]) if creep_on else base, yd)
        if creep_on:
            beta, cd = cd[base.shape[1]:], cd[:base.shape[1]]
            self.tip_creep_["beta"] = [float(b) for b in beta]
        if rest_ok:
            dx0, cd = float(cd[-1]), cd[:-1]
        # the creep signal K beta of the force rows (the same strain; one coefficient kappa, chain.creep)
        sf = Kf @ np.asarray(self.tip_creep_["beta"]) if creep_on else None
        regression = cfg.regression
        zf = force_regressor(Xf[:, 0], Xf[:, 1], n_A, C_p)
        Zf = zf[:, None] if sf is None else np.column_stack([zf, sf])
        if regression == "auto":
            # thesis mode: eq. (52) is exact for the force row in the eq. (55) convention (free-tip V_p is linear in
            # q); on-site mode: paper sec. IV-B regresses the four free terms (A1, A2, S2A1 + S3/n_A alpha, ...).
            regression = "approx" if cfg.h_mode == "thesis" else "full"
        self.fit_report_["regression_form"] = regression
        if regression == "approx":
            # f = (A3 / n_A) (Q - n_A C_p V_p)   (eq. 52): one physical coefficient A3
            cf = scaled_lstsq(Zf, yf)
            A3 = float(cf[0] * n_A)
            B21, B22 = force_coefficients(A3, n_A, C_p)
            self.coef_ = {"A1": float(cd[0]), "A2": float(cd[1]), "A3": A3, "B21": B21, "B22": B22}
        elif regression == "twoport":
            # f = (A3 / n_A) (Q - n_A C_p V_p) + S2 dx (eq. 46 = S3 x_pzt + S2 dx_tip), S2 >= 0 (a passive
            # tip port, eq. 8): the tip-stiffness column is the displacement row (A1 Q + A2 V_p) on the force rows
            dxf = tip_displacement(Xf[:, 0], Xf[:, 1], float(cd[0]), float(cd[1]))
            Tf = np.column_stack([zf, dxf] + ([] if sf is None else [sf]))
            lower = np.full(Tf.shape[1], -np.inf)
            lower[1] = 0.0
            cf = ridge_lstsq(Tf, yf, np.zeros(Tf.shape[1], bool), 0.0, lower=lower)   # bounded, column-scaled
            A3, S2 = float(cf[0] * n_A), float(cf[1])
            B21, B22 = force_row(float(cd[0]), float(cd[1]), A3, S2, n_A, C_p)
            self.coef_ = {"A1": float(cd[0]), "A2": float(cd[1]), "A3": A3, "B21": B21, "B22": B22, "S2": S2}
        else:
            cf = scaled_lstsq(Xf if sf is None else np.column_stack([Xf, sf]), yf)
            self.coef_ = {"A1": float(cd[0]), "A2": float(cd[1]), "B21": float(cf[0]), "B22": float(cf[1]),
                          "A3": float(cf[0] * n_A)}
        self.coef_["dx0"] = dx0
        if creep_on:
            self.tip_creep_["kappa"] = float(cf[-1])
            self.tip_creep_["applied"] = True
            Xd, Xf = np.column_stack([Xd, Kd]), np.column_stack([Xf, Kf])
        self.fit_report_["rest_offset"] = {**rest_info, "dx0_m": dx0}
        self.fit_report_["regression"] = {
            "n_displacement_equations": int(len(yd)),
            "n_force_equations": int(len(yf)),
            "rms_dx_m": float(np.sqrt(np.mean((self._predict_raw(Xd)[0] - yd) ** 2))),
            "rms_f_n": float(np.sqrt(np.mean((self._predict_raw(Xf)[1] - yf) ** 2))),
        }
        self.fit_report_["charge_resolution"] = self.charge_resolution(trials, meta)
        self.fit_report_["h_error_cost"] = self.h_error_cost()
        if any(self.stress_weights()):
            self._stress_load_ridge(cal_trials, cal)
        return self

    def _temperature_anchors(self, trials, meta) -> list[dict]:
        """The reference-free charge scale of every free- and blocked-tip trial (:func:`selfsense.chain.temperature.
        anchor_scale`): the scale of Q at which the output its tip state fixes (the force on a free tip, the
        displacement on a blocked one, eq. 52 before post-processing) is closest to zero over the released samples."""
        from selfsense.chain.temperature import anchor_scale, anchors_of

        out = []
        for k, t, tip in anchors_of(meta, trials):
            df = trials[t]
            rel = df["relay"].to_numpy() < 0.5
            q = df["q"].to_numpy(dtype=float)

            def cost(s, df=df, rel=rel, q=q, tip=tip):
                d = self._with_links(_with_column(df, "q", q / s))
                dx, f = self._predict_raw(self._regressors(d))
                r = (f if tip == "free" else dx)[rel]
                r = r[np.isfinite(r)]
                return float(np.mean(r * r)) if len(r) else 0.0

            s, gain = anchor_scale(cost)
            out.append({"k": int(k), "trial": t, "tip": tip, "s": float(s), "gain": float(gain)})
        return out

    def _temperature_refit(self, trials, meta, scales: Mapping[str, float],
                           hold_form: bool = False) -> tuple["SelfSensingEstimator", dict]:
        """The estimator of this configuration calibrated on the trials with their charges divided by ``scales``
        (the temperature member forced off inside), and those trials. ``hold_form``: the H(q) form this chain
        selected without the member (:meth:`selected_form`) is refitted without the blocked CV instead of selected
        again -- for the refit that only measures the anchors' residual trend (the whole selection there cost a third
        of the member's time and moved the slope by under 1 %); the refit whose state the member adopts runs the
        whole selection on the corrected charges (holding the form there too gave 4.71 % instead of 3.82 % on
        development case 50 of tip seed 20261214). A form a caller held for the chain without the member (``h_selection_cv``
        off: the gap diagnostic's recalibrations, ``compare_modes``) is a shortcut for that chain, not a choice for the
        corrected charges: the adopted refit then runs the configured selection (``h_candidates`` empty), as the
        pipeline's own fit with the member does."""
        corrected = {t: _with_column(df, "q", df["q"].to_numpy(dtype=float) / float(scales.get(t, 1.0)))
                     for t, df in trials.items()}
        form = self.selected_form() if hold_form else ()
        if form:                       # the trend refit: the form selected without the member, no CV
            cands, cv = form, False
        elif self.h_selection_cv:      # the configured (or the caller's) candidates, selected by the blocked CV
            cands, cv = self.h_candidates, True
        else:                          # a form the caller held for the chain without the member: the configured selection
            cands, cv = (), True
        est = type(self)(config=self.config, rig=self.rig,
                         members={**dict(self.members or {}), "temperature": "off"},
                         h_candidates=cands, h_selection_cv=cv,
                         h_selection_prune=self.h_selection_prune,
                         leakage_search_any_gauge=self.leakage_search_any_gauge,
                         slew_reuse=dict((self.amplifier_ or {}).get("slew") or {}) or None)
        return est.fit(corrected, meta), corrected

    def _temperature_link(self, trials, meta) -> "SelfSensingEstimator":
        """The temperature member of the charge link (:mod:`selfsense.chain.temperature`): the charge scale
        ``1 + b (k - k_c)`` of trial ``k`` of trials.csv, identified from the reference-free anchors of every free-
        and blocked-tip trial jointly with H(q) and the coefficients (the chain calibrated again on the corrected
        charges, a secant step on the anchors' residual trend, calibrated a third time there). ``auto`` adopts it
        where the first trend implies a scale change of at least
        :data:`~selfsense.chain.temperature.MIN_CAMPAIGN_CHANGE` over the campaign; "on" wherever the trend is
        identified. Where adopted, the fitted state is that of the chain calibrated on the corrected charges."""
        from selfsense.chain import temperature as tm

        info = self._start_member("temperature", "off")
        mode = info["mode"]
        if mode == "off":
            info["note"] = "temperature member off (config temperature: off or member forced off)"
            return self
        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        names = [str(t) for t in meta.index]
        k_c = tm.calibration_position(meta)
        try:
            anchors = self._temperature_anchors(trials, meta)
        except Exception as exc:   # noqa: BLE001 -- evidence that cannot be read leaves the chain without the member
            info["note"] = f"temperature member not applied: the anchors could not be read ({type(exc).__name__}: {exc})"
            self.fit_report_.setdefault("warnings", []).append(info["note"])
            return self
        b0, why = tm.anchor_trend(anchors, k_c)
        info.update({"k_c": k_c, "anchors_first": anchors, "slope_first_per_trial": b0})
        if b0 is None:
            info["note"] = f"temperature drift not identified: {why}"
            return self
        change = tm.campaign_change(b0, len(names))
        info["campaign_change_first"] = change
        if mode == "auto" and change < tm.MIN_CAMPAIGN_CHANGE:
            info["note"] = (f"charge-scale drift over the campaign {change:.2g} < {tm.MIN_CAMPAIGN_CHANGE:g} in the "
                            "free- and blocked-tip trials' reference-free relation: not applied")
            return self
        if b0 == 0.0:
            info["note"] = "no charge-scale trend in the anchors: not applied"
            return self
        try:
            est1, corr1 = self._temperature_refit(trials, meta, tm.campaign_scales(names, b0, k_c), hold_form=True)
            d1, _ = tm.anchor_trend(est1._temperature_anchors(corr1, meta), k_c)
            del est1, corr1   # memory: one recalibrated copy of the trials at a time
            b = tm.secant_slope(b0, b0, 0.0 if d1 is None else d1)
            scales = tm.campaign_scales(names, b, k_c)
            est, _ = self._temperature_refit(trials, meta, scales)
        except Exception as exc:   # noqa: BLE001 -- a failed recalibration leaves the chain without the member
            info["note"] = f"temperature member not applied: the recalibration failed ({type(exc).__name__}: {exc})"
            self.fit_report_.setdefault("warnings", []).append(info["note"])
            return self
        self._take_fitted_state(est)
        info.update({"applied": True, "source": "forced" if mode == "on" else "free- and blocked-tip anchors",
                     "residual_slope_per_trial": d1, "slope_per_trial": b,
                     "campaign_change": tm.campaign_change(b, len(names)), "scales": scales,
                     "note": f"charge scale drifting by {b:.3g} per trial of trials.csv: applied"})
        self.temperature_ = info
        self.fit_report_["temperature"] = info
        return self

    def _coefficient_rows(self, cal_trials, cal, taus) -> CoefficientRows:
        """The rows of the sensing-coefficient regression with the chain's current members (:class:`CoefficientRows`:
        ``[Q, V_p]`` and targets of the displacement rows (free-tip laser, the blocked tip's ``dx = 0``) and of the
        force rows (load cell, the free tip's ``f = 0``), the rows per segment, the rest-offset decision
        (:func:`_rest_offset`), the displacement rows' two-port columns (with the rest offset's where adopted) and the
        creep bank's columns of both (lags ``taus``, none where empty: :func:`selfsense.chain.creep.creep_columns`))."""
        from selfsense.chain.creep import creep_columns

        Xd, yd, Xf, yf = [], [], [], []
        for tid, row in cal.iterrows():
            df = cal_trials[tid]
            m = (df["relay"].to_numpy() < 0.5) & self._voltage_observed(df)
            # the calibration trial's load (stress member): its force reference, none on a free tip
            f_load = (np.nan_to_num(df["f_ref"].to_numpy(dtype=float)) if row["reference"] == "force" else
                      np.zeros(len(df)))
            feats = self._regressors(df, f_load)
            if len(taus):
                feats = np.column_stack([feats, creep_columns(feats[:, 0], feats[:, 1], _trial_dt(df), taus)])
            feats = feats[m]
            if row["reference"] == "displacement":
                ok = np.isfinite(df["dx_ref"].to_numpy()[m])
                Xd.append(feats[ok]); yd.append(df["dx_ref"].to_numpy()[m][ok])
            if row["tip"] == "blocked":
                Xd.append(feats); yd.append(np.zeros(len(feats)))
            if row["reference"] == "force":
                ok = np.isfinite(df["f_ref"].to_numpy()[m])
                Xf.append(feats[ok]); yf.append(df["f_ref"].to_numpy()[m][ok])
            if row["tip"] == "free":
                Xf.append(feats); yf.append(np.zeros(len(feats)))
        lengths_d, lengths_f = [len(v) for v in yd], [len(v) for v in yf]
        Xd, yd = np.vstack(Xd), np.concatenate(yd)
        Xf, yf = np.vstack(Xf), np.concatenate(yf)
        Kd, Xd = Xd[:, 2:], Xd[:, :2]
        Kf, Xf = Xf[:, 2:], Xf[:, :2]
        rest_ok, rest_info = (_rest_offset(Xd, yd, lengths_d) if self.config.rest_offset == "auto"
                              else (False, {"applied": False, "note": "rest offset off (config rest_offset: off)"}))
        base = np.column_stack([Xd, np.ones(len(Xd))]) if rest_ok else Xd
        return CoefficientRows(Xd, yd, Xf, yf, lengths_d, rest_ok, rest_info, base, Kd, Kf, lengths_f)

    def _row_folds(self, lengths) -> list:
        """The blocked folds of the coefficient rows' CV (:meth:`_tip_creep_decision`, :meth:`_force_rows_cv`):
        ``cv_blocks`` (at least 2) contiguous blocks per segment, not rotated (:func:`_rest_offset` folds the same
        way, with 5 blocks)."""
        from selfsense.hysteresis.models.select import blocked_folds

        return blocked_folds(lengths, max(int(self.config.cv_blocks), 2), rotate=False)

    def _force_rows_cv(self, rows: CoefficientRows, creep_on: bool) -> float:
        """Blocked-CV RMS [N] of the force rows of :meth:`_coefficient_rows` regressed on ``[Q, V_p]`` (thesis eq. 46)
        and, where the creep member is carried, its creep signal ``K beta`` (``beta`` fitted on the displacement
        rows): the force side of the offset-drift re-decision beside the creep member (:meth:`fit_coefficients`)."""
        A = rows.Xf
        if creep_on:
            beta = scaled_lstsq(np.column_stack([rows.base, rows.Kd]), rows.yd)[rows.base.shape[1]:]
            A = np.column_stack([rows.Xf, rows.Kf @ beta])
        return _blocked_cv_rms(A, rows.yf, self._row_folds(rows.lengths_f))

    def _tip_creep_decision(self, mode: str, rows: CoefficientRows) -> bool:
        """Whether the creep member (:mod:`selfsense.chain.creep`) is carried: forced ("on" / "off"), or where its
        bank lowers the blocked-CV RMS of the displacement rows (:meth:`_coefficient_rows`: the two-port's columns,
        with the rest offset where adopted) by more than :data:`~selfsense.chain.creep.CREEP_MIN_GAIN`; folds as
        :func:`_rest_offset`. The numbers and the decision go to :attr:`tip_creep_`."""
        from selfsense.chain.creep import CREEP_MIN_GAIN, creep_supported

        y, base, K = rows.yd, rows.base, rows.Kd
        info = self.tip_creep_
        if mode == "off":
            info["note"] = "creep member off (config tip_creep: off or member forced off)"
            return False
        if not K.shape[1]:
            info.update({"supported": False, "source": "none"})
            info["note"] = (("creep member forced on but not carried" if mode == "on" else "creep member not carried")
                            + ": no lag of the bank is identifiable from the calibration trials (every lag is longer "
                            "than three times the longest of them; chain.creep.identifiable_taus)")
            if mode == "on":
                self.fit_report_.setdefault("warnings", []).append(info["note"])
            return False
        held = self._row_folds(rows.lengths_d)
        without, with_ = _blocked_cv_rms(base, y, held), _blocked_cv_rms(np.column_stack([base, K]), y, held)
        supported = creep_supported(with_, without)
        on = mode == "on" or supported
        info.update({"cv_rms_m_without": without, "cv_rms_m_with": with_,
                     "min_gain": CREEP_MIN_GAIN, "supported": supported,
                     "source": "forced" if mode == "on" else ("calibration" if supported else "none")})
        info["note"] = (("creep member forced on" if mode == "on" else
                         "creep member applied" if supported else
                         "creep member not supported by the calibration trials")
                        + f" (blocked-CV RMS of the displacement rows {with_:.3g} m with the bank, {without:.3g} m "
                        f"without; adopted below {1.0 - CREEP_MIN_GAIN:.2f} of it)")
        return on

    def _stress_load_ridge(self, cal_trials, cal) -> None:
        """The ridge of the stress member's load solve (:func:`selfsense.chain.load.choose_load_ridge`), chosen on the
        calibration trials whose load is known (free tip: 0; force reference: its load) with the fitted
        coefficients; recorded in :attr:`stress_` with the scores of the grid."""
        from selfsense.chain.load import LOAD_RIDGE_GRID, choose_load_ridge, stress_weight

        s_h, s_q = self.stress_weights()
        c = self.coef_
        rows = []
        for tid, row in cal.iterrows():
            if not (row["tip"] == "free" or row["reference"] == "force"):
                continue
            df = cal_trials[tid]
            m = df["relay"].to_numpy() < 0.5
            Q, H, Vp0 = self._charge_h_vp(df)
            w = stress_weight(H, Q, s_h, s_q, *self.stress_offsets())
            fk = (np.nan_to_num(df["f_ref"].to_numpy(dtype=float)) if row["reference"] == "force"
                  else np.zeros(len(df)))
            rows.append(((c["B21"] * Q + c["B22"] * Vp0)[m], (1.0 + c["B22"] * w)[m], fk[m]))
        ridge, scores = choose_load_ridge(rows, *self.ranges_["f"])
        self.stress_.update({"load_ridge": ridge, "load_ridge_grid": list(LOAD_RIDGE_GRID),
                             "load_ridge_scores": scores})

    def h_error_cost(self) -> dict:
        """What the error of H(q) costs the tip estimates, from the calibration alone: ``V_p = V - H(q)`` (thesis
        eq. 27) enters eq. (52) through A2 and B22, so an error ``e`` of H moves the displacement by ``A2 e`` and the
        force by ``B22 e``. ``e`` is the selected H(q) model's blocked-CV RMS on the calibration trials (out of
        sample; the in-sample RMS where the form was held without CV). Reported in % of the calibration references'
        ranges (the scale of Table 3): where it is large, the load moves V_p little against what H(q) misses (a weakly
        coupled device), and the tip estimates are unlikely to be better than this on drives like the calibration's;
        drives the calibration never saw (holds, minor loops) add the H(q) model's extrapolation error. Not a bound:
        where H(q)'s error is systematic, the regression of the sensing coefficients takes part of it up."""
        rep = self.fit_report_.get("hysteresis", {})
        row = next((r for r in rep.get("selection", []) if r.get("selected")), None)
        cv = float(row["cv_rms_mean_v"]) if row is not None and row.get("cv_rms_mean_v") is not None else float("nan")
        e, source = (cv, "blocked CV") if np.isfinite(cv) else (float(rep.get("rms_v", float("nan"))), "in sample")
        if not np.isfinite(e):   # (JSON artefacts hold no NaN)
            return {"h_error_v": None, "source": None, "dx_pct": None, "f_pct": None,
                    "note": "no H(q) error on record: not assessed"}
        spans = self._calibration_spans()
        pct = {}
        for key, coef, span in (("dx_pct", "A2", spans["dx"]), ("f_pct", "B22", spans["f"])):
            c = abs(float(self.coef_.get(coef, 0.0)))
            pct[key] = float(c * e / span * 100.0) if span > 0 else 0.0
        note = (f"H(q) misses {e:.3g} V RMS ({source}, calibration trials); through A2 and B22 (thesis eq. 52) that "
                f"moves the tip estimates by {pct['dx_pct']:.3g} % of the displacement range and {pct['f_pct']:.3g} % "
                f"of the force range on drives like the calibration's (compare Table 3)")
        return {"h_error_v": e, "source": source, **pct, "note": note}

    def _calibration_spans(self) -> dict:
        """The calibration references' ranges ``{"dx": [m], "f": [N]}`` (from :attr:`ranges_`): the scale of Table 3
        for the costs the fit report states in % of range."""
        return {"dx": float(np.ptp(self.ranges_.get("dx", [0.0, 0.0]))),
                "f": float(np.ptp(self.ranges_.get("f", [0.0, 0.0])))}

    def _shunt_resistance(self) -> float | None:
        """The rig's shunt resistance [ohm], or None where the rig gives none (the charge resolution is then not
        assessed)."""
        try:
            return rig_value(self.rig, "shunt_resistance_ohm")
        except (KeyError, AttributeError, TypeError):
            return None

    def charge_resolution(self, trials: Mapping[str, pd.DataFrame], meta: pd.DataFrame) -> dict:
        """What the quantisation of the shunt channel costs the tip estimates, per trial and in summary
        (:func:`selfsense.chain.charge.charge_resolution`): where the noise does not dither the ADC step, the charge
        of the relay short and of the holds is off by up to half a step times their duration. The estimate is run
        once more with the charge moved by one SD of that error; the mean change of the raw tip estimates is
        reported in % of the calibration references' ranges (the scale of Table 3). Only V_s, V and the relay of each
        trial are read, no reference; nothing is fitted from it."""
        from selfsense.chain.charge import charge_resolution

        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        R = self._shunt_resistance()
        if R is None:
            return {"trials": {}, "limited": False, "validation_dx_pct": 0.0, "validation_f_pct": 0.0,
                    "calibration_h_target_v": 0.0, "note": "the rig gives no shunt resistance: not assessed"}
        spans = self._calibration_spans()
        per = {}
        for tid in meta.index:
            if tid not in trials:
                continue
            df = trials[tid]
            res, sig = charge_resolution(df, R)
            d = res.to_dict()
            d["dx_pct"] = d["f_pct"] = 0.0
            if not res.dithered and np.any(sig > 0):
                base = self.estimate(df)
                moved = self.estimate(_with_column(df, "q", df["q"].to_numpy(dtype=float) + sig))
                m = df["relay"].to_numpy() < 0.5
                for key, col in (("dx_pct", "dx_raw"), ("f_pct", "f_raw")):
                    span = spans["dx" if key == "dx_pct" else "f"]
                    diff = np.abs(moved[col].to_numpy() - base[col].to_numpy())[m]
                    d[key] = float(np.mean(diff) / span * 100.0) if span > 0 and diff.size else 0.0
            per[str(tid)] = d
        limited = {t: d for t, d in per.items() if not d["dithered"] and d["current_step_a"] > 0}
        if not per:
            note = "no trial"
        elif not limited:
            note = "the shunt channel resolves the charge in every trial (its noise dithers the ADC step)"
        else:
            worst = max(limited, key=lambda t: limited[t]["dx_pct"] + limited[t]["f_pct"])
            w = limited[worst]
            note = (f"one ADC step of the shunt channel is {w['current_step_a'] * 1e9:.3g} nA and its noise is "
                    f"{'below half a step' if w['relay_noise_steps'] is None else format(w['relay_noise_steps'], '.2f') + ' step'}"
                    f" where the current is constant: the quantiser is not dithered in {len(limited)} of {len(per)} "
                    f"trials, and the charge of the relay short and the holds is off by up to half a step times their "
                    f"duration. Worst trial {worst}: {w['sigma_q_end_c'] * 1e6:.3g} uC (1 SD) by its end; moving its charge "
                    f"by that much moves the tip estimates by {w['dx_pct']:.3g} % of the displacement range and "
                    f"{w['f_pct']:.3g} % of the force range. A larger shunt resistance or in-amp gain, a finer ADC or "
                    f"an added dither resolves it"
                    + ("" if (self.quantiser_ or {}).get("applied") else
                       "; calibration: quantiser: auto takes out the offset current the short's code leaves "
                       "(docs/method.md 1b'; off by default)"))
        roles = meta["role"] if "role" in meta else pd.Series(dtype=str)
        val = [t for t in per if str(roles.get(t, "")) == "validation"]
        cal = [t for t in per if str(roles.get(t, "")) == "calibration"]
        mean = (lambda k, ts: float(np.mean([per[t][k] for t in ts])) if ts else 0.0)
        slope = float(getattr(self, "h_slope_", 0.0))
        slope = slope if np.isfinite(slope) else 0.0
        h_target_v = abs(slope) * float(np.sqrt(np.mean([per[t]["sigma_q_rms_c"] ** 2 for t in cal]))) if cal else 0.0
        if limited and cal:
            note += (f". On the calibration trials the charge error is {h_target_v:.3g} V of the H(q) target "
                     f"V - Q / (n_A C_p) (1 SD, RMS): H(q) is calibrated on charge that this channel does not resolve")
        return {"trials": per, "limited": bool(limited), "validation_dx_pct": mean("dx_pct", val),
                "validation_f_pct": mean("f_pct", val), "calibration_h_target_v": h_target_v, "note": note}

    def fit(self, trials: Mapping[str, pd.DataFrame], meta: pd.DataFrame) -> "SelfSensingEstimator":
        """Calibrate H(q) then regress the sensing coefficients, on calibration trials only."""
        return self.fit_hysteresis(trials, meta).fit_coefficients(trials, meta)

    def _fit_ranges(self, cal_trials, cal) -> None:
        p = _rig_params(self.rig)
        # --- physical ranges for limiting (thesis sec. 5.2): from the calibration references
        dx_all = np.concatenate([cal_trials[t]["dx_ref"].to_numpy() for t in cal.index])
        f_all = np.concatenate([cal_trials[t]["f_ref"].to_numpy() for t in cal.index])
        dx_max = float(np.nanmax(dx_all)) if np.isfinite(dx_all).any() else p["dx_tip_free"]
        # the tip may open beyond its rest position (remanence after an excursion): the lower limit is the
        # smallest closing the calibration references saw, not 0
        dx_min = float(np.nanmin(dx_all)) if np.isfinite(dx_all).any() else 0.0
        f_max = float(np.nanmax(f_all)) if np.isfinite(f_all).any() else 0.0
        self.ranges_ = {"dx": [min(dx_min, 0.0), max(dx_max, 0.0)], "f": [0.0, max(f_max, 0.0)]}

    # ------------------------------------------------------------------ helpers
    def _charge_h_vp(self, df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(Q, H(Q), V_p)`` of a trial with its links applied: the charge, the hysteresis voltage and the piezo
        voltage ``V - H(Q)`` (thesis eq. 27) before the stress member's load term."""
        Q = self._charge(df)
        H = self._h(Q, df)
        return Q, H, piezo_voltage(df["V"].to_numpy(dtype=float), H)

    def _regressors(self, df: pd.DataFrame, f: np.ndarray | None = None) -> np.ndarray:
        """``[Q, V_p]`` of a trial (thesis eq. 27). With the stress member (:mod:`selfsense.chain.load`) ``V_p`` also
        loses ``w f`` (``w = s_H (H(q) - a_H) + s_Q (Q - a_Q)``): ``f`` given (a calibration trial's known load: its
        force reference, 0 on a free tip), or else solved with the force row in closed form (its ridge chosen on the
        calibration trials) within the calibration references' force range
        (:func:`~selfsense.chain.load.stress_voltage`)."""
        Q, H, V_p = self._charge_h_vp(df)
        s_h, s_q = self.stress_weights()
        if s_h or s_q:
            from selfsense.chain.load import stress_voltage, stress_weight

            w = stress_weight(H, Q, s_h, s_q, *self.stress_offsets())
            V_p = V_p - w * f if f is not None else stress_voltage(Q, V_p, w, self.coef_["B21"], self.coef_["B22"],
                                                                   *self.ranges_["f"], self.stress_ridge())
        if (self.tip_creep_ or {}).get("applied"):
            from selfsense.chain.creep import creep_columns

            return np.column_stack([Q, V_p, creep_columns(Q, V_p, _trial_dt(df), self.tip_creep_["taus_s"])])
        return np.column_stack([Q, V_p])

    def stress_offsets(self) -> tuple[float, float]:
        """The stress member's ``(a_H [V], a_Q [C])``: the stress columns' parts along ``f`` (chain.load)."""
        st = self.stress_ or {}
        return float(st.get("a_h_v", 0.0)), float(st.get("a_q_c", 0.0))

    def stress_ridge(self) -> float:
        """The ridge of the stress member's load solve (:func:`selfsense.chain.load.stress_load`; 0 where not chosen)."""
        return float((self.stress_ or {}).get("load_ridge", 0.0))

    def slew_rate(self) -> float:
        """The amplifier member's slew limit [V/s] (:func:`selfsense.chain.amplifier.with_slew`), 0 where the member
        does not carry one."""
        sl = (self.amplifier_ or {}).get("slew") or {}
        return float(sl["rate_v_per_s"]) if sl.get("applied") else 0.0

    def stress_weights(self) -> tuple[float, float]:
        """The stress member's ``(s_H [1/N], s_Q [V/(C N)])`` (``V_H = H(q) + (s_H (H(q) - a_H) + s_Q (Q - a_Q)) f``,
        :mod:`selfsense.chain.load`), zeros where the member is not carried."""
        st = self.stress_ or {}
        if not st.get("applied"):
            return 0.0, 0.0
        return float(st.get("s_h_per_n", 0.0)), float(st.get("s_q_v_per_c_n", 0.0))

    def _predict_raw(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = self.coef_
        # thesis eq. (52) on the total charge Q + q_0: the rest closing dx0 = A1 q_0 (0 unless adopted, _rest_offset)
        dx = tip_displacement(X[:, 0], X[:, 1], c["A1"], c["A2"], c.get("dx0", 0.0))
        f = tip_force(X[:, 0], X[:, 1], c["B21"], c["B22"])          # thesis eq. (46) / (52)
        cr = self.tip_creep_ or {}
        if cr.get("applied") and X.shape[1] > 2:
            # the creep member (chain.creep): the strain K beta at the tip displacement, kappa K beta at the force
            s = X[:, 2:] @ np.asarray(cr["beta"], dtype=float)
            dx, f = dx + s, f + float(cr["kappa"]) * s
        return dx, f

    def temperature_scale(self, trial: str | None) -> float:
        """The temperature member's charge scale of ``trial`` (1.0 where not applied or the trial is not known)."""
        tm = self.temperature_ or {}
        if trial is None or not tm.get("applied"):
            return 1.0
        return float((tm.get("scales") or {}).get(str(trial), 1.0))

    # ------------------------------------------------------------------ estimation
    def estimate(self, df: pd.DataFrame, trial: str | None = None) -> pd.DataFrame:
        """Estimate tip displacement and force for one prepared trial (thesis eq. 52 + Fig. 24 post-processing).

        ``trial``: the trial's name in the trials.csv the estimator was fitted with; where the temperature member is
        applied, its charge is divided by the trial's campaign scale (a trial not named there is estimated at the
        calibration's scale, 1).

        Returns columns ``t, dx_hat, f_hat, dx_raw, f_raw, V_p, V_H, q`` (m, N, V, C). During the relay segment
        (leads shorted) the estimates are 0 by construction of the known initial state.
        """
        if self.hysteresis_ is None:
            raise RuntimeError("SelfSensingEstimator.estimate called before fit()")
        q_measured = df["q"].to_numpy(dtype=float)
        s_t = self.temperature_scale(trial)
        if s_t != 1.0:
            df = _with_column(df, "q", q_measured / s_t)
        df = self._with_links(df)
        X = self._regressors(df)
        dx_raw, f_raw = self._predict_raw(X)
        relay = df["relay"].to_numpy() >= 0.5
        dx_raw = np.where(relay, 0.0, dx_raw)
        f_raw = np.where(relay, 0.0, f_raw)
        if not (np.isfinite(dx_raw).all() and np.isfinite(f_raw).all()):
            raise ValueError("estimate: non-finite values in the estimate (check the trial's V and q columns)")
        dx, f = dx_raw.copy(), f_raw.copy()
        cfg = self.config
        u = df["u_cmd"].to_numpy()
        if cfg.dc_offset:
            dx = sliding_dc_offset(dx, u, zero_level=cfg.zero_input_v / max(rig_value(self.rig, "amplifier_gain"), 1e-12))
        if cfg.dc_offset_force:
            f = sliding_dc_offset(f, u, zero_level=cfg.zero_input_v / max(rig_value(self.rig, "amplifier_gain"), 1e-12))
        if cfg.limit:
            dx = limit_to_range(dx, *self.ranges_["dx"])
            f = limit_to_range(f, *self.ranges_["f"])
        V_H = df["V"].to_numpy(dtype=float) - X[:, 1]  # thesis eq. (27): V = V_p + V_H (H evaluated once)
        return pd.DataFrame({
            "t": df["t"].to_numpy(dtype=float),
            "dx_hat": dx, "f_hat": f, "dx_raw": dx_raw, "f_raw": f_raw,
            "V_p": X[:, 1], "V_H": V_H, "q": q_measured,
        })

    @contextlib.contextmanager
    def _inputs_overridden(self, **inputs):
        """The caller's inputs ``inputs`` (forced ``members``, ``leakage_search_reuse``, ``h_candidates``) set on this
        estimator for the block -- a second calibration of the chain under other forced members or candidates, inside
        one fit -- and the caller's own objects put back afterwards, whatever the block raised. Only those inputs are
        restored; the fitted state the block leaves is the caller's to keep or to restore
        (:meth:`fitted_copy`)."""
        saved = {k: getattr(self, k) for k in inputs}
        for k, v in inputs.items():
            setattr(self, k, v)
        try:
            yield self
        finally:
            for k, v in saved.items():
                setattr(self, k, v)

    # ------------------------------------------------------------------ serialisation
    #: attributes a :meth:`fitted_copy` shares with the original: what the caller gave, not what the fit made
    SHARED_INPUTS = ("rig", "config", "members", "leakage_search_reuse")

    def fitted_copy(self) -> "SelfSensingEstimator":
        """A copy of the fitted state (every fitted attribute copied deeply) that shares :attr:`SHARED_INPUTS` with
        this estimator: a snapshot to restore (:meth:`fit_coefficients`' offset-drift re-decision) or to continue
        from (the gap diagnostic's recalibrations that share one H(q) calibration)."""
        import copy

        return copy.deepcopy(self, {id(v): v for k, v in self.__dict__.items() if k in self.SHARED_INPUTS})

    def to_dict(self) -> dict:
        return {
            "config": dataclasses.asdict(self.config),
            "hysteresis": _h_to_dict(self.hysteresis_) if self.hysteresis_ is not None else None,
            "h_slope": self.h_slope_,
            "onsite": self.onsite_,
            "coef": self.coef_,
            "ranges": self.ranges_,
            "fit_report": _json_safe_report(self.fit_report_),
            "calibration_trials": self.calibration_trials_,
            "leakage_s": self.leakage_s_,
            "offset_drift": self.offset_drift_,
            "members": dict(self.members),
            "drift_hysteresis": (_h_to_dict(self.drift_hysteresis_) if self.drift_hysteresis_ is not None else None),
            "amplifier": dict(self.amplifier_),
            "absorption": dict(self.absorption_),
            "quantiser": dict(self.quantiser_),
            "stress": dict(self.stress_),
            "tip_creep": dict(self.tip_creep_),
            "temperature": dict(self.temperature_),
            "amplifier_lag": dict(self.amplifier_lag_),
            "voltage_hysteresis": (_h_to_dict(self.voltage_hysteresis_) if self.voltage_hysteresis_ is not None
                                   else None),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], rig: Any) -> "SelfSensingEstimator":
        est = cls(config=SensingConfig(**d["config"]), rig=rig, members=dict(d.get("members", {})))
        est.hysteresis_ = _h_from_dict(d["hysteresis"]) if d.get("hysteresis") else None
        est.drift_hysteresis_ = _h_from_dict(d["drift_hysteresis"]) if d.get("drift_hysteresis") else None
        est.h_slope_ = float(d["h_slope"])
        est.onsite_ = dict(d.get("onsite", {}))
        coef = dict(d["coef"])
        extra = {k: coef.pop(k) for k in ("extra_dx", "extra_f") if k in coef}
        if any(extra.values()):  # a model fitted with the retired gap library's augmentation terms
            raise ValueError(f"model JSON: coef {sorted(k for k, v in extra.items() if v)} hold augmentation terms of "
                             "the retired tip-level gap library, which this version cannot evaluate; refit the model")
        est.coef_ = coef
        est.ranges_ = dict(d["ranges"])
        est.fit_report_ = dict(d.get("fit_report", {}))
        est.calibration_trials_ = list(d.get("calibration_trials", []))
        est.leakage_s_ = float(d.get("leakage_s", 0.0))
        est.offset_drift_ = bool(d.get("offset_drift", False))
        est.amplifier_ = dict(d.get("amplifier") or {})
        est.absorption_ = dict(d.get("absorption") or {})
        est.quantiser_ = dict(d.get("quantiser") or {})
        est.stress_ = dict(d.get("stress") or {})
        est.tip_creep_ = dict(d.get("tip_creep") or {})
        est.temperature_ = dict(d.get("temperature") or {})
        est.amplifier_lag_ = dict(d.get("amplifier_lag") or {})
        est.voltage_hysteresis_ = _h_from_dict(d["voltage_hysteresis"]) if d.get("voltage_hysteresis") else None
        return est
