"""The load link's stress member: a tip load that changes the actuator's hysteretic voltage (V_H scaled by the
tip force) makes the blocked tip's H differ from the free tip's. The member identifies the dependence on the blocked
calibration trial's force reference, jointly with H(q), carries it into every estimate by solving the force row and
the stress together, and is not adopted on the same device without the effect."""
from __future__ import annotations

import numpy as np
import pytest

from selfsense.chain.load import choose_load_ridge, stress_columns, stress_load, stress_voltage, stress_weight
from selfsense.gap.blind import FS_CASE, T_CASE, draw_tip_case
from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.counterfactual import _summary, tip_table
from selfsense.sensing import SelfSensingEstimator, SensingConfig

# case 1 of the gap diagnostic's tip campaign 4711 (a development case of the member): a Bouc-Wen device whose
# hysteretic voltage the tip load scales by 1 + m f / 0.1 N (simulator effect stress_hysteresis, m = 2.24: up to
# 1.7x at the blocked tip's 0.075 N); it costs Table 3 about 5 points against its twin
CASE = draw_tip_case(1, 4711)
S_TRUE = CASE["effects"]["load.stress_hysteresis"] * 0.1 / 0.1   # library magnitude x 0.1 -> m; s = m / 0.1 N


def test_the_closed_form_solves_the_force_row_and_the_stress_together():
    """V_p = Vp0 - w f and f = B21 Q + B22 V_p hold together on every sample whose solution lies in the force range,
    whatever the sign of 1 + B22 w; elsewhere the load is the nearer bound of the range (never a division blown up
    near 1 + B22 w = 0); the weight is s_H (H - a_H) + s_Q (Q - a_Q); the columns vanish on a free tip."""
    rng = np.random.default_rng(0)
    n = 4000
    Q, Vp0, H = rng.uniform(0, 1e-4, n), rng.uniform(-5, 120, n), rng.uniform(-30, 40, n)
    B21, B22 = -1.4e3, 4e-3
    w = stress_weight(H, Q, 15.0, -2e5, 3.0, 2e-5)
    np.testing.assert_allclose(w, 15.0 * (H - 3.0) - 2e5 * (Q - 2e-5))
    lo, hi = 0.0, 0.2
    Vp = stress_voltage(Q, Vp0, w, B21, B22, lo, hi)
    a, d = B21 * Q + B22 * Vp0, 1.0 + B22 * w
    exact = a / d
    inside = (exact >= lo) & (exact <= hi)
    assert (d < 0).any() and (d > 0).any() and inside.mean() > 0.2 and (~inside).any(), \
        "the test must exercise both signs of 1 + B22 w and both sides of the range"
    f = B21 * Q + B22 * Vp
    np.testing.assert_allclose(Vp[inside], Vp0[inside] - w[inside] * f[inside], rtol=0, atol=1e-9)
    np.testing.assert_allclose(f[inside], exact[inside], rtol=1e-9)
    held = np.where(exact < lo, lo, hi)[~inside]
    np.testing.assert_allclose(Vp[~inside], Vp0[~inside] - w[~inside] * held)
    assert np.all(stress_load(a, d, lo, hi) >= lo) and np.all(stress_load(a, d, lo, hi) <= hi)
    # 1 + B22 w = 0: the row holds for any load; never NaN; with a ridge the load is the least-squares one,
    # a d / (d^2 + ridge), shrunk towards 0 where d is small and equal to a / d where d^2 >> ridge
    assert stress_load(np.array([1.0, -1.0, 0.0]), np.zeros(3), lo, hi).tolist() == [lo, lo, lo]
    r = 0.03
    fr = stress_load(a, d, -np.inf, np.inf, r)
    np.testing.assert_allclose(fr, a * d / (d * d + r))
    big = np.abs(d) > 1.5
    np.testing.assert_allclose(fr[big], exact[big], rtol=0.02)
    small = np.abs(d) < 0.05
    assert small.any() and np.all(np.abs(fr[small]) < np.abs(exact[small]))
    # the ridge chosen on rows where the load is known: exact data pick no ridge, a row's noise near d = 0 a ridge
    f_true = rng.uniform(lo, hi, n)
    assert choose_load_ridge([(f_true * d, d, f_true)], lo, hi)[0] == 0.0
    noisy = f_true * d + rng.normal(0, 0.02, n)
    assert choose_load_ridge([(noisy, d, f_true)], lo, hi)[0] > 0.0
    np.testing.assert_array_equal(stress_columns(H, Q, np.zeros(n)), 0.0)
    np.testing.assert_array_equal(stress_voltage(Q, Vp0, np.zeros(n), B21, B22, lo, hi), Vp0)


@pytest.fixture(scope="module")
def stressed():
    tr, me, rig = simulate_family_case(CASE["family"], CASE["device_seed"], CASE["effects"], CASE["noise_seed"],
                                       T_CASE, FS_CASE)
    fits = {m: SelfSensingEstimator(config=SensingConfig(stress=m), rig=rig).fit(tr, me) for m in ("auto", "off")}
    return tr, me, rig, fits


def test_the_stress_member_is_adopted_recovers_the_load_dependence_and_the_tip_error(stressed):
    tr, me, rig, fits = stressed
    est, off = fits["auto"], fits["off"]
    st = est.stress_
    assert st["applied"] and st["source"] == "calibration", st
    assert st["cv_rms_v_with"] < 0.5 * st["cv_rms_v_without"]
    # s_H is the scale of H per newton: the simulator's m / 0.1 N within 40 % (first order in f, H_0 from the free
    # tip; the rest of the gauge is in s_Q)
    assert 0.6 * S_TRUE < st["s_h_per_n"] < 1.4 * S_TRUE, (st["s_h_per_n"], S_TRUE)
    t_auto = _summary(tip_table(tr, me, rig, None, estimator=est))["mean"]
    t_off = _summary(tip_table(tr, me, rig, None, estimator=off))["mean"]
    assert t_auto < 0.5 * t_off, (t_auto, t_off)
    assert not off.stress_["applied"] and off.stress_weights() == (0.0, 0.0)
    assert SensingConfig().stress == "off" and SensingConfig.from_mapping({"stress": False}).stress == "off"
    # the member travels with the model file and gives the same estimate
    again = SelfSensingEstimator.from_dict(est.to_dict(), rig)
    df = tr["val_force"]
    np.testing.assert_array_equal(again.estimate(df)["f_hat"].to_numpy(), est.estimate(df)["f_hat"].to_numpy())
    # and it is what the estimate carries: with the weights zeroed the contact trial's force moves
    again.stress_ = {**again.stress_, "applied": False}
    assert np.max(np.abs(again.estimate(df)["f_raw"].to_numpy() - est.estimate(df)["f_raw"].to_numpy())) > 1e-3


def test_the_stress_member_is_not_adopted_on_the_device_without_the_effect():
    tr, me, rig = simulate_family_case(CASE["family"], CASE["device_seed"], {}, CASE["noise_seed"], T_CASE, FS_CASE)
    est = SelfSensingEstimator(config=SensingConfig(stress="auto"), rig=rig).fit(tr, me)
    assert not est.stress_["applied"], est.stress_
    assert "not supported" in est.stress_["note"]
