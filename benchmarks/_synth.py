"""Synthetic inputs for the benchmarks (seeded, deterministic): a rig, a hand-made estimator with a realistic
modified-PI H(q) (15 play, 15 superposition, 15 x 4 creep operators) and raw DAQ logs of any length.

Nothing here is fitted: the benchmarks measure speed and equality of implementations, not accuracy.
"""
from __future__ import annotations

import copy

import numpy as np
import pandas as pd

RIG = {
    "dataset": "bench", "sample_rate_hz": 10000.0, "shunt_resistance_ohm": 1000.0, "amplifier_gain": 15.0,
    "inamp_gain": 10.0, "n_actuators": 5,
    "reference": {"laser_m_per_v": 2.0e-3, "load_cell_n_per_v": 0.1},
    "actuator_catalog": {"free_displacement_m": 10.0e-6, "blocked_force_n": 240.0, "stiffness_n_per_m": 24.0e6,
                         "capacitance_f": 0.25e-6, "max_voltage_v": 150.0},
    "tip_free_displacement_m": 6.3e-3,
}
Q_MAX = 5 * 0.25e-6 * 120.0  # total charge at full drive [C]


def operator(dt: float = 1e-4, n_play: int = 15, n_sup: int = 15, n_creep: int = 4, seed: int = 0):
    """A ModifiedPI in the thesis' parametrisation (thresholds on [0, max|x|), eq. 61; log creep bank, eq. 40)
    with a two-sided superposition (exactly one r_S = 0), input unit C, output unit V."""
    from selfsense.hysteresis.pi import ModifiedPI

    rng = np.random.default_rng(seed)
    r_H = np.arange(n_play) / n_play * Q_MAX
    w_H = rng.uniform(0.2, 1.0, n_play) / n_play
    w_H[0] = 0.6
    w_K = rng.uniform(0.0, 0.05, n_play) / n_play
    n_pos = (n_sup - 1) // 2
    r_S = np.r_[0.0, np.linspace(0.15, 0.9, n_pos) * Q_MAX, -np.linspace(0.1, 0.5, n_sup - 1 - n_pos) * Q_MAX]
    w_S = np.r_[8.0e5, rng.uniform(-0.05, 0.1, n_sup - 1) * 8.0e5]
    return ModifiedPI.with_log_creep(r_H=r_H, w_H=w_H, r_S=r_S, w_S=w_S, dt=dt, r_K=r_H, w_K=w_K, m=n_creep)


def rig_obj(rig: dict | None = None):
    from selfsense.io import parse_rig

    out = parse_rig(copy.deepcopy(rig or RIG))
    return out[0] if isinstance(out, tuple) else out


def estimator(dt: float = 1e-4, rig: dict | None = None):
    """A 'fitted' SelfSensingEstimator (hand-set coefficients of thesis eq. 52, H = GaugedH(ModifiedPI))."""
    from selfsense.sensing import SelfSensingEstimator, SensingConfig
    from selfsense.sensing.estimator import GaugedH

    rig = rig or RIG
    est = SelfSensingEstimator(config=SensingConfig(), rig=rig_obj(rig))
    est.hysteresis_ = GaugedH(operator(dt), sign=-1.0, c=2.0e4)
    n_A, C_p = rig["n_actuators"], rig["actuator_catalog"]["capacitance_f"]
    est.config.regression = "full"
    # free terms of eq. (46) (regression="full"), chosen so that dx and f mostly lie inside their ranges
    est.coef_ = {"A1": 20.0, "A2": 1.0e-5, "A3": 1500.0 * n_A, "B21": 1500.0, "B22": -4.0e-4,
                 "extra_dx": {}, "extra_f": {}}
    est.h_slope_ = 1.0 / (n_A * C_p)
    est.ranges_ = {"dx": [0.0, 6.0e-3], "f": [0.0, 0.2]}
    est.calibration_trials_ = []
    return est


def raw_log(n: int, fs: float = 1e4, start: int = 0, n_relay: int | None = None, seed: int = 0,
            rig: dict | None = None) -> pd.DataFrame:
    """Samples [start, start + n) of an endless raw DAQ log: 1 s relay (shorted) segment, then a 0.7 Hz
    raised-cosine drive with a 0.13 Hz amplitude modulation (returns to 0 V every cycle), in-amp offset + noise.
    Chunks generated separately concatenate to the same log (noise seeded per chunk start)."""
    rig = rig or RIG
    n_relay = int(fs) if n_relay is None else n_relay
    k = np.arange(start, start + n, dtype=np.float64)
    t = k / fs
    tt = np.clip(t - n_relay / fs, 0.0, None)
    w, wm = 2 * np.pi * 0.7, 2 * np.pi * 0.13
    amp = 3.5 * (0.7 + 0.3 * np.sin(wm * tt))
    u = amp * (1 - np.cos(w * tt))
    du = 3.5 * 0.3 * wm * np.cos(wm * tt) * (1 - np.cos(w * tt)) + amp * w * np.sin(w * tt)
    u[k < n_relay] = 0.0
    du[k < n_relay] = 0.0
    C = rig["n_actuators"] * rig["actuator_catalog"]["capacitance_f"]
    Vs = rig["shunt_resistance_ohm"] * C * rig["amplifier_gain"] * du * 1.1
    rng = np.random.default_rng([seed, start])
    v_shunt = rig["inamp_gain"] * Vs + 3e-4 + 1e-3 * rng.standard_normal(n)
    relay = (k < n_relay).astype(np.float64)
    return pd.DataFrame({"t": t, "u_cmd": u, "v_shunt": v_shunt, "relay": relay})


def batch_estimate(est, raw: pd.DataFrame) -> pd.DataFrame:
    """The batch pipeline on a raw log: io.to_si -> signals.prepare_trial (stages.ingest) -> estimator.estimate."""
    from selfsense.io.dataset import to_si
    from selfsense.signals import prepare_trial

    df = raw.copy()
    df["laser"] = np.nan
    df["load_cell"] = np.nan
    si = to_si(df, est.rig, "displacement")
    return est.estimate(prepare_trial(si, est.rig))
