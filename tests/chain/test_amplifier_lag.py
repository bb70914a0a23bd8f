"""The voltage link's lag member: an HV amplifier of finite bandwidth (or a skew between the DAQ's clocks) delivers
the command ``tau`` late, ``V = gain u_cmd(t - tau) - V_s``. The member identifies ``tau`` jointly with H(q) (a column
``gain du_cmd/dt`` of the selected form's fit), recovers a lag added to a device, is not adopted where the command
already tells the actuator voltage, lowers Table 3 where it is adopted, and the batch estimate, the model file and
the stream carry the same correction (the C export's agreement: tests/sensing/test_export_c.py)."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from selfsense.chain.amplifier import LAG_MAX_R2, LAG_MAX_S, LAG_MIN_GAIN, lag_column, lag_r2
from selfsense.gap.blind import FS_CASE, T_CASE
from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.counterfactual import _summary, tip_table
from selfsense.sensing import SelfSensingEstimator, SensingConfig

# an effect-free Bouc-Wen device of the tip protocol (selfsense.gap.blind.draw_tip_case(1, 777)); its amplifier's
# bandwidth (the simulator's first-order lag) puts the actuator voltage behind the command
FAMILY, DEVICE, NOISE = "bouc_wen", 77752332, 6203064
TAU_ADDED = 1.0e-3   # [s] a lag added to the device by shifting its logged command


def test_lag_column_is_the_backward_difference_of_the_command():
    t = np.array([0.0, 1e-3, 2e-3, 4e-3, 5e-3])
    u = np.array([0.0, 1.0, 3.0, 3.0, 2.0])
    col = lag_column(pd.DataFrame({"t": t, "u_cmd": u}), 10.0)
    np.testing.assert_allclose(col, [0.0, 1e4, 2e4, 0.0, -1e4])
    # a ramp: constant gain * slope after the first sample, whatever the sample times
    t = np.cumsum(np.r_[0.0, np.random.default_rng(0).uniform(0.5e-3, 1.5e-3, 50)])
    col = lag_column(pd.DataFrame({"t": t, "u_cmd": 3.0 * t}), 20.0)
    assert col[0] == 0.0 and np.allclose(col[1:], 60.0)


def test_lag_r2_is_the_share_a_design_reproduces():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(400, 3))
    assert lag_r2(X, X @ np.array([1.0, -2.0, 0.5])) == pytest.approx(1.0)
    w = rng.normal(size=400)
    X1 = np.column_stack([X, np.ones(400)])
    w -= X1 @ np.linalg.lstsq(X1, w, rcond=None)[0]        # orthogonal to every column and of mean 0
    assert lag_r2(X, w) == pytest.approx(0.0, abs=1e-12)
    assert lag_r2(X, np.ones(400)) == 1.0                    # a constant column tells nothing


def test_config_and_member_modes():
    assert SensingConfig().amplifier_lag == "auto"
    with pytest.raises(ValueError, match="SensingConfig.amplifier_lag"):
        SensingConfig(amplifier_lag="on")
    est = SelfSensingEstimator(config=SensingConfig(amplifier_lag="off"), members={"amplifier_lag": "on"})
    assert est._member_modes()["amplifier_lag"] == "on"
    assert 0 < LAG_MIN_GAIN < 0.1 and 1e-4 < LAG_MAX_S <= 1e-2


@pytest.fixture(scope="module")
def clean():
    return simulate_family_case(FAMILY, DEVICE, {}, NOISE, T_CASE, FS_CASE)


def _shift_command(trials, rig, tau):
    """The same device logged with a command that leads what the amplifier delivered by ``tau`` more (to first
    order): ``u + tau du/dt`` and ``V = gain u - V_s`` with it."""
    out = {}
    for t, df in trials.items():
        d = df.copy()
        w = lag_column(df, 1.0)
        d["u_cmd"] = df["u_cmd"].to_numpy(float) + tau * w
        d["V"] = df["V"].to_numpy(float) + tau * float(rig.amplifier_gain) * w
        out[t] = d
    return out


@pytest.fixture(scope="module")
def fits(clean):
    tr, me, rig = clean
    auto = SelfSensingEstimator(config=SensingConfig(), rig=rig).fit(tr, me)
    off = SelfSensingEstimator(config=SensingConfig(amplifier_lag="off"), rig=rig).fit(tr, me)
    return auto, off


def _table3(est, trials, meta, rig):
    return _summary(tip_table(trials, meta, rig, None, estimator=est))["mean"]


def test_adopted_on_the_simulated_amplifier_and_table3_lowered(clean, fits):
    tr, me, rig = clean
    auto, off = fits
    lag = auto.amplifier_lag_
    assert lag["applied"] and lag["source"] == "calibration rows" and lag["cv_gain"] >= LAG_MIN_GAIN
    assert 0 < lag["tau_s"] <= LAG_MAX_S and lag["column_r2"] <= LAG_MAX_R2
    assert auto.fit_report_["amplifier_lag"]["applied"] and "applied" in lag["note"]
    assert not off.amplifier_lag_["applied"] and "off" in off.amplifier_lag_["note"]
    # a lag is not a slew limit: the amplifier member's slew part finds none on this device (first look)
    assert not auto.amplifier_["slew"]["applied"] and auto.amplifier_["slew"]["rate_v_per_s"] == 0.0
    json.dumps(auto.amplifier_, allow_nan=False)   # a model artefact: the numbers not computed are None, not NaN
    assert _table3(auto, tr, me, rig) < _table3(off, tr, me, rig)
    # the estimate applies the correction: the model without it gives another estimate of the same samples
    t = "val_disp"
    plain = SelfSensingEstimator.from_dict({**auto.to_dict(), "amplifier_lag": {}}, rig)
    assert not np.allclose(plain.estimate(tr[t])["dx_raw"], auto.estimate(tr[t])["dx_raw"])


def test_an_added_lag_is_recovered_and_a_removed_one_is_not_adopted(clean, fits):
    tr, me, rig = clean
    auto, _ = fits
    tau0 = auto.amplifier_lag_["tau_s"]
    more = SelfSensingEstimator(config=SensingConfig(), rig=rig).fit(_shift_command(tr, rig, TAU_ADDED), me)
    assert more.amplifier_lag_["applied"]
    assert more.amplifier_lag_["tau_s"] - tau0 == pytest.approx(TAU_ADDED, rel=0.15)
    # the command shifted back by the lag the member found: what is left is not a lag worth carrying
    none = SelfSensingEstimator(config=SensingConfig(), rig=rig).fit(_shift_command(tr, rig, -tau0), me)
    lag = none.amplifier_lag_
    assert not lag["applied"] and "not applied" in lag["note"]
    assert abs(lag["tau_s"]) < 0.2 * tau0 or lag["cv_gain"] < LAG_MIN_GAIN


def test_model_file_and_stream_carry_the_member(clean, fits):
    from selfsense.sensing.streaming import SelfSensingStream

    tr, me, rig = clean
    auto, _ = fits
    back = SelfSensingEstimator.from_dict(auto.to_dict(), rig)
    assert back.amplifier_lag_ == auto.amplifier_lag_
    for t in ("val_disp", "val_blocked"):
        df = tr[t]
        pd.testing.assert_frame_equal(back.estimate(df, trial=t), auto.estimate(df, trial=t))
        v_shunt = df["V_s"].to_numpy() * float(rig.inamp_gain)
        for stamps in (None, df["t"].to_numpy()):   # the sample period, or the log's time stamps
            stream = SelfSensingStream(auto, dt=1.0 / FS_CASE, trial=t)
            out = stream.process(df["u_cmd"].to_numpy(), v_shunt, df["relay"].to_numpy(), t=stamps, full=True)
            batch = auto.estimate(df, trial=t)
            for col in ("dx_hat", "f_hat"):
                rng = float(np.ptp(batch[col])) or 1.0
                assert np.max(np.abs(out[col] - batch[col].to_numpy())) < 1e-9 * rng, (t, col, stamps is None)


def test_not_adopted_where_the_calibration_is_sines_at_one_rate(clean):
    """The thesis protocol (a free-tip and a blocked-tip sine): a lag of a sine is a loop width like the hysteresis'
    own, and the column is not separable from it on those rows."""
    tr, me, rig = clean
    meta = me.set_index("trial") if "trial" in me.columns else me
    sines = meta.drop(index=[t for t in meta.index if meta.loc[t, "role"] == "calibration"
                             and meta.loc[t, "signal"] != "sine"])
    assert list(sines[sines["role"] == "calibration"]["signal"]) == ["sine", "sine"]
    est = SelfSensingEstimator(config=SensingConfig(), rig=rig).fit(tr, sines)
    lag = est.amplifier_lag_
    assert not lag["applied"] and lag["column_r2"] > LAG_MAX_R2
    assert "does not separate a lag from the hysteresis" in lag["note"]
