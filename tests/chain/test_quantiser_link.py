"""The charge link's quantiser member: where the shunt channel's noise does not dither its ADC step, the relay short
reads one code and the subtracted in-amp offset is off by up to half a step; every sample that reads another code
carries that error as a current. The member finds the current on the calibration rows, takes it out of Q, and is not
adopted where the channel is dithered."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from selfsense.chain.charge import charge_resolution, quantiser_column
from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.counterfactual import _summary, tip_table
from selfsense.sensing import SelfSensingEstimator, SensingConfig
from selfsense.signals import charge_from_shunt


def test_an_undithered_short_leaves_a_current_on_the_samples_off_its_code():
    """Synthetic channel: 1 mV ADC step, in-amp offset 0.3 steps, noise 0.05 steps (undithered), a drive with a 6 s
    hold at zero current. The measured minus the true charge is the short's offset error over R times the member's
    column (R^2 > 0.98, slope within 5 %), where a ramp in time fits worse."""
    rng = np.random.default_rng(3)
    dt, R, step, o = 1e-3, 1000.0, 1e-3, 0.3e-3
    t = np.arange(20_000) * dt
    relay = (t < 0.5).astype(float)
    i = np.where((t >= 0.5) & (t < 8.0), 3e-6 * np.sin(2 * np.pi * 0.7 * (t - 0.5)), 0.0)
    i += np.where(t >= 14.0, 2e-6 * np.sin(2 * np.pi * 1.1 * (t - 14.0)), 0.0)
    Vs = step * np.round((R * i + o + 0.05 * step * rng.standard_normal(t.size)) / step)
    q, off = charge_from_shunt(t, Vs, relay, R)
    q_true, _ = charge_from_shunt(t, R * i, relay, R, offset=None)
    err = q - q_true
    col = quantiser_column(pd.DataFrame({"t": t, "V_s": Vs, "relay": relay}), 0.5 * step)
    e_over_r = (o - off) / R                         # 0.3 steps: the short reads code 0
    assert off == 0.0 and np.isclose(e_over_r, 0.3e-6)
    slope = float(col @ err / (col @ col))
    r2 = 1 - np.sum((err - slope * col) ** 2) / np.sum((err - err.mean()) ** 2)
    assert r2 > 0.98 and abs(slope / e_over_r - 1) < 0.05, (r2, slope)
    ramp = np.where(relay < 0.5, t - 0.5, 0.0)
    r2_ramp = 1 - np.sum((err - float(ramp @ err / (ramp @ ramp)) * ramp) ** 2) / np.sum((err - err.mean()) ** 2)
    assert r2_ramp < r2
    assert col[relay > 0.5].max() == 0.0 and np.all(np.diff(col[t >= 0.5]) >= 0)


def _whole_device(family, preset, seed):
    """A device of the whole-device benchmark on the thesis protocol (selfsense.devices.run_device's data), with the
    simulator's truth beside it."""
    from selfsense.devices import device_scenario, simulate_device

    return simulate_device(device_scenario(family, preset, seed, "thesis", "device"), with_truth=True)


def _true_current(tr, truth, half_step_v) -> float:
    """The simulator's offset current as the member would see it: the measured-minus-true charge of every trial
    (after its relay short) regressed on the member's column (an oracle: the simulator's truth)."""
    num = den = 0.0
    for t, df in tr.items():
        m = df["relay"].to_numpy() < 0.5
        e = df["q"].to_numpy() - truth[t]["q"].to_numpy()
        e = e - e[np.argmax(m)]
        col = quantiser_column(df, half_step_v)
        num, den = num + float(col[m] @ e[m]), den + float(col[m] @ col[m])
    return num / den


@pytest.fixture(scope="module")
def coarse():
    # generalised PI, clean preset, seed 4 of the whole-device benchmark: a 12-bit shunt channel whose noise does not
    # dither its step (one of the devices the member was measured on, docs/method.md 1b')
    return _whole_device("gpi", "clean", 4)


@pytest.fixture(scope="module")
def device():
    tr, me, rig, truth = simulate_family_case("preisach", 11, {}, 5, with_truth=True)
    return tr, me, rig, truth


def _fit(tr, me, rig, mode="auto", quantiser="auto", **cfg):
    # "auto" (the default) lets the calibration decide; "off" never applies the member
    return SelfSensingEstimator(config=SensingConfig(quantiser=quantiser, **cfg), rig=rig,
                                members={"quantiser": mode}).fit(tr, me)


@pytest.fixture(scope="module")
def fitted(coarse):
    tr, me, rig, _ = coarse
    # one H(q) kind (the Preisach grids of the registry) instead of the whole selection: the member does not depend
    # on it (the same current and Table 3 as with h_model auto), and the fixture takes 166 s instead of 236 s here
    return _fit(tr, me, rig, h_model="preisach"), _fit(tr, me, rig, "off", h_model="preisach")


def test_member_finds_the_current_and_lowers_table3_on_an_undithered_channel(coarse, fitted):
    tr, me, rig, truth = coarse
    est, off = fitted
    R = float(rig.shunt_resistance_ohm)
    assert not charge_resolution(tr["cal_free_sine"], R)[0].dithered
    qz = est.quantiser_
    assert qz["applied"] and qz["supported"] and qz["cv_rms_m_with"] < qz["cv_rms_m_without"]
    # the true offset current (oracle, the simulator's truth; 444 nA)
    i_true = _true_current(tr, truth, qz["half_step_v"])
    assert abs(qz["i_q_a"] / i_true - 1) < 0.15, (qz["i_q_a"], i_true)                 # 412 nA measured
    assert abs(qz["i_q_a"]) <= 0.5 * qz["current_step_a"] * (1 + 1e-12)
    on = _summary(tip_table(tr, me, rig, None, estimator=est))["mean"]
    without = _summary(tip_table(tr, me, rig, None, estimator=off))["mean"]
    assert on < 0.5 * without, (on, without)                                             # 1.66 against 8.18 measured


def test_not_adopted_on_a_dithered_channel_and_the_fit_is_bit_identical(device):
    tr, me, rig, _ = device
    a, b = _fit(tr, me, rig, "auto"), _fit(tr, me, rig, "off")
    assert not a.quantiser_["applied"] and "dithers" in a.quantiser_["note"]
    for t in ("val_disp", "val_force"):
        pa, pb = a.estimate(tr[t]), b.estimate(tr[t])
        assert np.array_equal(pa["dx_hat"].to_numpy(), pb["dx_hat"].to_numpy())
        assert np.array_equal(pa["f_hat"].to_numpy(), pb["f_hat"].to_numpy())


def test_stream_and_model_json_carry_the_member_and_config_turns_it_off(coarse, fitted):
    from selfsense.gap.counterfactual import adopted_members
    from selfsense.sensing.export_c import c_sources
    from selfsense.sensing.streaming import SelfSensingStream

    co, me, rig, _ = coarse
    est = fitted[0]
    assert est.quantiser_["applied"] and adopted_members(est)["quantiser"]
    assert "Q_I" in c_sources(est, rig, float(np.median(np.diff(co["val_force_large_mixed"]["t"]))))[1]
    assert not est.offset_drift_ and not est.amplifier_.get("applied")   # members a plain stream refuses
    for t in ("val_force_large_mixed", "val_disp_free_mixed"):
        df = co[t]
        out = SelfSensingStream(est, dt=float(np.median(np.diff(df["t"])))).process(
            df["u_cmd"].to_numpy(), df["V_s"].to_numpy() * float(rig.inamp_gain), df["relay"].to_numpy(), full=True)
        batch = est.estimate(df)
        for c in ("dx_hat", "f_hat"):
            rng = float(np.ptp(batch[c])) or 1.0
            assert np.max(np.abs(out[c] - batch[c].to_numpy())) < 1e-9 * rng, (t, c)
    back = SelfSensingEstimator.from_dict(est.to_dict(), rig)
    df = co["val_force_large_mixed"]
    assert np.array_equal(back.estimate(df)["f_hat"].to_numpy(), est.estimate(df)["f_hat"].to_numpy())
    off = SelfSensingEstimator(config=SensingConfig(quantiser="off"), rig=rig)
    off._quantiser_link(co, me)
    assert not off.quantiser_["applied"] and "config quantiser: off" in off.quantiser_["note"]
    with pytest.raises(ValueError, match="SensingConfig.quantiser"):
        SensingConfig(quantiser="on")
    with pytest.raises(ValueError, match="V_s column"):
        est.estimate(df.drop(columns=["V_s"]))


def _synthetic_free_trial(g=5e-9, drift=0.0, o_steps=0.3, levels=True, seed=3):
    """A free-tip trial on an undithered shunt channel (1 mV step over 1 kohm: 500 nA of bound, noise 0.05 steps):
    a 0.4 Hz sine whose amplitude changes every cycle (``levels``) or stays, the in-amp offset ``o_steps`` of a step
    (drifting by ``drift`` V/s), a leakage ``g`` [S]; the laser follows the actuators' charge. Returns the prepared
    frame, the true offset current (the short's rounding error over R), the half step and the bound."""
    rng = np.random.default_rng(seed)
    dt, R, step, C = 1e-3, 1000.0, 1e-3, 1e-6
    t = np.arange(30_000) * dt
    relay = (t < 0.5).astype(float)
    amp = np.array([1.0, 0.4, 0.8, 0.25, 0.6, 1.0, 0.3, 0.7, 0.5, 0.9, 0.35, 0.75])
    A = amp[np.minimum(((t - 0.5).clip(0) // 2.5).astype(int), amp.size - 1)] if levels else 1.0
    V = np.where(t >= 0.5, A * 60.0 * (1 - np.cos(2 * np.pi * 0.4 * (t - 0.5))), 0.0)
    q_true = C * V
    i = np.gradient(q_true, dt) + g * V
    o = o_steps * step + drift * np.clip(t - 0.5, 0, None)
    Vs = step * np.round((R * i + o + 0.05 * step * rng.standard_normal(t.size)) / step)
    q, off = charge_from_shunt(t, Vs, relay, R)
    dx = 2.0 * q_true + 1e-7 * rng.standard_normal(t.size)
    df = pd.DataFrame({"t": t, "q": q, "V": V, "V_s": Vs, "relay": relay,
                       "dx_ref": np.where(relay > 0.5, np.nan, dx)})
    return df, (o_steps * step - off) / R, 0.5 * step, 0.5 * step / R


@pytest.mark.parametrize("kw", [{}, {"g": 0.0}, {"drift": 2e-6}, {"o_steps": -0.4}, {"o_steps": 0.0}])
def test_the_laser_rows_find_the_current_beside_leakage_and_drift(kw):
    """On a drive of several amplitudes the free-tip laser rows separate the member's column from a leakage current
    (int V dt) and an offset drift (t^2): the current is found within 10 % of its bound (2.6-7.9 % measured), the CV
    folds agree on it, and with a current the held-out RMS falls."""
    from selfsense.chain.charge import QUANTISER_FOLD_SPREAD, fit_quantiser

    df, i_true, half, bound = _synthetic_free_trial(**kw)
    f = fit_quantiser({"cal": df}, half)
    assert abs(f.i_q_a - i_true) < 0.1 * bound, (f.i_q_a, i_true)
    assert np.ptp(f.i_q_folds_a) < QUANTISER_FOLD_SPREAD * bound
    if abs(i_true) > 0.2 * bound:
        assert f.cv_rms_m_with < 0.5 * f.cv_rms_m_without


def test_a_drive_of_one_amplitude_does_not_separate_the_column():
    """On a sine of constant amplitude the leakage column, the drift and the member's column are all ramps in time:
    the fold currents scatter over more than the bound (1-4 bounds measured), whatever the full fit says."""
    from selfsense.chain.charge import QUANTISER_FOLD_SPREAD, fit_quantiser

    for kw in ({}, {"o_steps": -0.4}):
        df, i_true, half, bound = _synthetic_free_trial(levels=False, **kw)
        f = fit_quantiser({"cal": df}, half)
        assert np.ptp(f.i_q_folds_a) > QUANTISER_FOLD_SPREAD * bound, f.i_q_folds_a


@pytest.mark.parametrize("case", ["at_bound", "spread", "worse"])
def test_the_gate_refuses_a_current_it_cannot_trust(coarse, monkeypatch, case):
    """The estimator's gate on the identified current (auto): beyond 0.99 of the bound, fold currents spread over more
    than half the bound, or a column that makes the held-out laser RMS worse: not adopted, the trials unchanged and
    the note naming the reason; "on" still applies it (clipped to the bound)."""
    from selfsense.chain import charge

    tr, me, rig, _ = coarse
    R = float(rig.shunt_resistance_ohm)
    half = 0.5 * charge_resolution(tr["cal_free_sine"], R)[0].step_v
    bound = half / R
    i_q, folds, cv1 = {"at_bound": (1.2 * bound, [1.2 * bound] * 5, 0.5), "spread": (0.3 * bound,
                       [-0.5 * bound, 0.3 * bound, 0.9 * bound, 0.2 * bound, 0.3 * bound], 0.5),
                       "worse": (0.3 * bound, [0.3 * bound] * 5, 1.1)}[case]
    fake = charge.QuantiserFit(i_q_a=i_q, i_q_folds_a=folds, cv_rms_m_without=1.0, cv_rms_m_with=cv1, n_rows=100,
                               trials=["cal_free_sine"], note="")
    monkeypatch.setattr(charge, "fit_quantiser", lambda *a, **k: fake)
    est = SelfSensingEstimator(config=SensingConfig(quantiser="auto"), rig=rig, members={"quantiser": "auto"})
    out = est._quantiser_link(tr, me)
    qz = est.quantiser_
    assert not qz["applied"] and not qz["supported"]
    assert {"at_bound": "bound", "spread": "spread", "worse": "RMS with the column"}[case] in qz["note"]
    assert all(out[t] is tr[t] for t in tr)
    forced = SelfSensingEstimator(config=SensingConfig(quantiser="auto"), rig=rig, members={"quantiser": "on"})
    forced._quantiser_link(tr, me)
    assert forced.quantiser_["applied"] and abs(forced.quantiser_["i_q_a"]) <= bound


def test_the_laser_rows_find_the_current_where_the_reference_h_search_went_to_its_bound():
    """On a rate-dependent device (KP family, clean, whole-device seed 6, a 12-bit undithered channel) the earlier
    member searched the current with a rate-independent reference H(q) and ended at its bound (the true current is
    0.62 of it; forced on, Table 3 displacement went from 19.6 to 71.4 %). The free-tip laser rows involve no H(q):
    they find the true current within 10 % of the bound, and the gate adopts it."""
    tr, me, rig, truth = _whole_device("rate_kp", "clean", 6)
    est = SelfSensingEstimator(config=SensingConfig(quantiser="auto"), rig=rig, members={"quantiser": "auto"})
    est._quantiser_link(est._voltage_link(tr, me), me)
    qz = est.quantiser_
    bound = 0.5 * qz["current_step_a"]
    i_true = _true_current(tr, truth, qz["half_step_v"])
    assert abs(i_true) > 0.3 * bound
    assert abs(qz["i_q_a"] - i_true) < 0.1 * bound, (qz["i_q_a"], i_true, bound)
    assert qz["applied"] and qz["supported"] and not qz["at_bound"]
