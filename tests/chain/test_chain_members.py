"""The estimator carries the charge link's leakage member when the holds of all trials support it, forced on or off
by ``members``; the fitted model never depends on a validation trial's reference."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from selfsense.chain.charge import leak_column
from selfsense.mechanics.device import default_tweezer_mechanics
from selfsense.sensing import SelfSensingEstimator, SensingConfig

FS = 200.0
G = 20e-9  # injected insulation leakage [S]
RIG = {
    "n_actuators": 5,
    "amplifier_gain": 15.0,
    "actuator_catalog": {"capacitance_f": 0.25e-6, "blocked_force_n": 240.0, "max_voltage_v": 150.0,
                         "free_displacement_m": 10e-6},
    "tip_free_displacement_m": 6.3e-3,
}
CFG = {"h_model": "preisach", "cv_blocks": 3, "rest_offset": "off", "limit": False}


def _h_true(Q):
    out, prev = np.zeros_like(Q), np.zeros(4)
    r = np.array([0.0, 0.5e-4, 1e-4, 1.5e-4])
    w = np.array([0.0, 30e3, 20e3, 12e3])
    for k, q in enumerate(Q):
        prev = np.maximum(q - r, np.minimum(q + r, prev))
        out[k] = w @ prev
    return out


def _drive(kind, n, hold_s=12.0):
    t = np.arange(n) / FS
    if kind == "sine":
        return t, 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
    lv = [0, 150, 150, 0, 0, 90, 90, 0, 0, 120, 120, 40, 40]
    kt = np.cumsum([0] + [0.5 if i % 2 == 0 else hold_s for i in range(len(lv) - 1)])
    return t, np.interp(t, kt, lv)


def _trial(kind, env, seed, n, relay_n=200):
    dev = default_tweezer_mechanics()
    t, vp = _drive(kind, n)
    vp[:relay_n] = 0.0
    sol = dev.solve(vp) if env == "free" else dev.solve(vp, blocked=True) if env == "blocked" else \
        dev.solve(vp, k_env=200.0, gap=3e-3)
    Q = np.asarray(sol["q"], float)
    V = vp + _h_true(Q)
    relay = np.zeros(n)
    relay[:relay_n] = 1
    iv = leak_column(np.where(relay > 0, 0.0, V), 1.0 / FS)
    rng = np.random.default_rng(seed)
    q_meas = Q + G * iv + 2e-9 * rng.standard_normal(n)
    return pd.DataFrame({"t": t, "V": V, "q": q_meas, "u_cmd": V / 15.0, "relay": relay,
                         "dx_ref": np.asarray(sol["dx_tip"], float), "f_ref": np.asarray(sol["f_tip"], float),
                         "V_c": V, "V_s": 0.0 * V})


@pytest.fixture(scope="module")
def data():
    n_mixed = int(FS * 80)
    trials = {
        "cal_free": _trial("sine", "free", 0, 4000),
        "cal_block": _trial("sine", "blocked", 1, 4000),
        "val_free": _trial("mixed", "free", 2, n_mixed),
        "val_obj": _trial("mixed", "object", 3, n_mixed),
        "val_block": _trial("mixed", "blocked", 4, n_mixed),
    }
    meta = pd.DataFrame([
        ("cal_free", "calibration", "free", "displacement"),
        ("cal_block", "calibration", "blocked", "force"),
        ("val_free", "validation", "free", "displacement"),
        ("val_obj", "validation", "object", "displacement"),
        ("val_block", "validation", "blocked", "force"),
    ], columns=["trial", "role", "tip", "reference"]).set_index("trial")
    meta["signal"] = "sine"
    return trials, meta


def _err(est, df, col="dx"):
    e = est.estimate(df)[f"{col}_hat"].to_numpy()
    ref = df[f"{col}_ref"].to_numpy()
    return float(np.mean(np.abs(e - ref)) / np.ptp(ref) * 100)


@pytest.fixture(scope="module")
def fitted(data):
    trials, meta = data
    auto = SelfSensingEstimator(config=SensingConfig(**CFG), rig=RIG).fit(trials, meta)
    off = SelfSensingEstimator(config=SensingConfig(**CFG), rig=RIG, members={"leakage": "off"}).fit(trials, meta)
    return auto, off


def test_holds_of_all_trials_carry_the_leakage_into_the_estimate(data, fitted):
    """The sine calibration trials cannot show a leakage; the long holds of the (reference-free) validation drives
    can: the estimator adopts the hold-estimated conductance, and the displacement estimate of every long hold no
    longer runs away."""
    trials, _ = data
    auto, off = fitted
    drift = auto.fit_report_["hysteresis"]["drift"]
    assert drift["source"] == "holds", drift
    assert auto.leakage_s_ == pytest.approx(G, rel=0.15)
    assert off.leakage_s_ == 0.0
    for t in ("val_free", "val_obj"):
        assert _err(auto, trials[t]) < 0.5 * _err(off, trials[t])


def test_the_model_never_reads_a_validation_reference(data, fitted):
    trials, meta = data
    scrambled = dict(trials)
    rng = np.random.default_rng(9)
    for t in ("val_free", "val_obj", "val_block"):
        df = trials[t].copy()
        df["dx_ref"] = rng.standard_normal(len(df))
        df["f_ref"] = np.nan
        scrambled[t] = df
    again = SelfSensingEstimator(config=SensingConfig(**CFG), rig=RIG).fit(scrambled, meta)
    a = json.dumps(fitted[0].to_dict(), sort_keys=True, default=float)
    b = json.dumps(again.to_dict(), sort_keys=True, default=float)
    assert a == b


def test_forced_member_and_bad_member_names(data):
    trials, meta = data
    with pytest.raises(ValueError, match=r"members\['leakage'\].*'auto', 'on' or 'off'"):
        SelfSensingEstimator(config=SensingConfig(**CFG), rig=RIG, members={"leakage": "yes"}).fit(trials, meta)
    with pytest.raises(ValueError, match="unknown members"):
        SelfSensingEstimator(config=SensingConfig(**CFG), rig=RIG, members={"creep": "on"}).fit(trials, meta)
