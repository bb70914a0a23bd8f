"""Stage-wise gap diagnostic: residuals of each physical stage in the measured signals (docs/gap.md).

The estimate flows u_cmd -> V (amplifier) -> Q (electrical) -> x (mechanical) -> tip / load. Each stage has a
residual that needs no truth, measured on the trials where the stage is observed:

* **holds**: the shunt signal while the relay shorts the actuators before every trial (a 0 V hold): nominal, one
  offset per trial; a ramp there is an in-amp drift, an irregular current a remanent state relaxing.
* **electrical** (free-tip trials): the measured charge Q as the response to the actuator voltage V. Nominal model:
  a signed Prandtl-Ishlinskii operator of V with a relaxation bank (thesis ``000_18d138f03f1777c3.txt`` eqs. 27-33:
  V = V_p + H(q), and on a free tip V_p is proportional to q, so Q is a hysteretic, creeping function of V); what is
  left is what that relation cannot be (charge added or lost outside the actuator, a voltage that is not the
  amplifier's command).
* **amplifier**: with V reconstructed as V_c - V_s (eq. 56) an amplifier that cannot follow its command shows in
  the electrical residual; its member (a slew / current limit) is tested there, and a crossover dead band (not a
  member) is left to the electrical stage's open-set test.
* **mechanical** (free-tip trials): the laser against Q. On a free tip the displacement is proportional to the
  stored charge (eqs. 27 and 52 with f = 0), so the nominal model is a line in Q (plus a small quadratic term for
  the mechanism's kinematics) and the stage is almost null-free.
* **blocked** (blocked-tip trials, reference-free): the actuator voltage V against the charge Q. With the tip
  blocked x = 0, so V_p = Q / (n_A C_p) and V = Q / (n_A C_p) + H(Q) (thesis eqs. 27 and 55): the nominal model is
  a line in Q plus the stand-in's H(Q) identified on the free-tip trial, with one offset per trial. An actuator
  whose hysteresis depends on its stress (the tip load) shows there as V_H (1 + c f) with f proportional to Q.
* **load** (force-reference trials): the load cell against the nominal estimate f^ (the fast stand-in of the
  sensing estimator, :class:`selfsense.gap.standin.FastSensingEstimator`, calibrated on the calibration trials), with
  Q and V free (eq. 46: the two-port cross terms are part of the nominal).
* **anchors** (where the fitted chain is given: the pipeline, the tip tier): the chain's own charge scale on the free-
  and blocked-tip trials, validation trials included (no reference read), against the trial's position in the
  campaign; its member names a temperature drift by the rule that adopts the chain's temperature member
  (:func:`anchor_stage`).

Each stage has a library of members (a few physically shaped columns, some on a grid of a physical parameter:
a time constant, a mode frequency, a rate limit); competing members sit in one stage model and enter by forward
selection on the blocked-CV relative gain (contiguous blocks, never random samples). A member is accepted when
its gain beats its null threshold (:mod:`selfsense.gap.stage_thresholds`, from effect-free cases over the
device families, studentised max-statistic = family-wise correction). A member whose best grid point lies on the
edge of its grid is accepted only if a generic model-error model gains nothing beyond it (open-set test first);
otherwise, and whenever the generic model still gains beyond the accepted members, the stage reports
"unexplained structure".

The shrink of a member is the held-out RMS of its stage before and after adding it with its stage-fitted
coefficients; the truth it is checked against is the stage residual re-simulated without the effect
(:mod:`selfsense.gap.blind`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Callable

import numpy as np
import pandas as pd
from selfsense.chain.amplifier import rate_limit
from selfsense.signals.iir import lfilter

from selfsense.signals.kernels import shunt_current

__all__ = ["StageSignals", "stage_signals", "prepare_signals", "MEMBERS", "STAGES", "diagnose_stages",
           "stage_residuals", "GramCV"]

N_BLOCKS = 6     #: contiguous CV blocks per trial


# --------------------------------------------------------------------------------------------------- signals
@dataclass
class StageSignals:
    """The measured signals of one trial after the relay released (SI units; t from the release)."""

    name: str
    t: np.ndarray
    V: np.ndarray
    Q: np.ndarray
    Vc: np.ndarray
    i: np.ndarray
    dx: np.ndarray
    f: np.ndarray
    dt: float
    tip: str
    reference: str
    role: str
    order: int
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)


def _release(relay: np.ndarray) -> int:
    on = np.flatnonzero(np.asarray(relay, float) >= 0.5)
    return int(on[-1] + 1) if len(on) else 0


def stage_signals(trials: dict, meta: pd.DataFrame, rig) -> list[StageSignals]:
    """Per-trial signals from prepared trials (``selfsense.signals.prepare_trial``: t, V, q, V_c, V_s, dx_ref,
    f_ref, relay) and trials.csv meta; shunt current i = V_s / R. The trials are taken in the order of ``meta``'s
    rows (trials.csv: the measurement order, docs/data_format.md), whatever the order of ``trials``: a trial's
    position there is its time in the campaign (``order``, the temperature member's axis); trials without a meta row
    follow, in their own order."""
    R = float(getattr(rig, "shunt_resistance_ohm", None) or rig["shunt_resistance_ohm"])
    out = []
    names = [t for t in meta.index if t in trials] + [t for t in trials if t not in meta.index]
    for k, name in enumerate(names):
        df = trials[name]
        m = meta.loc[name]
        a = _release(df["relay"].to_numpy())
        on = np.flatnonzero(df["relay"].to_numpy(float)[:a] >= 0.5)
        t = df["t"].to_numpy(float)[a:]
        if len(t) < 4 * N_BLOCKS:
            continue
        dt = float(np.median(np.diff(t)))
        out.append(StageSignals(
            name=str(name), t=t - t[0], V=df["V"].to_numpy(float)[a:], Q=df["q"].to_numpy(float)[a:],
            Vc=df["V_c"].to_numpy(float)[a:], i=shunt_current(df["V_s"].to_numpy(float)[a:], 0.0, R),
            dx=df["dx_ref"].to_numpy(float)[a:] if "dx_ref" in df else np.full(len(t), np.nan),
            f=df["f_ref"].to_numpy(float)[a:] if "f_ref" in df else np.full(len(t), np.nan),
            dt=dt, tip=str(m.get("tip", "")), reference=str(m.get("reference", "")), role=str(m.get("role", "")),
            order=k, extra={"relay_vs": df["V_s"].to_numpy(float)[on[0]:on[-1] + 1] if len(on) else np.zeros(0),
                            "post_noise": _mad(np.diff(df["V_s"].to_numpy(float)[a:]))}))
    return out


def _mad(x: np.ndarray) -> float:
    """Robust standard deviation (1.4826 x median absolute deviation)."""
    x = np.asarray(x, float)
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else float("nan")


def lp(x: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """First-order low-pass y' = (x - y) / tau, exact for piecewise-constant input, starting at rest (y = 0)."""
    a = float(np.exp(-dt / tau))
    return lfilter([1.0 - a], [1.0, -a], np.asarray(x, float))


def resonator(x: np.ndarray, f_hz: float, zeta: float, dt: float) -> np.ndarray:
    """Unit-DC-gain second-order low-pass at f_hz (bilinear transform with pre-warping), from rest."""
    w = 2 * np.pi * f_hz
    K = w / np.tan(w * dt / 2)
    a0 = K * K + 2 * zeta * w * K + w * w
    b = np.array([w * w, 2 * w * w, w * w]) / a0
    a = np.array([1.0, (2 * w * w - 2 * K * K) / a0, (K * K - 2 * zeta * w * K + w * w) / a0])
    return lfilter(b, a, np.asarray(x, float))


def _plays(x: np.ndarray, radii, z0=None) -> np.ndarray:
    from selfsense.hysteresis.operators import play_operator

    return play_operator(np.asarray(x, float), np.asarray(radii, float), z0)


# --------------------------------------------------------------------------------------------------- members
@dataclass(frozen=True)
class Member:
    """A library member: ``cols(s, ctx, g)`` -> (n, k) columns for trial ``s`` at grid value ``g``; or, for a
    level test, ``gain(stage_model, base_cols)`` -> its statistic (then ``cols`` returns no column)."""

    name: str
    family: str
    stage: str
    cols: Callable
    grid: tuple = (None,)
    unit: str = ""
    physics: str = ""
    gain: Callable | None = None
    #: physical sign of the member's first coefficient relative to the stage's reference coefficient (the charge
    #: -> displacement gain a of the mechanical stage): a fit with the other sign is not this member
    sign: int | None = None
    #: smallest null scale of this member where it differs from its stage's (selfsense.gap.blind.calibrate). Such a
    #: member is judged by its gain on the nominal model's RMS, what its null was measured on, not on what the
    #: members accepted before it left (their forms are not the world's, and their misfit is not in its null)
    null_floor: float | None = None
    fallback_of: str | None = None  #: a wider form of the member named here, tried only where that member fails


def _c_leak(s, ctx, g):
    # the estimator's own leakage member (one definition for the chain and the diagnostic)
    from selfsense.chain.charge import leak_column

    return leak_column(s.V, s.dt)[:, None]


def _c_offset(s, ctx, g):
    return np.column_stack([s.t, s.t ** 2 / 10.0])


def _c_absorption(s, ctx, g):
    # the charge of the estimator's absorption member (chain.charge): the diagnostic tests the same column
    from selfsense.chain.charge import absorption_column

    return (absorption_column(s.V, s.dt, g) - s.V)[:, None]


def _c_creep(s, ctx, g):
    return (lp(s.Q, g, s.dt) - s.Q)[:, None]


def _c_temperature(s, ctx, g):
    return (s.Q * (s.order - ctx["order_mid"]))[:, None]


def _c_mode(s, ctx, g):
    """In-phase and quadrature response of a second-order mode at ``g`` Hz (zeta 0.05) to the charge: the tip
    mode's own lag and its back-coupling into the charge shift the phase, so both components are free."""
    r = resonator(s.Q, g, 0.05, s.dt)
    return np.column_stack([r - s.Q, np.gradient(r, s.dt) / (2 * np.pi * g)])


def _c_amplifier(s, ctx, g):
    rate = ctx["slew"] * g
    vc = rate_limit(s.Vc, rate, np.arange(len(s.Vc)) * s.dt)
    return (vc - s.Vc)[:, None]


def _c_preload(s, ctx, g):
    v = s.V / ctx["v_span"]
    r = np.array([float(g)])
    return _plays(v, r, z0=r.copy()) - _plays(v, r)  # a play pre-driven up to +r, less the relaxed one


def _c_one_sided(s, ctx, g):
    v = s.V / ctx["v_span"]
    rm = np.maximum.accumulate(v)
    first = (v >= rm - 1e-3).astype(float)
    return np.column_stack([first * v, (rm - v) * (1 - (rm - v))])


def _c_lost_charge(s, ctx, g):
    """Charge the measurement lost while the shunt channel sat at its rail: per trial, the time spent at the upper and
    at the lower rail so far (cumulative, in seconds over the trial's length; one coefficient each = the mean current
    beyond the range). The rail is the channel's extreme value over the whole dataset, counted only where at least
    three samples sit exactly on it (a saturated in-amp or ADC holds one value while the current goes on). Zero in a
    trial that never reaches it, so the member says nothing where nothing clipped."""
    hi, lo = ctx["i_rail"]
    n = len(s)
    up = np.cumsum(s.i >= hi) * s.dt if np.isfinite(hi) else np.zeros(n)
    dn = np.cumsum(s.i <= lo) * s.dt if np.isfinite(lo) else np.zeros(n)
    T = max(n * s.dt, s.dt)
    return np.column_stack([up / T, dn / T])


def _per_trial(s, ctx, B):
    out = np.zeros((B.shape[0], B.shape[1] * ctx["n_trials"]))
    k = ctx["trial_index"][s.name]
    out[:, B.shape[1] * k:B.shape[1] * (k + 1)] = B
    return out


def _c_none(s, ctx, g):
    return np.zeros((len(s.extra["relay_vs"]), 0))


def _g_excess(sm, base) -> float:
    """Fast fluctuation of the shunt signal while the relay shorts the actuators, against the same channel's noise
    after the release: median over trials of std(diff V_s, short) / (1.4826 MAD(diff V_s, after release)) - 1.
    A remanent operator state relaxing through the short drives an irregular current there; an effect-free short
    leaves the in-amp's noise, and a drifting offset (ramp, random walk) hardly changes sample-to-sample
    differences. Normalised by the channel's own noise, so it does not depend on the rig's in-amp or ADC."""
    return sm.extra["relay_excess"]


def _c_ramp(s, ctx, g):
    """Per trial, an in-amp offset ramping during the relay short (thermal drift): a linear trend."""
    x = np.linspace(0.0, 1.0, len(s.extra["relay_vs"]))
    return _per_trial(s, ctx, x[:, None])


def _c_stress(s, ctx, g):
    fh = s.extra["f_hat"] / ctx["f_span"]
    return np.column_stack([fh * s.V / ctx["v_span"], fh * fh])


def _c_stress_blocked(s, ctx, g, wide: bool = False):
    """H(Q) scaled by the actuator stress, to first order in its linear part: on a blocked tip the stress is
    proportional to Q, so V = Q / (n_A C_p) + H(Q) + c Q^2. A dependence on the field alone is part of H(Q), which is
    identified on the free tip over the same charge range; at equal Q the blocked and the free tip differ only in
    stress. On a free tip there is no tip load (the column is 0); on any other trial the stress proxy is the stand-in's
    force estimate over the blocked trials' force per charge (``kappa``), so that a correction carries to contact
    trials. ``wide`` (member ``load.stress_hysteresis@blocked_h``): H(Q) (1 + m |p|), the column H^(Q) |p| beside
    Q p, for an H far from linear in Q (two columns, a larger null gain: a threshold of its own, tried only where the
    narrow form fails)."""
    if s.tip == "free":
        return np.zeros((len(s), 1 + wide))
    p = s.Q if s.tip == "blocked" else s.extra["f_hat"] / ctx["kappa"]
    c = p * s.Q / ctx["q_span"] ** 2
    return np.column_stack([c, np.abs(p) * s.extra["v_h"] / (ctx["q_span"] * ctx["v_span"])]) if wide else c[:, None]


def _c_contact(s, ctx, g):
    fh = s.extra["f_hat"] / ctx["f_span"]
    c = np.maximum(fh, 0.0)
    return np.column_stack([c ** 1.5, np.sqrt(c)])


#: the electrical nominal's relaxation bank [s] (electrical creep of H is part of the nominal model)
CREEP_TAU_S = (0.1, 0.3, 1.0, 3.0, 10.0)
TAU_GRID = (0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0)
MODE_GRID = (8.0, 12.0, 18.0, 27.0, 40.0, 60.0, 90.0, 135.0)
_STRESS_BLK = "load.stress_hysteresis@blocked"

MEMBERS: dict[str, Member] = {m.name: m for m in [
    # mechanical stage: laser against charge on free-tip trials
    Member("slow.leakage", "slow", "mechanical", _c_leak, physics="a parallel conductance g: the shunt also "
           "carries g V, so the laser follows Q - g int V dt, g > 0", sign=-1),
    Member("slow.offset_drift", "slow", "mechanical", _c_offset, physics="in-amp offset integrated into Q: "
           "Q error = c1 t + c2 t^2"),
    Member("slow.absorption", "slow", "mechanical", _c_absorption, TAU_GRID, "s",
           "charge parked in a dielectric-absorption branch: the laser follows Q - C_da LP_tau V (after a step the "
           "charge keeps rising while the tip does not)", sign=-1),
    Member("slow.creep", "slow", "mechanical", _c_creep, TAU_GRID, "s",
           "charge-free creep strain: x = a Q + c (LP_tau Q - Q) (after a step the tip keeps moving while the "
           "charge does not)", sign=1),
    # its null is ten times tighter than its stage's other members (95 % quantile 0.0004 against 0.003-0.005, largest
    # 0.003 in 200 effect-free cases): a floor of 0.002 is five times its 95 % quantile and leaves T unchanged (chosen
    # after the seed-27182 temperature cases had been looked at; scored first on a later seed)
    Member("slow.temperature", "slow", "mechanical", _c_temperature,
           physics="actuator constant drifting over the campaign: x = a Q (1 + c k_trial)", null_floor=0.002),
    # its null is tighter still (95 % quantile 0.0003, largest 0.0007 in 200 effect-free cases, against 0.003-0.005
    # for the charge-path members): the temperature member's floor of 0.002, six times its 95 % quantile, leaves T
    # unchanged (chosen after the tip-mode gains of stage seeds 20261223 and 20261226 had been looked at, where the
    # default floor left 19 of 81 tip-mode cases with nothing named, gains 0.009-0.055; scored first on a later seed)
    Member("rate.mechanism_mode", "rate", "mechanical", _c_mode, MODE_GRID, "Hz",
           "tip mode: x = a Q + c1 (R_f[Q] - Q) + c2 d/dt R_f[Q] / (2 pi f), R_f a second-order low-pass at f "
           "(zeta 0.05); in-phase and quadrature because the mode also couples back into the charge",
           null_floor=0.002),
    # electrical stage: V against Q on free-tip trials
    Member("slow.leakage@el", "slow", "electrical", _c_leak, physics="Q = G[V] + g int V dt (the shunt also carries g V)"),
    Member("slow.offset_drift@el", "slow", "electrical", _c_offset, physics="Q = G[V] + c1 t + c2 t^2"),
    Member("slow.temperature@el", "slow", "electrical", _c_temperature, physics="C_p drifting over the campaign"),
    Member("rate.amplifier", "rate", "electrical", _c_amplifier, (0.6, 0.8, 1.0, 1.25), "x slew of the data",
           "amplifier slew / current limit: V = rate_limit(G u_cmd) - V_s"),
    # holds stage: the shunt signal while the relay shorts the actuators (a 0 V hold before every trial)
    Member("hysteresis.preload@holds", "hysteresis", "holds", _c_none, gain=_g_excess,
           physics="remanent operator state relaxing through the relay short: an irregular shunt current at 0 V "
                   "(level test: sample-to-sample fluctuation during the short / after the release - 1)"),
    Member("slow.offset_drift@holds", "slow", "holds", _c_ramp,
           physics="in-amp offset drifting during the relay short: a ramp of the shunt signal at 0 V"),
    Member("hysteresis.preload", "hysteresis", "electrical", _c_preload, (0.1, 0.25, 0.45, 0.7), "x Q range",
           "operator state not relaxed at the start: a play pre-driven to +r"),
    Member("hysteresis.one_sided", "hysteresis", "electrical", _c_one_sided,
           physics="first-loading (virgin) curve differs from the later branches"),
    Member("hysteresis.one_sided@mechanical", "hysteresis", "mechanical", _c_lost_charge,
           physics="first-loading (virgin) current beyond the shunt channel's range: the measured charge lost what "
                   "flowed while the channel sat at its rail, x = a (Q + c_up t_up(t) + c_dn t_dn(t)), t_up / t_dn the "
                   "time at the upper / lower rail so far in the trial"),
    # load stage: load cell against the nominal force estimate on force-reference trials
    Member("load.stress_hysteresis", "load", "load", _c_stress, physics="H(q) scaled by the tip load: f^ V, f^2"),
    # blocked stage: V against Q on blocked-tip trials (reference-free)
    Member(_STRESS_BLK, "load", "blocked", _c_stress_blocked,
           physics="H(q) scaled by the actuator stress: on a blocked tip f is proportional to Q, so V = Q / (n_A C_p) + "
                   "H(Q) + c Q^2 (H's linear part scaled; H itself is identified on the free tip)"),
    Member("load.stress_hysteresis@blocked_h", "load", "blocked", partial(_c_stress_blocked, wide=True),
           fallback_of=_STRESS_BLK,
           physics="H(q) scaled by the actuator stress, its loop too: V = V_p + H(Q) (1 + m |p|), H^(Q) |p| and Q p"),
    Member("load.contact", "load", "load", _c_contact, physics="Hertz-like contact: f^1.5, f^0.5 (compressive)"),
]}

def effect_of(member: str) -> str:
    """The effect a member names: ``slow.leakage@el`` and ``slow.leakage`` name the same physical effect."""
    return member.split("@")[0]


STAGES = ("holds", "electrical", "mechanical", "blocked", "load")


# ------------------------------------------------------------------------------------------ nominal and generic
def _nominal(stage: str, s: StageSignals, ctx: dict, ntr: int) -> np.ndarray:
    onehot = np.zeros((len(_target(stage, s)), ntr))
    onehot[:, ctx["trial_index"][s.name]] = 1.0
    if stage == "holds":
        return onehot
    if stage == "mechanical":
        u = s.Q / ctx["q_span"]
        # the shunt current: a sub-sample skew between the laser and the integrated charge (channel timing,
        # trapezoidal integration) is a first-order term in dQ/dt
        return np.column_stack([u, u * u, s.i * s.dt * 100.0 / ctx["q_span"], onehot])
    if stage == "electrical":
        v = s.V / ctx["v_span"]
        P = _plays(v, np.arange(1, 11) / 10.0)
        C = np.column_stack([lp(v, tau, s.dt) - v for tau in CREEP_TAU_S])
        return np.column_stack([v, v * v, P, C, np.ones(len(s))])
    if stage == "blocked":
        return np.column_stack([s.Q / ctx["q_span"], s.extra["v_h"] / ctx["v_span"], onehot])
    if stage == "load":
        fh = s.extra["f_hat"] / ctx["f_span"]
        return np.column_stack([fh, s.Q / ctx["q_span"], s.V / ctx["v_span"], onehot])
    raise ValueError(stage)


def _generic(stage: str, s: StageSignals, ctx: dict) -> np.ndarray:
    """Generic model-error columns (the open-set test): what no member is, but a physical effect could be."""
    if stage == "holds":
        return np.zeros((len(_target(stage, s)), 0))
    u = s.Q / ctx["q_span"]
    ny = 0.5 / s.dt
    if stage == "mechanical":
        P = _plays(u, [0.005, 0.015, 0.04])
        R = np.column_stack([resonator(u, f, 0.03, s.dt) - u for f in (0.5 * ny, 0.8 * ny)])
        return np.column_stack([P, R, u ** 3, lp(u, 0.02, s.dt) - u])
    if stage == "blocked":
        return np.column_stack([u * u, u ** 3, lp(u, 0.02, s.dt) - u, _plays(u, [0.005, 0.015, 0.04])])
    if stage == "electrical":
        v = s.V / ctx["v_span"]
        Z = np.column_stack([np.minimum(v, c) for c in (0.015, 0.04, 0.1)])
        return np.column_stack([Z, lp(v, 0.01, s.dt) - v, lp(v, 0.03, s.dt) - v, v ** 3, _plays(v, [0.01, 0.03])])
    fh = s.extra["f_hat"] / ctx["f_span"]
    return np.column_stack([fh ** 3, lp(fh, 0.05, s.dt) - fh, _plays(fh, [0.02, 0.08])])


def _stage_trials(stage: str, sigs: list[StageSignals]) -> list[StageSignals]:
    if stage == "holds":
        return [s for s in sigs if len(s.extra.get("relay_vs", ())) >= 8 * N_BLOCKS]
    if stage in ("electrical", "mechanical"):
        return [s for s in sigs if s.tip == "free" and s.reference == "displacement" and np.isfinite(s.dx).all()]
    if stage == "blocked":
        return [s for s in sigs if s.tip == "blocked" and "v_h" in s.extra]
    return [s for s in sigs if s.reference == "force" and np.isfinite(s.f).all() and "f_hat" in s.extra]


def _target(stage: str, s: StageSignals) -> np.ndarray:
    if stage == "holds":
        return s.extra["relay_vs"]
    return {"electrical": s.Q, "mechanical": s.dx, "blocked": s.V, "load": s.f}[stage]


# --------------------------------------------------------------------------------------------------- CV engine
class GramCV:
    """Blocked cross-validation of least squares on column subsets from per-block Gram matrices.

    ``Z`` (n, P) columns, ``y`` (n,), ``blocks`` (n,) block ids. Columns are scaled to unit RMS; every fold is a
    ridge solve (relative ridge ``ridge`` on the scaled Gram) on all blocks but one, scored on the held-out block.
    ``rms(cols)`` is the held-out RMS residual over all blocks."""

    def __init__(self, Z: np.ndarray, y: np.ndarray, blocks: np.ndarray, ridge: float = 1e-8):
        sc = np.sqrt(np.mean(Z * Z, axis=0))
        sc[sc == 0] = 1.0
        self.scale = sc
        Zs = Z / sc
        order = np.argsort(blocks, kind="stable")
        Zs, y, blocks = Zs[order], y[order], blocks[order]
        cut = np.concatenate([[0], np.flatnonzero(np.diff(blocks)) + 1, [len(blocks)]])
        sl = [slice(a, b) for a, b in zip(cut[:-1], cut[1:])]
        self.G = np.stack([Zs[k].T @ Zs[k] for k in sl])
        self.h = np.stack([Zs[k].T @ y[k] for k in sl])
        self.yy = np.array([float(y[k] @ y[k]) for k in sl])
        self.n = len(y)
        self.Gt, self.ht = self.G.sum(0), self.h.sum(0)
        self.ridge = ridge
        self._cache: dict = {}

    def _solve(self, G, h, c):
        A = G[np.ix_(c, c)]
        lam = self.ridge * (np.trace(A) / len(c) if len(c) else 1.0)
        return np.linalg.solve(A + lam * np.eye(len(c)), h[c])

    def rms(self, cols) -> float:
        c = np.asarray(sorted(set(int(x) for x in cols)), int)
        key = tuple(c)
        if key not in self._cache:
            e = 0.0
            for b in range(len(self.yy)):
                w = self._solve(self.Gt - self.G[b], self.ht - self.h[b], c)
                e += self.yy[b] - 2 * w @ self.h[b][c] + w @ self.G[b][np.ix_(c, c)] @ w
            self._cache[key] = float(np.sqrt(max(e, 0.0) / self.n))
        return self._cache[key]

    def fit(self, cols) -> np.ndarray:
        c = np.asarray(sorted(set(int(x) for x in cols)), int)
        return self._solve(self.Gt, self.ht, c) / self.scale[c]

    def rms_in(self, cols) -> float:
        """In-sample RMS residual with the degrees of freedom taken out: sqrt(RSS / (n - p))."""
        c = np.asarray(sorted(set(int(x) for x in cols)), int)
        key = ("in",) + tuple(c)
        if key not in self._cache:
            w = self._solve(self.Gt, self.ht, c)
            e = float(self.yy.sum() - 2 * w @ self.ht[c] + w @ self.Gt[np.ix_(c, c)] @ w)
            self._cache[key] = float(np.sqrt(max(e, 0.0) / max(self.n - len(c), 1)))
        return self._cache[key]


@dataclass
class StageModel:
    stage: str
    cv: GramCV
    nominal: list
    member_cols: dict          #: member -> [cols per grid value]
    generic: list
    n_rows: int
    trials: list
    y_rms: float
    extra: dict = field(default_factory=dict)
    insample: bool = False   #: score by the dof-adjusted in-sample RMS (per-trial trend columns cannot be
    #: extrapolated into a held-out block at a segment's edge; used for the relay-short segments)

    def r(self, cols) -> float:
        return self.cv.rms_in(cols) if self.insample else self.cv.rms(cols)


def _context(sigs: list[StageSignals]) -> dict:
    free = [s for s in sigs if s.tip == "free"] or sigs
    qs = np.concatenate([s.Q for s in free])
    vs = np.concatenate([s.V for s in free])
    q_span = float(np.ptp(qs)) or 1.0
    v_span = float(np.ptp(vs)) or 1.0
    C = q_span / v_span
    imax = max(float(np.max(np.abs(s.i))) for s in sigs)
    fh = [s.extra["f_hat"] for s in sigs if "f_hat" in s.extra]
    f_span = float(np.ptp(np.concatenate(fh))) if fh else 1.0
    # force per charge on a blocked tip (the stand-in's f^ against Q): the stress proxy of the blocked stage
    blk = [s for s in sigs if s.tip == "blocked" and "f_hat" in s.extra]
    qq = sum(float(s.Q @ s.Q) for s in blk)
    kappa = sum(float(s.extra["f_hat"] @ s.Q) for s in blk) / qq if qq > 0 else 0.0
    # the shunt channel's rails: its extreme values over the dataset where >= 3 samples sit exactly on them
    i_all = np.concatenate([s.i for s in sigs])
    hi, lo = float(np.max(i_all)), float(np.min(i_all))
    rail = (hi if np.sum(i_all == hi) >= 3 else np.inf, lo if np.sum(i_all == lo) >= 3 else -np.inf)
    return {"q_span": q_span, "v_span": v_span, "slew": imax / C, "i_rail": rail, "f_span": f_span or 1.0,
            "kappa": kappa or 1.0,
            "order_mid": 0.5 * (min(s.order for s in sigs) + max(s.order for s in sigs)),
            "trial_index": {}}


def build_stage(stage: str, sigs: list[StageSignals], ctx: dict | None = None,
                nominal_only: bool = False) -> StageModel | None:
    """Design of one stage: nominal, every member at every grid value, generic columns; None if unobserved."""
    rows = _stage_trials(stage, sigs)
    if not rows:
        return None
    ctx = dict(ctx or _context(sigs))
    ctx["trial_index"] = {s.name: k for k, s in enumerate(rows)}
    ctx["n_trials"] = len(rows)
    blocks, mats, y = [], [], []
    names = [] if nominal_only else [m for m in MEMBERS.values() if m.stage == stage]
    widths = None  # column count of every part (nominal, each member at each grid value, generic)
    for k, s in enumerate(rows):
        parts = [_nominal(stage, s, ctx, len(rows))]
        for m in names:
            for g in m.grid:
                parts.append(m.cols(s, ctx, g))
        if not nominal_only:
            parts.append(_generic(stage, s, ctx))
        widths = widths or [p.shape[1] for p in parts]
        mats.append(np.column_stack(parts))
        y.append(_target(stage, s))
        n = len(y[-1])
        blocks.append(k * N_BLOCKS + np.minimum((np.arange(n) * N_BLOCKS) // n, N_BLOCKS - 1))
    Z, yv, bl = np.vstack(mats), np.concatenate(y), np.concatenate(blocks)
    p0 = widths[0]
    j, part = p0, 1
    member_cols = {}
    for m in names:
        lst = []
        for _ in m.grid:
            lst.append(list(range(j, j + widths[part])))
            j += widths[part]
            part += 1
        member_cols[m.name] = lst
    generic = list(range(j, Z.shape[1]))
    good = np.isfinite(Z).all(1) & np.isfinite(yv)
    cv = GramCV(Z[good], yv[good], bl[good])
    extra = {}
    if stage == "holds":
        r = [float(np.std(np.diff(s.extra["relay_vs"]))) / s.extra["post_noise"] - 1.0 for s in rows
             if s.extra.get("post_noise", 0) > 0]
        extra["relay_excess"] = float(np.median(r)) if r else float("nan")
    return StageModel(stage, cv, list(range(p0)), member_cols, generic, int(good.sum()), [s.name for s in rows],
                      float(np.sqrt(np.mean(yv[good] ** 2))), extra=extra, insample=stage == "holds")


def _best(sm: StageModel, base: list, member: str) -> tuple[float, int]:
    if MEMBERS[member].gain is not None:
        return float(MEMBERS[member].gain(sm, base)), 0
    r0 = sm.r(base)
    gains = [1.0 - sm.r(base + c) / r0 for c in sm.member_cols[member]]
    sg = MEMBERS[member].sign
    if sg is not None:  # a fit of the wrong physical sign is not this member
        for j, c in enumerate(sm.member_cols[member]):
            cols = sorted(set(base + c))
            w = dict(zip(cols, sm.cv.fit(cols)))
            if np.sign(w[c[0]] * w[sm.nominal[0]]) != sg:
                gains[j] = min(gains[j], 0.0)
    k = int(np.argmax(gains))
    return float(gains[k]), k


def stage_gains(sm: StageModel) -> dict:
    """Relative held-out gain of every member alone over the nominal model, and of the generic model."""
    out = {m: _best(sm, sm.nominal, m)[0] for m in sm.member_cols}
    r0 = sm.r(sm.nominal)
    out["generic"] = 1.0 - sm.r(sm.nominal + sm.generic) / r0 if sm.generic else 0.0
    return out


def diagnose_stage(sm: StageModel, thr: dict) -> dict:
    """Forward selection in one stage model against the null thresholds ``thr`` (member -> gain threshold,
    "generic" -> threshold of the generic model)."""
    base = list(sm.nominal)
    r_nom = sm.r(base)
    accepted, notes = [], []
    left = list(sm.member_cols)
    while left:
        cand = []
        for m in left:
            g, k = _best(sm, base, m)
            if MEMBERS[m].null_floor is not None and MEMBERS[m].gain is None:
                g *= sm.r(base) / r_nom   # the RMS it removes, as a fraction of the nominal's
            cand.append((MEMBERS[m].gain is None, g / thr.get(m, np.inf), g, k, m))
        # column members first; level tests (no columns) only on what the accepted column members leave
        cand = [c for c in cand if c[1] > 1.0] or cand
        done = {a["member"] for a in accepted} | {x[4] for x in cand if x[1] > 1.0}  # a wider form: where they fail
        cand = [c for c in cand if MEMBERS[c[4]].fallback_of not in done]
        if not cand:
            break
        cand.sort(reverse=True)
        _, ratio, g, k, m = cand[0]
        if not ratio > 1.0:
            break
        grid = MEMBERS[m].grid
        cols = sm.member_cols[m][k]
        if len(grid) > 2 and k in (0, len(grid) - 1):
            rb = sm.r(base + cols)
            gen = 1.0 - sm.r(base + cols + sm.generic) / rb
            if gen > thr.get(f"generic@{sm.stage}", np.inf):
                notes.append(f"{m}: best at the edge of its grid ({grid[k]} {MEMBERS[m].unit}) and the generic model "
                             f"still gains {gen:.3f} beyond it: not accepted (open set)")
                left.remove(m)
                continue
        r_before = sm.r(base)
        base = base + cols
        accepted.append({"member": m, "effect": effect_of(m), "family": MEMBERS[m].family, "gain": g,
                         "threshold": thr.get(m, np.inf), "grid_value": grid[k], "unit": MEMBERS[m].unit,
                         "rms_before": r_before, "rms_after": sm.r(base)})
        left.remove(m)
    gen = 1.0 - sm.r(base + sm.generic) / sm.r(base)
    cols_of = {a["member"]: sm.member_cols[a["member"]][list(MEMBERS[a["member"]].grid).index(a["grid_value"])]
               for a in accepted}
    if accepted:  # stage-fitted coefficients of the final stage model (all data), kept fixed for the correction
        w = dict(zip(sorted(set(base)), sm.cv.fit(base)))
        for a in accepted:
            a["coef"] = [float(w[c]) for c in cols_of[a["member"]]]
            a["coef_ref"] = float(w[sm.nominal[0]])  # the first nominal column: u (mechanical), v (electrical), f^
    unexplained = bool(gen > thr.get(f"generic@{sm.stage}", np.inf)) or any("open set" in n for n in notes)
    shrink_alone = {m: r_nom - sm.r(sm.nominal + c) for m, c in cols_of.items()}
    return {"stage": sm.stage, "rms_nominal": r_nom, "rms_after": sm.r(base), "rms_target": sm.y_rms,
            "n_rows": sm.n_rows, "trials": sm.trials, "accepted": accepted, "generic_gain_after": float(gen),
            "unexplained": unexplained, "notes": notes, "shrink_alone": shrink_alone,
            "gains_alone": stage_gains(sm)}


def _head_to_head(stages: dict) -> None:
    """Competing explanations of one residual, decided by a second stage. A relaxation current through the relay
    short (holds stage) biases the offset that the charge integration takes from the shorted segment, so an
    offset-like charge drift in the mechanical / electrical stage is then the remanent operator state's (preload),
    not the in-amp's."""
    acc = {a["member"] for a in stages.get("holds", {}).get("accepted", [])}
    if "hysteresis.preload@holds" not in acc:
        return
    for st in ("holds", "mechanical", "electrical"):
        for a in stages.get(st, {}).get("accepted", []):
            if a["effect"] == "slow.offset_drift":
                a.update(effect="hysteresis.preload", family="hysteresis",
                         note="offset-like drift explained by the irregular relaxation current seen during the relay "
                              "short (holds stage): it also trends there and biases the relay-segment offset "
                              "estimate that the charge integration subtracts")


def _cross_stage(stages: dict) -> None:
    """A charge-measurement error (leakage, offset) must show in the mechanical stage too: the laser follows the
    actuator's true charge. When the mechanical stage is observed and names no charge-path member, an electrical
    stage drift is the V-Q relation's own slow relaxation (electrical creep of H, part of the nominal), so the
    electrical charge-path acceptances are withdrawn (kept in the notes)."""
    mech = stages.get("mechanical", {})
    if not mech.get("observed"):
        return
    charge = {"slow.leakage", "slow.offset_drift", "slow.absorption", "hysteresis.preload"}
    if any(a["effect"] in charge for a in mech.get("accepted", [])):
        return
    el = stages.get("electrical", {})
    keep = []
    for a in el.get("accepted", []):
        if a["member"] in ("slow.leakage@el", "slow.offset_drift@el"):
            el.setdefault("notes", []).append(
                f"{a['member']}: gain {a['gain']:.3f} above its threshold, but the mechanical stage shows no "
                "charge error (the laser follows the measured charge): read as slow relaxation of the V-Q "
                "relation, not confirmed")
        else:
            keep.append(a)
    el["accepted"] = keep


def attach_force_estimate(sigs: list[StageSignals], trials: dict, meta: pd.DataFrame, rig) -> None:
    """Nominal force estimate f^ on every trial from the fast stand-in estimator calibrated on the calibration
    trials (eqs. 27, 52, 55); stored in ``s.extra["f_hat"]``, with the stand-in's H(Q) in ``s.extra["v_h"]`` (both
    left out if the calibration fails: the load and blocked stages are then unobserved)."""
    from .standin import FastSensingEstimator

    try:
        est = FastSensingEstimator(rig=rig).fit(trials, meta)
    except Exception:  # noqa: BLE001 - the load and blocked stages are then unobserved, and the verdict says so
        return
    for s in sigs:
        df = trials[s.name]
        e = est.estimate(df)
        a = len(df) - len(s)
        s.extra["f_hat"] = e["f_hat"].to_numpy(float)[a:]
        s.extra["v_h"] = e["V_H"].to_numpy(float)[a:]


def prepare_signals(trials: dict, meta: pd.DataFrame, rig) -> tuple[list[StageSignals], dict]:
    """Stage signals of every trial with the nominal force estimate attached, and the dataset's scales."""
    sigs = stage_signals(trials, meta, rig)
    attach_force_estimate(sigs, trials, meta, rig)
    return sigs, _context(sigs)


def stage_residuals(trials: dict, meta: pd.DataFrame, rig) -> dict:
    """Held-out RMS of every stage's nominal model (what the blind check's truth compares)."""
    sigs, ctx = prepare_signals(trials, meta, rig)
    out = {}
    for st in STAGES:
        sm = build_stage(st, sigs, ctx, nominal_only=True)
        if sm is not None:
            out[st] = sm.r(sm.nominal)
    return out


#: the stage read from the fitted chain itself and its one member (:func:`anchor_stage`)
ANCHOR_MEMBER = "slow.temperature@anchors"


def anchor_stage(fitted, trials: dict, meta: pd.DataFrame, named: set | frozenset = frozenset()) -> dict:
    """Stage ``anchors``: the fitted chain's own reference-free evidence of a charge scale drifting over the campaign
    (:func:`selfsense.chain.temperature.anchor_evidence`: free- and blocked-tip trials, validation included, only V
    and Q read), through the same V_p = V - H(q) that costs Table 3. Its member names the drift where the campaign
    change reaches the threshold that adopts the chain's temperature member (one rule for both), as a fallback: the
    anchors move with any misfit of the chain that differs between early and late trials (stress, an amplifier limit,
    a first-loading curve, an offset drift: tip seed 20261227), so it is not named where the signal stages name
    another effect (``named``; docs/gap.md, "The chain's anchors")."""
    from selfsense.chain import temperature as tm

    meta = meta.set_index("trial") if "trial" in meta.columns else meta
    try:
        # where the chain carries the member, the anchors it was adopted on (before its correction)
        anchors = (getattr(fitted, "temperature_", None) or {}).get("anchors_first") or \
            fitted._temperature_anchors(trials, meta)
        ev = tm.anchor_evidence(anchors, tm.calibration_position(meta), len(meta))
    except Exception as exc:  # noqa: BLE001 - the stage is then unobserved, and says why
        return {"stage": "anchors", "observed": False, "notes": [f"anchors not read: {type(exc).__name__}: {exc}"]}
    if not ev["identified"]:
        return {"stage": "anchors", "observed": False, "notes": [ev["why"]], "evidence": ev}
    g, thr = ev["campaign_change"], ev["threshold"]
    d = {"stage": "anchors", "observed": True, "rms_nominal": ev["rms_offsets"], "rms_after": ev["rms_offsets"],
         "rms_target": float("nan"), "n_rows": len(ev["anchors"]), "trials": [a["trial"] for a in ev["anchors"]],
         "accepted": [], "generic_gain_after": float("nan"), "unexplained": False, "notes": [], "shrink_alone": {},
         "gains_alone": {ANCHOR_MEMBER: g}, "thresholds": {ANCHOR_MEMBER: thr}, "evidence": ev}
    other = sorted(set(named) - {"slow.temperature"})
    if g >= thr and other:
        d["notes"].append(f"{ANCHOR_MEMBER}: campaign change {g:.2g} >= {thr:.2g}, but the stages name "
                          f"{', '.join(other)}, whose misfit moves the chain's anchors too: not named")
    elif g >= thr:
        d["rms_after"] = ev["rms_trend"]
        d["shrink_alone"][ANCHOR_MEMBER] = ev["rms_offsets"] - ev["rms_trend"]
        d["accepted"].append({"member": ANCHOR_MEMBER, "effect": "slow.temperature", "family": "slow", "gain": g,
                              "threshold": thr, "grid_value": None, "unit": "", "rms_before": ev["rms_offsets"],
                              "rms_after": ev["rms_trend"]})
    return d


def diagnose_stages(trials: dict, meta: pd.DataFrame, rig, thresholds: dict, fitted=None) -> dict:
    """The stage-wise verdict of a dataset: per stage the nominal held-out RMS, accepted members with their
    gains, thresholds, stage-fitted grid values and shrink, the open-set flag; then the named effects ranked by
    their gain over threshold. ``fitted``: the configured estimator fitted on the dataset; where given (and it has
    the temperature member's anchors) the stage ``anchors`` is read from it (:func:`anchor_stage`)."""
    sigs, ctx = prepare_signals(trials, meta, rig)
    stages = {}
    for st in STAGES:
        sm = build_stage(st, sigs, ctx)
        stages[st] = ({"stage": st, "observed": False} if sm is None
                      else {"observed": True, **diagnose_stage(sm, thresholds)})
    _head_to_head(stages)
    _cross_stage(stages)
    if fitted is not None and hasattr(fitted, "_temperature_anchors"):
        stages["anchors"] = anchor_stage(fitted, trials, meta,
                                         {a["effect"] for d in stages.values() for a in d.get("accepted", [])})
    effects: dict = {}
    for st, d in stages.items():
        for a in d.get("accepted", []):
            e = a["effect"]
            score = a["gain"] / a["threshold"]
            cur = effects.setdefault(e, {"effect": e, "family": a["family"], "score": -np.inf, "shrink_by_stage": {},
                                         "acceptances": []})
            cur["shrink_by_stage"][st] = d["shrink_alone"][a["member"]]
            cur["acceptances"].append({"stage": st, "member": a["member"], "score": score})
            if score > cur["score"]:
                cur.update({"stage": st, "member": a["member"], "score": score, "gain": a["gain"],
                            "grid_value": a["grid_value"], "unit": a["unit"],
                            "shrink_rms": d["shrink_alone"][a["member"]], "rms_nominal": d["rms_nominal"]})
    ranked = sorted(effects.values(), key=lambda e: -e["score"])
    unexpl = [st for st, d in stages.items() if d.get("unexplained")]
    return {"stages": stages, "effects": ranked, "unexplained": unexpl,
            "top": ranked[0]["effect"] if ranked else None, "_signals": sigs, "_context": ctx}
