"""The charge link's temperature member: the actuators' charge per volt drifting over the campaign (a temperature that
rises while the trials are measured). The member reads the drift from the free- and blocked-tip trials' reference-free
relation (zero force, zero displacement), recovers a known drift jointly with H(q) and the coefficients, is not
adopted on an effect-free device, and the batch estimate, the stream and the C export agree on what it does."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from selfsense.chain.temperature import (MIN_CAMPAIGN_CHANGE, anchor_scale, anchor_trend, calibration_position,
                                         campaign_scales, secant_slope)
from selfsense.gap.blind import FS_CASE, T_CASE
from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.counterfactual import _summary, tip_table
from selfsense.sensing import SelfSensingEstimator, SensingConfig

# an effect-free Bouc-Wen device of the tip protocol (selfsense.gap.blind.draw_tip_case(1, 777)): its anchors' trend
# implies a charge-scale change of about 1e-4 over the campaign, far below the member's threshold
FAMILY, DEVICE, NOISE = "bouc_wen", 77752332, 6203064
B_TRUE = 5e-4   # injected charge-scale drift per trial of trials.csv (3.5e-3 over the eight trials)


def test_anchor_scale_finds_the_minimum_of_a_quadratic_cost():
    s, gain = anchor_scale(lambda s: 2.0 + 1e6 * (s - 1.0007) ** 2)
    assert s == pytest.approx(1.0007, abs=1e-9)
    assert gain == pytest.approx((2.0 + 1e6 * 0.0007 ** 2) / 2.0)
    assert anchor_scale(lambda s: -((s - 1.0) ** 2)) == (1.0, 1.0)   # no minimum: the calibration's scale


def test_anchor_trend_separates_the_slope_from_the_tip_offsets():
    # free anchors offset by +4e-4, blocked by -2e-4, common slope 3e-4 per trial
    anchors = [{"k": k, "tip": tip, "s": 1.0 + off + 3e-4 * (k - 1.5)}
               for k, tip, off in [(0, "free", 4e-4), (1, "blocked", -2e-4), (2, "free", 4e-4), (3, "free", 4e-4),
                                   (6, "blocked", -2e-4)]]
    b, why = anchor_trend(anchors, 1.5)
    assert why == "" and b == pytest.approx(3e-4, rel=1e-9)
    # one anchor per tip state: no trend can be told from the offsets
    b, why = anchor_trend([{"k": 0, "tip": "free", "s": 1.0}, {"k": 5, "tip": "blocked", "s": 1.002}], 0.5)
    assert b is None and "two positions" in why


def test_secant_step_and_campaign_scales():
    # d(b) = b0 - g b with b0 = 2e-4, g = 0.5: the trend vanishes at 4e-4
    assert secant_slope(2e-4, 2e-4, 2e-4 - 0.5 * 2e-4) == pytest.approx(4e-4)
    assert secant_slope(2e-4, 2e-4, 2e-4 - 0.01 * 2e-4) == pytest.approx(2e-4 + 2e-4 - 0.01 * 2e-4)  # did not fall
    assert secant_slope(2e-4, 2e-4, 2e-4 - 0.1 * 2e-4) == pytest.approx(8e-4)   # capped at 4x the first slope
    sc = campaign_scales(["a", "b", "c"], 1e-3, 1.0)
    assert sc == {"a": pytest.approx(0.999), "b": 1.0, "c": pytest.approx(1.001)}
    meta = pd.DataFrame({"role": ["calibration", "calibration", "validation", "calibration"]}, index=list("abcd"))
    assert calibration_position(meta) == pytest.approx((0 + 1 + 3) / 3)


@pytest.fixture(scope="module")
def clean():
    return simulate_family_case(FAMILY, DEVICE, {}, NOISE, T_CASE, FS_CASE)


def _drifted(trials, meta, b):
    names = list(meta.index)
    sc = campaign_scales(names, b, calibration_position(meta))
    out = {}
    for t, df in trials.items():
        d = df.copy()
        d["q"] = d["q"].to_numpy(float) * sc[t]
        out[t] = d
    return out


def _fit(trials, meta, rig, mode):
    return SelfSensingEstimator(config=SensingConfig(temperature="auto"), rig=rig,
                                members={"temperature": mode}).fit(trials, meta)


def _table3(est, trials, meta, rig):
    return _summary(tip_table(trials, meta, rig, None, estimator=est))["mean"]


@pytest.fixture(scope="module")
def drifted_fits(clean):
    tr, me, rig = clean
    dr = _drifted(tr, me, B_TRUE)
    return dr, _fit(dr, me, rig, "auto"), _fit(dr, me, rig, "off")


def test_off_by_default_and_forced_on_by_members(clean):
    tr, me, rig = clean
    assert SensingConfig().temperature == "off"
    est = SelfSensingEstimator(config=SensingConfig(), rig=rig, members={"temperature": "auto"})
    assert est._member_modes()["temperature"] == "auto"
    with pytest.raises(ValueError, match="SensingConfig.temperature"):
        SensingConfig(temperature="on")
    assert SensingConfig.from_mapping({"temperature": False}).temperature == "off"   # an unquoted off in YAML


def test_not_adopted_on_an_effect_free_device(clean):
    tr, me, rig = clean
    est = _fit(tr, me, rig, "auto")
    tm = est.temperature_
    assert tm["mode"] == "auto" and not tm["applied"]
    assert tm["campaign_change_first"] < MIN_CAMPAIGN_CHANGE
    assert "not applied" in tm["note"]
    # the trial name changes nothing where the member is not applied
    t = "val_blocked"
    pd.testing.assert_frame_equal(est.estimate(tr[t], trial=t), est.estimate(tr[t]))


def test_known_drift_recovered_and_table3_lowered(clean, drifted_fits):
    tr, me, rig = clean
    dr, auto, off = drifted_fits
    tm = auto.temperature_
    assert tm["applied"] and tm["source"] == "free- and blocked-tip anchors"
    # the joint identification (recalibrated chain, secant step) recovers the injected slope; the first trend, read
    # with H(q) and the coefficients fitted on the drifted charges, is lower
    assert tm["slope_per_trial"] == pytest.approx(B_TRUE, rel=0.3)
    assert abs(tm["slope_first_per_trial"]) <= abs(tm["slope_per_trial"]) * 1.05
    t3_auto, t3_off = _table3(auto, dr, me, rig), _table3(off, dr, me, rig)
    t3_clean = _table3(_fit(tr, me, rig, "off"), tr, me, rig)
    assert t3_auto < t3_off
    # at least half of what the drift cost is given back
    assert t3_off - t3_auto >= 0.5 * (t3_off - t3_clean)
    # a trial estimated without its name is estimated at the calibration's scale
    t = "val_repeat"
    assert auto.temperature_scale(t) == pytest.approx(tm["scales"][t])
    assert auto.temperature_scale(None) == 1.0 and auto.temperature_scale("not_a_trial") == 1.0
    with_name = auto.estimate(dr[t], trial=t)
    unscaled = auto.estimate(dr[t])
    assert not np.allclose(with_name["f_raw"], unscaled["f_raw"])
    # the estimate returns the measured charge either way
    np.testing.assert_array_equal(with_name["q"].to_numpy(), dr[t]["q"].to_numpy())


def test_model_round_trip_and_stream_carry_the_member(clean, drifted_fits):
    from selfsense.sensing.export_c import ExportError, c_sources
    from selfsense.sensing.streaming import SelfSensingStream

    dr, auto, _ = drifted_fits
    back = SelfSensingEstimator.from_dict(auto.to_dict(), auto.rig)
    t = "val_blocked"
    pd.testing.assert_frame_equal(back.estimate(dr[t], trial=t), auto.estimate(dr[t], trial=t))
    with pytest.raises(ExportError, match="temperature member"):
        c_sources(auto, auto.rig, 1.0 / FS_CASE)
    # the stream divides the charge by the named trial's scale, as the batch estimate does: fed the DAQ samples of an
    # undrifted trial (the in-amp output the DAQ logged), it gives the batch estimate of that trial under its name
    tr, me, rig = clean
    assert not auto.offset_drift_ and not auto.amplifier_.get("applied")   # members a plain stream refuses
    for t in ("val_blocked", "val_repeat"):
        df = tr[t]
        stream = SelfSensingStream(auto, dt=1.0 / FS_CASE, trial=t)
        assert stream.temperature_scale == pytest.approx(auto.temperature_scale(t)) and stream.temperature_scale != 1
        v_shunt = df["V_s"].to_numpy() * float(rig.inamp_gain)
        out = stream.process(df["u_cmd"].to_numpy(), v_shunt, df["relay"].to_numpy(), full=True)
        batch = auto.estimate(df, trial=t)
        plain = auto.estimate(df)
        for col in ("dx_hat", "f_hat"):
            rng = float(np.ptp(batch[col])) or 1.0
            assert np.max(np.abs(out[col] - batch[col].to_numpy())) < 1e-9 * rng, (t, col)
        assert np.max(np.abs(plain["f_raw"].to_numpy() - batch["f_raw"].to_numpy())) > 1e-6 * float(
            np.ptp(batch["f_raw"]))
    with pytest.warns(UserWarning, match="temperature member and no trial was named"):
        assert SelfSensingStream(auto, dt=1.0 / FS_CASE).temperature_scale == 1.0


def test_stream_command_names_the_trial(clean, drifted_fits, tmp_path):
    """``selfsense stream --trial NAME`` (its line path, ``stream_lines``) gives the batch estimate under that name,
    line by line; without the name, the calibration's scale and the warning."""
    import io
    import json

    from selfsense.cli.stream import stream_lines

    tr, me, rig = clean
    _, auto, _ = drifted_fits
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(auto.to_dict(), default=float))
    t = "val_repeat"
    df = tr[t].iloc[:1500]
    v_shunt = df["V_s"].to_numpy() * float(rig.inamp_gain)
    lines = ["t,u_cmd,v_shunt,relay\n"] + [f"{float(a)!r},{float(b)!r},{float(c)!r},{int(d)}\n" for a, b, c, d in zip(
        df["t"].to_numpy(), df["u_cmd"].to_numpy(), v_shunt, df["relay"].to_numpy())]

    def run(**kw):
        out = io.StringIO()
        assert stream_lines(model, rig, lines, out, dt=1.0 / FS_CASE, **kw) == len(df)
        return pd.read_csv(io.StringIO(out.getvalue()))

    named = run(trial=t)
    batch = auto.estimate(df, trial=t)
    for col in ("dx_hat", "f_hat"):
        rng = float(np.ptp(batch[col])) or 1.0
        assert np.max(np.abs(named[col].to_numpy() - batch[col].to_numpy())) < 1e-9 * rng, col
    with pytest.warns(UserWarning, match="temperature member and no trial was named"):
        plain = run()
    assert np.max(np.abs(plain["f_hat"].to_numpy() - named["f_hat"].to_numpy())) > 1e-6 * float(np.ptp(batch["f_hat"]))


def test_a_held_form_is_a_shortcut_the_adopted_refit_does_not_keep(clean, drifted_fits):
    """A caller that holds the form selected without the member (the gap diagnostic's recalibrations,
    ``compare_modes``: ``h_selection_cv`` off) gets the estimator the whole selection gives: the chain without the
    member is the same model bit for bit, the trend refit holds that form in both, and the adopted refit selects
    again on the corrected charges."""
    _, me, rig = clean
    dr, auto, off = drifted_fits
    held = SelfSensingEstimator(config=SensingConfig(temperature="auto"), rig=rig, members={"temperature": "auto"},
                                h_candidates=off.selected_form(), h_selection_cv=False).fit(dr, me)
    assert held.temperature_["applied"] and auto.temperature_["applied"]
    assert held.temperature_["slope_per_trial"] == auto.temperature_["slope_per_trial"]
    assert held.coef_ == auto.coef_
    sel = held.fit_report_["hysteresis"]["selection"]
    assert len(sel) == len(auto.fit_report_["hysteresis"]["selection"]) > 2   # the whole selection, not the held pair


def test_anchor_evidence_measures_the_campaign_change_and_the_rms_it_removes():
    from selfsense.chain.temperature import anchor_evidence

    anchors = [{"k": k, "tip": tip, "s": 1.0 + off + 3e-4 * (k - 1.5) + e, "trial": f"t{k}"}
               for k, tip, off, e in [(0, "free", 4e-4, 1e-5), (1, "blocked", -2e-4, -1e-5), (2, "free", 4e-4, -2e-5),
                                      (3, "free", 4e-4, 1e-5), (6, "blocked", -2e-4, 1e-5)]]
    ev = anchor_evidence(anchors, 1.5, 8)
    assert ev["identified"] and ev["threshold"] == MIN_CAMPAIGN_CHANGE
    assert ev["slope_per_trial"] == pytest.approx(3e-4, rel=0.1)
    assert ev["campaign_change"] == pytest.approx(7 * abs(ev["slope_per_trial"]), rel=1e-12)
    # the trend takes the drift out: what is left is the anchors' scatter (1e-5), far below the RMS about the offsets
    assert ev["rms_trend"] < 2e-5 < 3e-4 < ev["rms_offsets"]
    one = anchor_evidence([{"k": 0, "tip": "free", "s": 1.0}, {"k": 5, "tip": "blocked", "s": 1.002}], 0.5, 6)
    assert not one["identified"] and "two positions" in one["why"]


def test_the_gap_diagnostic_names_the_drift_from_the_chains_anchors_and_not_on_an_effect_free_device(clean,
                                                                                                     drifted_fits):
    """The diagnostic's stage ``anchors`` reads the fitted chain (here without the member, as the default estimator
    runs): it names ``slow.temperature`` on the drifted device by the rule that adopts the member (campaign change >=
    MIN_CAMPAIGN_CHANGE), and nothing on the same device without the drift."""
    from selfsense.gap.blind import load_stage_thresholds
    from selfsense.gap.pipeline import why_not
    from selfsense.gap.stages import ANCHOR_MEMBER, anchor_stage, diagnose_stages

    tr, me, rig = clean
    dr, auto, off = drifted_fits
    st = anchor_stage(off, dr, me)
    assert st["observed"] and [a["member"] for a in st["accepted"]] == [ANCHOR_MEMBER]
    assert st["gains_alone"][ANCHOR_MEMBER] >= MIN_CAMPAIGN_CHANGE
    assert st["rms_after"] < st["rms_nominal"]
    assert set(st["trials"]) == {t for t, m in me.iterrows() if m["tip"] in ("free", "blocked")}
    # the chain that carries the member reads the anchors it was adopted on, not those its correction leaves
    assert anchor_stage(auto, dr, me)["gains_alone"][ANCHOR_MEMBER] == pytest.approx(
        auto.temperature_["campaign_change_first"], rel=1e-12)
    thr = load_stage_thresholds()
    v = diagnose_stages(dr, me, rig, thr, fitted=off)
    e = next(x for x in v["effects"] if x["effect"] == "slow.temperature")
    assert any(a["stage"] == "anchors" for a in e["acceptances"])
    v0 = diagnose_stages(tr, me, rig, thr, fitted=_fit(tr, me, rig, "off"))
    assert v0["stages"]["anchors"]["observed"] and not v0["stages"]["anchors"]["accepted"]
    assert "slow.temperature" not in [x["effect"] for x in v0["effects"]]
    row = next(r for r in why_not({**v0, "thresholds": thr}) if r["member"] == ANCHOR_MEMBER)
    assert not row["accepted"] and row["threshold"] == MIN_CAMPAIGN_CHANGE and "below" in row["why"]
