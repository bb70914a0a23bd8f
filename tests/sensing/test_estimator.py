"""The estimator recovers tip displacement and force when the data follow its own model class.

Data: the tweezer's exact static mechanics (thesis eq. 45, selfsense.mechanics) with a known play-type hysteresis
H_true(q) (thesis eq. 32) in the electrical domain. Then thesis eq. (52) with the eq. (55) convention is exact
(see the derivation in selfsense.sensing.estimator), so the only error left is the H(q) fit.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from selfsense.mechanics.device import default_tweezer_mechanics
from selfsense.sensing import CalibrationError, SelfSensingEstimator, SensingConfig

FS = 1000.0
#: the thesis identification (H of the modified PI on the free-tip trial, no drift compensation): the data below
#: follow exactly its model class
LEGACY = {"h_model": "modified_pi", "h_identification": "thesis", "drift": "off"}

RIG = {
    "n_actuators": 5,
    "amplifier_gain": 15.0,
    "actuator_catalog": {"capacitance_f": 0.25e-6, "blocked_force_n": 240.0, "max_voltage_v": 150.0,
                         "free_displacement_m": 10e-6},
    "tip_free_displacement_m": 6.3e-3,
}


def _play(x, r, y0=0.0):
    y = np.empty_like(x)
    prev = y0
    for k, xk in enumerate(x):
        prev = max(xk - r, min(xk + r, prev))
        y[k] = prev
    return y


def _h_true(Q):
    qmax = 4e-4
    out = np.zeros_like(Q)
    for i, w in enumerate([0.0, 30e3, 20e3, 12e3, 8e3]):
        out += w * _play(Q, i * qmax / 6)
    return out


def _drive(kind, n):
    t = np.arange(n) / FS
    if kind == "sine":
        amp = np.interp(t, [0, t[-1]], [150, 80])
        v = amp * 0.5 * (1 - np.cos(2 * np.pi * 0.5 * t))
    else:
        v = np.clip(np.interp(t % 4, [0, 1, 2, 3, 4], [0, 150, 150, 40, 0]), 0, 150)
    return t, v


def _trial(kind, env, n=6000, relay_n=300):
    dev = default_tweezer_mechanics()
    t, vp = _drive(kind, n)
    vp[:relay_n] = 0.0
    if env == "free":
        sol = dev.solve(vp)
    elif env == "blocked":
        sol = dev.solve(vp, blocked=True)
    else:
        sol = dev.solve(vp, k_env=200.0, gap=3e-3)
    Q = np.asarray(sol["q"], float)
    V = vp + _h_true(Q)
    relay = np.zeros(n)
    relay[:relay_n] = 1
    return pd.DataFrame({"t": t, "V": V, "q": Q, "u_cmd": V / 15.0, "relay": relay,
                         "dx_ref": np.asarray(sol["dx_tip"], float), "f_ref": np.asarray(sol["f_tip"], float),
                         "V_c": V, "V_s": 0.0 * V})


@pytest.fixture(scope="module")
def data():
    trials = {
        "cal_free": _trial("sine", "free"),
        "cal_block": _trial("sine", "blocked"),
        "val_obj_d": _trial("mixed", "object"),
        "val_free": _trial("mixed", "free"),
        "val_block": _trial("mixed", "blocked"),
    }
    meta = pd.DataFrame([
        ("cal_free", "calibration", "free", "displacement"),
        ("cal_block", "calibration", "blocked", "force"),
        ("val_obj_d", "validation", "object", "displacement"),
        ("val_free", "validation", "free", "displacement"),
        ("val_block", "validation", "blocked", "force"),
    ], columns=["trial", "role", "tip", "reference"]).set_index("trial")
    meta["signal"] = "sine"
    return trials, meta


def _pct(est, ref):
    return float(np.mean(np.abs(est - ref)) / (ref.max() - ref.min()) * 100)


@pytest.mark.parametrize("mode", ["thesis", "onsite"])
def test_recovers_displacement_and_force_on_unseen_loads(data, mode):
    trials, meta = data
    cfg = SensingConfig(h_mode=mode, n_play=12, n_sup=6, n_creep=0, creep=False, dc_offset=False, limit=False, **LEGACY)
    est = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    obj = est.estimate(trials["val_obj_d"])
    blk = est.estimate(trials["val_block"])
    ref = trials["val_obj_d"]
    assert _pct(obj["dx_hat"].to_numpy(), ref["dx_ref"].to_numpy()) < 3.0
    # force on a contact trial: zero before contact, then the object's reaction
    assert _pct(obj["f_hat"].to_numpy(), ref["f_ref"].to_numpy()) < 5.0
    assert _pct(blk["f_hat"].to_numpy(), trials["val_block"]["f_ref"].to_numpy()) < 5.0


def test_physical_coefficients_match_eq_47_48_53(data):
    """With a perfect H the regressed A1 agrees with the mechanics' closed form up to the eq. (55) convention."""
    trials, meta = data
    cfg = SensingConfig(n_play=12, n_sup=6, n_creep=0, creep=False, dc_offset=False, limit=False, **LEGACY)
    est = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    dev = default_tweezer_mechanics()
    M = dev.tip_matrix("contract")
    Cp_cat = RIG["actuator_catalog"]["capacitance_f"]
    # force row: f = M11 (V_p_est - Q/(n Cp_cat))  =>  A3 = -M11 / Cp_cat  (derivation in the module docstring)
    assert est.coef_["A3"] == pytest.approx(-M[1, 1] / Cp_cat, rel=0.05)
    # displacement row: dx = (M00 - M01 M10/M11 - M01/(n Cp_cat)) Q + M01 V_p_est
    assert est.coef_["A2"] == pytest.approx(M[0, 1], rel=0.05)
    n = RIG["n_actuators"]
    A1 = M[0, 0] - M[0, 1] * M[1, 0] / M[1, 1] - M[0, 1] / (n * Cp_cat)
    assert est.coef_["A1"] == pytest.approx(A1, rel=0.05)


def test_validation_trials_never_used_for_fitting(data):
    trials, meta = data
    cfg = SensingConfig(n_play=8, n_sup=4, n_creep=0, creep=False, **LEGACY)
    a = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    poisoned = dict(trials)
    for t in ("val_obj_d", "val_free", "val_block"):
        bad = trials[t].copy()
        bad["dx_ref"] = 1.0
        bad["f_ref"] = -5.0
        poisoned[t] = bad
    b = SelfSensingEstimator(config=cfg, rig=RIG).fit(poisoned, meta)
    assert a.coef_ == b.coef_


def test_hold_rows_read_every_trial_s_v_and_q_and_never_a_validation_reference(data):
    """hold_rows: auto takes the holds of every trial into the H(q) fit from V and Q alone: poisoning the references
    of the validation trials changes nothing, while their charge in a hold does change H."""
    trials, meta = data
    cfg = SensingConfig(h_model="preisach", cv_blocks=3, drift="off", limit=False)
    a = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    rep = a.fit_report_["hysteresis"]["hold_rows"]
    assert rep["applied"] and {"val_obj_d", "val_free", "val_block"} <= set(rep["trials"])
    poisoned = dict(trials)
    for t in ("val_obj_d", "val_free", "val_block"):
        bad = trials[t].copy()
        bad["dx_ref"] = 1.0
        bad["f_ref"] = -5.0
        poisoned[t] = bad
    b = SelfSensingEstimator(config=cfg, rig=RIG).fit(poisoned, meta)
    assert a.coef_ == b.coef_
    np.testing.assert_array_equal(a.hysteresis_.coef_, b.hysteresis_.coef_)
    # drift: off turns the charge link's leakage and offset-drift search off, whatever the other members' modes
    # (the stress member's configured "off" once switched it back on)
    drift = a.fit_report_["hysteresis"]["drift"]
    assert a.leakage_s_ == 0.0 and not a.offset_drift_ and "search" not in drift
    assert drift["note"] == "drift compensation off (config drift: off)"
    # a charge ramp inside the holds of one validation trial moves the creep of H
    ramped = dict(trials)
    bad = trials["val_free"].copy()
    bad["q"] = bad["q"] + 2e-7 * bad["t"]
    ramped["val_free"] = bad
    c = SelfSensingEstimator(config=cfg, rig=RIG).fit(ramped, meta)
    q = trials["val_free"]["q"].to_numpy()   # (the ramp may also change which Preisach variant is selected)
    assert not np.allclose(a.hysteresis_.predict(q), c.hysteresis_.predict(q))
    off = SelfSensingEstimator(config=SensingConfig(**{**cfg.__dict__, "hold_rows": "off"}), rig=RIG).fit(ramped, meta)
    assert off.fit_report_["hysteresis"]["hold_rows"]["applied"] is False
    # the gap diagnostic's view: a member of the chain it can force off (the same fit as the config switch)
    from selfsense.gap.counterfactual import adopted_members

    forced = SelfSensingEstimator(config=cfg, rig=RIG, members={"hold_rows": "off"}).fit(ramped, meta)
    assert adopted_members(c)["hold_rows"] and not adopted_members(forced)["hold_rows"]
    np.testing.assert_array_equal(forced.hysteresis_.coef_, off.hysteresis_.coef_)
    with pytest.raises(ValueError, match="hold_rows"):
        SensingConfig(hold_rows="on")


def test_json_round_trip_gives_identical_estimates(data):
    trials, meta = data
    cfg = SensingConfig(n_play=8, n_sup=4, n_creep=2, creep=True, **LEGACY)
    a = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    import json

    b = SelfSensingEstimator.from_dict(json.loads(json.dumps(a.to_dict())), RIG)
    ea, eb = a.estimate(trials["val_obj_d"]), b.estimate(trials["val_obj_d"])
    np.testing.assert_array_equal(ea.to_numpy(), eb.to_numpy())


def test_missing_roles_give_clear_errors(data):
    trials, meta = data
    cfg = SensingConfig(n_play=4, n_sup=2, n_creep=0, creep=False, **LEGACY)
    m = meta.copy()
    m.loc["cal_free", "tip"] = "object"
    with pytest.raises(CalibrationError, match="no calibration trial with tip 'free'"):
        SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, m)
    m = meta.copy()
    m.loc["cal_block", "reference"] = "displacement"
    with pytest.raises(CalibrationError, match="reference 'force'"):
        SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, m)
    with pytest.raises(ValueError, match="h_mode"):
        SensingConfig(h_mode="magic")



def _remanent_trial(kind, env, vp_rest=-4.0, n=6000, relay_n=300):
    """A device that rests at V_p = vp_rest with the leads shorted (remanent V_H = -vp_rest, the relay does not erase
    it): the integrator, started at the relay (eq. 57), misses the rest charge q_rest, and the tip rests open."""
    dev = default_tweezer_mechanics()
    t, vp = _drive(kind, n)
    vp[:relay_n] = 0.0
    vp = vp + vp_rest
    sol = dev.solve(vp) if env == "free" else (dev.solve(vp, blocked=True) if env == "blocked"
                                                else dev.solve(vp, k_env=200.0, gap=3e-3))
    q = np.asarray(sol["q"], float)
    q_rest = float(np.asarray(dev.solve(np.array([vp_rest]))["q"])[0]) if env != "blocked" else \
        float(np.asarray(dev.solve(np.array([vp_rest]), blocked=True)["q"])[0])
    V = vp + _h_true(q - q_rest) - vp_rest
    relay = np.zeros(n)
    relay[:relay_n] = 1
    return pd.DataFrame({"t": t, "V": V, "q": q - q_rest, "u_cmd": V / 15.0, "relay": relay,
                         "dx_ref": np.asarray(sol["dx_tip"], float), "f_ref": np.asarray(sol["f_tip"], float),
                         "V_c": V, "V_s": 0.0 * V})


def test_rest_offset_recovered_where_the_tip_rests_open_and_not_invented_elsewhere(data):
    """A device whose actuators rest at V_p = -4 V (charge the integrator never saw): the tip rests open, the
    displacement row's constant dx0 is adopted by the blocked CV and lowers the validation error; on the
    remanence-free data it is not adopted (dx0 exactly 0)."""
    trials, meta = data
    meta = meta.copy()
    meta.loc["cal_free2"] = ["calibration", "free", "displacement", "mixed"]
    specs = {"cal_free": ("sine", "free"), "cal_block": ("sine", "blocked"), "cal_free2": ("mixed", "free"),
             "val_obj_d": ("mixed", "object"), "val_free": ("mixed", "free"), "val_block": ("mixed", "blocked")}
    rem = {k: _remanent_trial(*v) for k, v in specs.items()}
    dev = default_tweezer_mechanics()
    d_rest = float(np.asarray(dev.solve(np.array([-4.0]))["dx_tip"])[0])
    assert d_rest < -50e-6   # the tip rests open by more than 50 um
    cfg = SensingConfig(n_play=12, n_sup=6, n_creep=0, creep=False, dc_offset=False, limit=False, **LEGACY)
    est = SelfSensingEstimator(config=cfg, rig=RIG).fit(rem, meta)
    off = SelfSensingEstimator(config=SensingConfig(**{**cfg.__dict__, "rest_offset": "off"}), rig=RIG).fit(rem, meta)
    assert est.fit_report_["rest_offset"]["applied"] and off.coef_["dx0"] == 0.0
    errs = []
    for e in (est, off):
        out = e.estimate(rem["val_free"])
        errs.append(_pct(out["dx_hat"].to_numpy()[300:], rem["val_free"]["dx_ref"].to_numpy()[300:]))
    assert errs[0] < 0.85 * errs[1], errs   # measured 1.28 vs 1.62 % (the rest is the H fit)
    plain = {**trials, "cal_free2": _trial("mixed", "free")}
    est0 = SelfSensingEstimator(config=cfg, rig=RIG).fit(plain, meta)
    assert not est0.fit_report_["rest_offset"]["applied"] and est0.coef_["dx0"] == 0.0


def test_two_port_force_row_keeps_a_passive_port(data):
    """regression: twoport fits f = (A3 / n_A)(Q - n_A C_p V_p) + S2 dx with S2 >= 0 (thesis eq. 46, a passive tip
    port). On this fixture eq. (52) is exact in the eq. (55) gauge (derivation in docs/method.md 6e), so the two-port
    fit's validation force error stays within 0.5 points of eq. (52)'s (measured 2.24 vs 2.53 % on the contact
    trial); the default (auto, thesis mode) is eq. (52)."""
    trials, meta = data
    base = dict(n_play=12, n_sup=6, n_creep=0, creep=False, dc_offset=False, limit=False, **LEGACY)
    auto = SelfSensingEstimator(config=SensingConfig(**base), rig=RIG).fit(trials, meta)
    assert auto.fit_report_["regression_form"] == "approx" and "S2" not in auto.coef_
    tp = SelfSensingEstimator(config=SensingConfig(**base, regression="twoport"), rig=RIG).fit(trials, meta)
    assert tp.fit_report_["regression_form"] == "twoport" and tp.coef_["S2"] >= 0.0
    ref = trials["val_obj_d"]["f_ref"].to_numpy()
    ea = _pct(auto.estimate(trials["val_obj_d"])["f_hat"].to_numpy(), ref)
    et = _pct(tp.estimate(trials["val_obj_d"])["f_hat"].to_numpy(), ref)
    assert abs(ea - et) < 0.5 and et < 3.0, (ea, et)


def _with_shunt_record(df, R, step, noise_steps, seed=0):
    """The trial with a shunt channel ``V_s`` that carries its current (R dq/dt plus an in-amp offset of a third of
    a step) quantised with ADC step ``step`` and noise ``noise_steps`` (in steps)."""
    t = df["t"].to_numpy(float)
    i = np.concatenate([[0.0], np.diff(df["q"].to_numpy(float)) / np.diff(t)])
    relay = df["relay"].to_numpy() >= 0.5
    i[relay | np.concatenate([[False], relay[:-1]])] = 0.0   # the shorted leads, and the step of q as they open
    rng = np.random.default_rng(seed)
    vs = R * i + step / 3 + noise_steps * step * rng.standard_normal(len(t))
    return df.assign(V_s=np.round(vs / step) * step)


def test_charge_resolution_costs_scale_with_the_adc_step(data):
    """The report of the charge resolution (estimator.charge_resolution): an undithered shunt channel is flagged,
    and what its charge error moves in the tip estimates grows in proportion to the ADC step (the error is up to
    half a step times the constant-current time, and the estimator is linear in the charge around it); a dithered
    channel is not flagged. Only V_s, V and the relay are read."""
    trials, meta = data
    cfg = SensingConfig(n_play=12, n_sup=6, n_creep=0, creep=False, dc_offset=False, limit=False, **LEGACY)
    est = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    assert "no shunt resistance" in est.fit_report_["charge_resolution"]["note"]   # RIG gives none
    est.rig = {**RIG, "shunt_resistance_ohm": 1000.0}
    rep = {}
    for step, noise in ((1e-3, 0.1), (4e-3, 0.1), (1e-3, 1.0)):
        shunted = {k: _with_shunt_record(v, 1000.0, step, noise) for k, v in trials.items()}
        rep[(step, noise)] = est.charge_resolution(shunted, meta)
    fine, coarse, dithered = rep[(1e-3, 0.1)], rep[(4e-3, 0.1)], rep[(1e-3, 1.0)]
    assert fine["limited"] and coarse["limited"] and not dithered["limited"]
    assert "nA" in fine["note"] and "resolves the charge" in dithered["note"]
    assert set(fine["trials"]) == set(meta.index)
    for tid in ("val_free", "val_obj_d"):
        a, b = fine["trials"][tid], coarse["trials"][tid]
        assert a["current_step_a"] == pytest.approx(1e-6) and b["current_step_a"] == pytest.approx(4e-6)
        assert b["sigma_q_end_c"] == pytest.approx(4 * a["sigma_q_end_c"], rel=1e-6)
        assert a["dx_pct"] > 0 and b["dx_pct"] == pytest.approx(4 * a["dx_pct"], rel=0.05)
        assert dithered["trials"][tid]["dx_pct"] == 0.0


def test_h_error_cost_is_the_h_error_through_a2_and_b22(data):
    """estimator.h_error_cost: the selected H(q) model's blocked-CV error e moves the tip estimates by |A2| e and
    |B22| e (V_p = V - H(q) in thesis eq. 52), reported in % of the calibration ranges; it is a part of the validation
    error, not more (here a PI model and a straight line for H(q), whose systematic error the regression partly takes
    up: 2.9 % against 34 % measured); and it is a property of the device, not of the units of its references: tip
    references scaled by 3 (a longer lever) give the same cost."""
    cfg = SensingConfig(h_model="auto", drift="off", creep=False, dc_offset=False, limit=False)
    trials, meta = data
    scaled = {k: v.assign(dx_ref=3 * v["dx_ref"], f_ref=3 * v["f_ref"]) for k, v in trials.items()}
    out = {}
    for name, cands, tr in (("line", (("linear", {}),), trials),
                            ("pi", (("linear", {}), ("pi", {"n_play": 8, "ridge": 1e-6, "creep": False})), trials),
                            ("pi3", (("linear", {}), ("pi", {"n_play": 8, "ridge": 1e-6, "creep": False})), scaled)):
        est = SelfSensingEstimator(config=cfg, rig=RIG)
        est.h_candidates = cands
        est.fit(tr, meta)
        c = est.fit_report_["h_error_cost"]
        row = next(r for r in est.fit_report_["hysteresis"]["selection"] if r["selected"])
        assert row["kind"] == ("linear" if name == "line" else "pi")
        assert c["source"] == "blocked CV" and c["h_error_v"] == row["cv_rms_mean_v"]
        span_dx, span_f = np.ptp(est.ranges_["dx"]), np.ptp(est.ranges_["f"])
        assert c["dx_pct"] == pytest.approx(abs(est.coef_["A2"]) * c["h_error_v"] / span_dx * 100, rel=1e-12)
        assert c["f_pct"] == pytest.approx(abs(est.coef_["B22"]) * c["h_error_v"] / span_f * 100, rel=1e-12)
        assert "% of the displacement range" in c["note"]
        e = est.estimate(tr["val_free"])
        err = _pct(e["dx_hat"].to_numpy(), tr["val_free"]["dx_ref"].to_numpy())
        assert 0 < c["dx_pct"] < err
        out[name] = c
    for k in ("h_error_v", "dx_pct", "f_pct"):
        assert out["pi3"][k] == pytest.approx(out["pi"][k], rel=1e-9)


def test_a_second_calibrations_inputs_are_the_callers_again_after_the_block_even_when_it_raises():
    """``_inputs_overridden``: the forced members, the leakage search to reuse and the candidates a fit sets for a
    second calibration inside itself are put back as the very objects the caller gave (the gap diagnostic compares
    and shares them by identity), also when that calibration raises; nothing else is touched."""
    from selfsense.sensing.estimator import SelfSensingEstimator, SensingConfig

    members, reuse, cands = {"leakage": "auto"}, {"g": 1.0}, (("linear", {}),)
    est = SelfSensingEstimator(config=SensingConfig(), rig=None, members=members, leakage_search_reuse=reuse,
                               h_candidates=cands)
    est.fit_report_ = {"kept": True}
    with est._inputs_overridden(members={"leakage": "off"}, h_candidates=()) as inner:
        assert inner is est and est.members == {"leakage": "off"} and est.h_candidates == ()
        assert est.leakage_search_reuse is reuse
    assert est.members is members and est.h_candidates is cands and est.leakage_search_reuse is reuse
    with pytest.raises(RuntimeError, match="refit failed"):
        with est._inputs_overridden(members={"offset_drift": "off"}, leakage_search_reuse=None):
            raise RuntimeError("refit failed")
    assert est.members is members and est.leakage_search_reuse is reuse and est.fit_report_ == {"kept": True}


def test_a_configured_h_kind_is_checked_against_its_major_loop_and_kept(data, monkeypatch):
    """h_model names a kind: the major-loop check (docs/method.md 6b) runs on every trial's charge and is recorded,
    but never replaces the kind; where the kind leaves its loop the fit report warns and names the trial."""
    from selfsense.hysteresis.models import select

    trials, meta = data
    cfg = SensingConfig(h_model="pi", n_creep=0, creep=False, drift="off", dc_offset=False, limit=False)
    est = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    env = est.fit_report_["hysteresis"]["envelope"]
    assert est.hysteresis_.kind == "pi" and len(env) == 1 and env[0]["excursion"] <= select.ENVELOPE_TOL
    assert not any("major loop" in w for w in est.fit_report_["hysteresis"]["warnings"])
    real = select.envelope_excursion

    def runaway(model, qs_cal, probes, dt):   # the model's real check, its worst trial 2 ranges out
        got = real(model, qs_cal, probes, dt)
        lo, hi = got["range_v"]
        return {**got, "excursion": 2.0, "trial": probes[-1][0], "h_v": [lo, hi + 2.0 * (hi - lo)]}

    monkeypatch.setattr(select, "envelope_excursion", runaway)
    est = SelfSensingEstimator(config=cfg, rig=RIG).fit(trials, meta)
    assert est.hysteresis_.kind == "pi"
    warn = [w for w in est.fit_report_["hysteresis"]["warnings"] if "major loop" in w]
    assert len(warn) == 1 and "configured pi" in warn[0] and "kept because h_model names it" in warn[0]
    assert "trial val_obj_d" in warn[0]   # the last trial of the sorted probes
    assert est.fit_report_["hysteresis"]["envelope"][0]["trial"] == "val_obj_d"
