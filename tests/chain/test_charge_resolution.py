"""Resolution of the charge measurement (selfsense.chain.charge.charge_resolution): an ADC step that the noise does
not dither biases the mean of a constant current, and that bias integrates over the relay short and the holds."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from selfsense.chain.charge import DITHER_MIN_STEPS, charge_resolution, quantisation_step
from selfsense.signals.charge import charge_from_shunt

R = 1000.0          # shunt [ohm]
STEP = 1.1e-3       # ADC step of V_s [V]: 1.1 uA over 1 kohm
C = 3e-6            # actuator capacitance [F]
FS = 1000.0


def _trial(offset_v: float, noise_steps: float, seed: int) -> tuple[pd.DataFrame, np.ndarray]:
    """Relay 0.5 s, ramp to 120 V, hold 6 s, ramp to 0 V, hold 6 s: the shunt sees C dV/dt, a relaxation current
    after each ramp (random amplitude up to two ADC steps, 1.5 s), an in-amp offset, noise and the ADC's rounding.
    Returns the prepared trial and the true charge."""
    t = np.arange(0.0, 14.5, 1.0 / FS)
    V = np.interp(t, [0.0, 0.5, 1.5, 7.5, 8.5, 14.5], [0.0, 0.0, 120.0, 120.0, 0.0, 0.0])
    relay = (t < 0.5).astype(float)
    rng = np.random.default_rng(seed)
    i = C * np.gradient(V, t)
    for t_end, sign in ((1.5, 1.0), (8.5, -1.0)):
        i += sign * rng.uniform(0.0, 2.0) * STEP / R * np.exp(-(t - t_end) / 1.5) * (t >= t_end)
    vs_true = R * i + offset_v
    vs = np.round((vs_true + noise_steps * STEP * rng.standard_normal(t.size)) / STEP) * STEP
    q, _ = charge_from_shunt(t, vs, relay, R)
    q_true, _ = charge_from_shunt(t, R * i, relay, R, offset=0.0)
    return pd.DataFrame({"t": t, "V": V, "q": q, "relay": relay, "V_s": vs}), q_true


def test_quantisation_step_is_found_and_float_records_are_not_quantised():
    rng = np.random.default_rng(1)
    x = np.round(rng.normal(0.0, 20 * STEP, 5000) / STEP) * STEP + 0.37 * STEP   # an offset lattice
    assert quantisation_step(x) == pytest.approx(STEP, rel=1e-6)
    assert quantisation_step(rng.normal(0.0, 1.0, 5000)) == 0.0          # floating-point data
    assert quantisation_step(np.zeros(100)) == 0.0                       # a constant is no lattice


def test_undithered_channel_predicts_the_spread_of_the_charge_error():
    """Over random in-amp offsets (where the true value sits between two steps), the SD of the charge error at the
    end of the trial is the one predicted from the relay short and the two holds (uniform bias, +- half a step)."""
    ends, preds = [], []
    rng = np.random.default_rng(7)
    for k in range(120):
        df, q_true = _trial(offset_v=rng.uniform(0.0, STEP), noise_steps=0.1, seed=k)
        res, sig = charge_resolution(df, R)
        assert not res.dithered
        assert res.step_v == pytest.approx(STEP, rel=1e-6)
        assert res.current_step_a == pytest.approx(STEP / R, rel=1e-6)
        assert res.n_holds >= 2 and res.unresolved_hold_s > 10.0
        assert np.all(sig[df["relay"].to_numpy() >= 0.5] == 0.0) and np.all(np.diff(sig[500:]) >= -1e-18)
        ends.append(df["q"].to_numpy()[-1] - q_true[-1])
        preds.append(res.sigma_q_end_c)
    sd = float(np.std(ends))
    pred = float(np.median(preds))
    # the error of a hold depends on how far its current sits from the short's, which the channel cannot see: the
    # uniform-bias model is an estimate of the scale of the spread (measured here: the spread is 0.72 of it), not a bound
    assert 0.3 * pred < sd < 1.5 * pred, (sd, pred)


def test_dithered_channel_is_resolved():
    ends, preds = [], []
    rng = np.random.default_rng(3)
    for k in range(40):
        df, q_true = _trial(offset_v=rng.uniform(0.0, STEP), noise_steps=1.0, seed=100 + k)
        res, sig = charge_resolution(df, R)
        assert res.dithered and res.relay_noise_steps >= DITHER_MIN_STEPS and res.unresolved_hold_s == 0.0
        ends.append(df["q"].to_numpy()[-1] - q_true[-1])
        preds.append(res.sigma_q_end_c)
    # the dither makes the offset's mean unbiased: what is left is its statistical error over the 500 samples of the
    # short, integrated over the trial, as predicted; far below half a step over the 12 s of holds
    sd, pred = float(np.std(ends)), float(np.median(preds))
    assert 0.7 * pred < sd < 1.3 * pred, (sd, pred)   # measured: 0.94
    assert pred < 0.2 * (STEP / R / np.sqrt(12)) * 12.0


def test_records_without_a_quantised_shunt_channel():
    df, _ = _trial(offset_v=0.3 * STEP, noise_steps=0.1, seed=0)
    res, sig = charge_resolution(df.drop(columns="V_s"), R)
    assert "no shunt-voltage record" in res.note and not sig.any()
    df["V_s"] = df["V_s"] + 1e-7 * np.random.default_rng(0).standard_normal(len(df))   # not on a lattice
    res, sig = charge_resolution(df, R)
    assert res.step_v == 0.0 and "not quantised" in res.note and not sig.any()
