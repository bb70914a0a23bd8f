"""Charge integration (thesis 000_18d138f03f1777c3.txt eq. 57), actuator voltage (eq. 56), Fig. 24 post-processing."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from selfsense.signals import (SignalError, actuator_voltage, charge_from_shunt, limit_to_range, prepare_trial,
                               relay_offset, sliding_dc_offset)

R = 1000.0


def _reference_charge(t, V_s, relay, R, off):
    """Plain loop version of eq. (57) with reset while relay == 1."""
    q = np.zeros(len(t))
    for k in range(1, len(t)):
        if relay[k] == 1:
            q[k] = 0.0
        else:
            q[k] = q[k - 1] + 0.5 * ((V_s[k] - off) + (V_s[k - 1] - off)) / R * (t[k] - t[k - 1])
    return q


def TRAPZ_BOUND(dt, I0=2e-4, f=1.3):
    """Composite trapezoid error of integral I0 sin(w t): |dt^2/12 * (I'(T) - I'(0))| <= dt^2/12 * 2 I0 w."""
    return dt**2 / 12 * 2 * I0 * 2 * np.pi * f * 1.001


def _sine_case(fs=1000.0, n=3000, n_relay=300, I0=2e-4, f=1.3, offset=0.0):
    t = np.arange(n) / fs
    t0 = t[n_relay]
    I = np.where(t >= t0, I0 * np.sin(2 * np.pi * f * (t - t0)), 0.0)
    relay = (np.arange(n) < n_relay).astype(float)
    q_true = np.where(t >= t0, I0 / (2 * np.pi * f) * (1 - np.cos(2 * np.pi * f * (t - t0))), 0.0)
    return t, R * I + offset, relay, q_true


def test_known_current_integrates_to_analytic_charge():
    t, V_s, relay, q_true = _sine_case()
    q, off = charge_from_shunt(t, V_s, relay, R)
    assert off == 0.0
    err = np.max(np.abs(q - q_true))
    assert err <= TRAPZ_BOUND(1e-3)
    assert np.ptp(q_true) == pytest.approx(2 * 2e-4 / (2 * np.pi * 1.3))
    # second order: halving dt quarters the error
    t2, V2, r2, qt2 = _sine_case(fs=2000.0, n=6000, n_relay=600)
    err2 = np.max(np.abs(charge_from_shunt(t2, V2, r2, R)[0] - qt2))
    assert err / err2 == pytest.approx(4.0, rel=0.02)


def test_linear_current_exact_on_nonuniform_grid():
    rng = np.random.default_rng(3)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 999))])
    relay = np.zeros(t.size)
    relay[0] = 1
    a = 3e-3  # A/s
    V_s = R * a * (t - t[0])
    q, _ = charge_from_shunt(t, V_s, relay, R)
    np.testing.assert_allclose(q, a * (t - t[0]) ** 2 / 2, rtol=1e-12, atol=1e-18)


def test_offset_removed_from_relay_segment():
    off = 0.3e-3  # 0.3 mV after the in-amp
    t, V_s, relay, q_true = _sine_case(offset=off)
    q, est = charge_from_shunt(t, V_s, relay, R)
    assert est == pytest.approx(off, rel=1e-12)
    assert np.max(np.abs(q - q_true)) <= TRAPZ_BOUND(1e-3)
    # without offset removal the error is exactly the ramp off/R * (t - t0)
    q_raw, z = charge_from_shunt(t, V_s, relay, R, offset=None)
    assert z == 0.0
    t0 = t[relay == 0][0] - 1e-3
    drift = np.where(relay == 0, off / R * (t - t0), 0.0)
    np.testing.assert_allclose(q_raw - q, drift, rtol=1e-9, atol=1e-15)
    assert drift[-1] > 0.015 * np.ptp(q_true)  # the drift matters: 1.7 % of the charge range within 2.7 s
    # an explicit offset works the same
    q_fix, z = charge_from_shunt(t, V_s, relay, R, offset=off)
    np.testing.assert_allclose(q_fix, q, rtol=0, atol=1e-18)


def test_offset_uses_first_relay_segment_only():
    relay = np.array([1, 1, 1, 0, 0, 1, 1, 0], float)
    V_s = np.array([1, 2, 3, 9, 9, 50, 60, 9], float)
    assert relay_offset(V_s, relay) == 2.0


def test_reset_during_relay_and_restart():
    t, V_s, relay, _ = _sine_case(offset=0.0)
    relay[1500:1600] = 1.0
    # a V_s reading while shorted (e.g. discharge transient) must not leak into q
    V_s = V_s.copy()
    V_s[1500:1600] += 0.5
    q, off = charge_from_shunt(t, V_s, relay, R, offset=0.0)
    assert np.all(q[relay == 1] == 0.0)
    np.testing.assert_allclose(q, _reference_charge(t, V_s, relay, R, 0.0), rtol=1e-10, atol=1e-16)
    # after the relay opens again the charge restarts from 0 with the trapezoid of the first step
    k = 1600
    assert q[k] == pytest.approx(0.5 * (V_s[k] + V_s[k - 1]) / R * (t[k] - t[k - 1]))


@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), n=st.integers(2, 300), off=st.floats(-1e-2, 1e-2))
def test_vectorised_equals_reference_loop(seed, n, off):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(1e-4, 2e-3, n))
    V_s = rng.normal(size=n)
    relay = (rng.uniform(size=n) < 0.2).astype(float)
    relay[0] = 1.0
    q, _ = charge_from_shunt(t, V_s, relay, R, offset=off)
    np.testing.assert_allclose(q, _reference_charge(t, V_s, relay, R, off), rtol=1e-9, atol=1e-12)


def test_no_relay_segment_is_a_clear_error():
    t, V_s, relay, _ = _sine_case()
    with pytest.raises(SignalError, match="no relay == 1"):
        charge_from_shunt(t, V_s, np.zeros_like(relay), R)
    q, _ = charge_from_shunt(t, V_s, np.zeros_like(relay), R, offset=None)  # explicit: integrate from t[0]
    assert q[0] == 0.0


@pytest.mark.parametrize("kw,msg", [
    (dict(R=0.0), "R must be finite and > 0"),
    (dict(R=-5.0), "R must be finite and > 0"),
    (dict(offset="mean"), "offset must be"),
])
def test_bad_arguments(kw, msg):
    t, V_s, relay, _ = _sine_case(n=400, n_relay=10)
    args = dict(R=R)
    args.update(kw)
    with pytest.raises(SignalError, match=msg):
        charge_from_shunt(t, V_s, relay, **args)
    with pytest.raises(SignalError, match="strictly increasing"):
        charge_from_shunt(t[::-1], V_s, relay, R)
    with pytest.raises(SignalError, match="only 0 and 1"):
        charge_from_shunt(t, V_s, relay * 2, R)


def test_actuator_voltage_eq56():
    V_c = np.array([0.0, 100.0, 150.0])
    V_s = np.array([0.0, 0.5, -0.2])
    np.testing.assert_array_equal(actuator_voltage(V_c, V_s), [0.0, 99.5, 150.2])
    with pytest.raises(SignalError):
        actuator_voltage(V_c, V_s[:2])


def test_limit_to_range():
    x = np.array([-1.0, 0.5, 2.0, np.nan])
    np.testing.assert_array_equal(limit_to_range(x, 0.0, 1.0), [0.0, 0.5, 1.0, np.nan])
    with pytest.raises(SignalError):
        limit_to_range(x, 1.0, 0.0)


def test_sliding_dc_offset_fig24():
    """Drift removed: the offset resets to the current value whenever the input is zero."""
    n = 1000
    t = np.arange(n) * 1e-3
    u = np.where((t % 0.25) < 0.05, 0.0, 5.0)  # input returns to zero every 0.25 s
    true = np.where(u > 0, 1e-3, 0.0)
    drift = 4e-4 * t  # slow drift of the estimate [m]
    x = true + drift
    y, off = sliding_dc_offset(x, u, return_offset=True)
    assert np.all(y[u == 0] == 0.0)
    # remaining error = drift accumulated since the last zero-input sample: at most 4e-4 * 0.2 s
    assert np.max(np.abs(y - true)) <= 4e-4 * 0.2 + 1e-15
    assert np.max(np.abs(x - true)) > 3.9e-4  # and it was larger before
    # before the first zero-input sample the offset is 0
    y2 = sliding_dc_offset(x, np.r_[np.full(10, 5.0), u[10:]])
    np.testing.assert_array_equal(y2[:10], x[:10])


def _load_io_conftest():
    spec = importlib.util.spec_from_file_location("_io_synth", Path(__file__).parents[1] / "io" / "io_factory.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_prepare_trial_recovers_capacitance(tmp_path):
    """On the synthetic free-tip trial V_s = R C dV_c/dt (plus a 0.3 mV in-amp output offset), so the
    integrated charge must equal C_total * V_c, C_total = n_A * C_p = 1.25 uF."""
    from selfsense.io import load_rig, trial_signals

    synth = _load_io_conftest()
    d = synth.make_dataset(tmp_path)
    rig = load_rig(d)
    pr = prepare_trial(trial_signals(d, "free_sine", rig=rig), rig)
    assert list(pr.columns) == ["t", "V", "q", "u_cmd", "relay", "dx_ref", "f_ref", "V_c", "V_s"]
    C = rig.n_actuators * rig.actuator_catalog.capacitance_f
    np.testing.assert_allclose(pr["V"], pr["V_c"] - pr["V_s"], rtol=0, atol=0)
    assert pr.attrs["v_s_offset_v"] == pytest.approx(3e-4 / rig.inamp_gain, abs=2e-5)
    err = np.max(np.abs(pr["q"] - C * pr["V_c"]))
    assert err < 1e-3 * np.ptp(C * pr["V_c"])
    C_fit = np.polyfit(pr["V_c"], pr["q"], 1)[0]
    assert C_fit == pytest.approx(C, rel=1e-3)
