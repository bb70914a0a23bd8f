"""The amplifier member's slew limit (voltage link, :mod:`selfsense.chain.amplifier`): an HV amplifier at its slew
limit ``S`` delivers ``rate_limit(gain u_cmd, S)`` while the log shows the command. The member finds ``S`` from the V-Q
rows alone (no reference), recovers the simulator's slew rate on a device of the tip campaign, lowers Table 3 against
the same model without it, is not adopted on an effect-free device (tests/chain/test_amplifier_lag.py), and the batch
estimate, the model file and the stream carry the same correction (the C export's agreement:
tests/sensing/test_export_c.py)."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from selfsense.chain.amplifier import SLEW_CV_RATIO, rate_limit, slew_candidates, with_slew
from selfsense.gap.blind import FS_CASE, T_CASE, draw_tip_case
from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.counterfactual import _summary, tip_table
from selfsense.sensing import SelfSensingEstimator, SensingConfig

# tip case 38 of seed 20261224: a generalised-PI device whose amplifier limits (relative magnitude 11.7) put a slew
# limit of 1500 / 11.7 = 128 V/s on every trial's fast edges (17-33 % of the samples)
CASE, SEED = 38, 20261224


def test_rate_limit_is_the_clipped_forward_recursion():
    t = np.array([0.0, 1.0, 2.0, 4.0, 5.0, 6.0])
    x = np.array([0.0, 5.0, 5.0, 5.0, -5.0, -5.0])
    np.testing.assert_allclose(rate_limit(x, 2.0, t), [0.0, 2.0, 4.0, 5.0, 3.0, 1.0])
    slow = np.sin(np.linspace(0.0, 6.0, 200))
    tt = np.linspace(0.0, 6.0, 200)
    np.testing.assert_array_equal(rate_limit(slow, 10.0, tt), slow)      # never faster than the rate: unchanged
    with pytest.raises(ValueError, match="samples"):
        rate_limit(x, 1.0, t[:-1])


def test_with_slew_keeps_eq56_with_the_delivered_command():
    t = np.arange(0.0, 1.0, 1e-3)
    u = np.where(t < 0.5, 0.0, 2.0)
    vs = np.full_like(t, 0.1)
    df = pd.DataFrame({"t": t, "u_cmd": u, "V": 10.0 * u - vs, "relay": 0.0})
    out = with_slew(df, 10.0, 100.0)
    np.testing.assert_allclose(out["V"], 10.0 * out["u_cmd"] - vs, atol=1e-12)
    assert np.max(np.abs(np.diff(10.0 * out["u_cmd"]))) <= 100.0 * 1e-3 * (1 + 1e-12)
    assert out["u_cmd"].iloc[-1] == pytest.approx(2.0)                   # caught up on the hold after the edge
    assert with_slew(df, 10.0, 0.0) is df
    c = slew_candidates({"a": df}, 10.0)
    assert len(c) and np.all(np.diff(c) < 0) and c[0] <= 0.9 * 20.0 / 1e-3


@pytest.fixture(scope="module")
def case():
    c = draw_tip_case(CASE, SEED)
    tr, me, rig, truth = simulate_family_case(c["family"], c["device_seed"], c["effects"], c["noise_seed"], T_CASE,
                                              FS_CASE, with_truth=True)
    est = SelfSensingEstimator(config=SensingConfig(), rig=rig).fit(tr, me)
    return c, tr, me, rig, truth, est


def test_recovers_the_simulated_slew_and_lowers_table3(case):
    c, tr, me, rig, truth, est = case
    sl = est.amplifier_["slew"]
    s_true = 1500.0 / c["effects"]["rate.amplifier"]
    # the simulator's delivered command rises at most at its slew rate
    vc = np.asarray(truth["cal_free"]["V_c"])
    assert np.max(np.abs(np.diff(vc))) * FS_CASE == pytest.approx(s_true, rel=1e-6)
    assert sl["applied"] and sl["supported"] and sl["source"] == "V-Q rows" and "applied" in sl["note"]
    assert sl["rate_v_per_s"] == pytest.approx(s_true, rel=0.03)
    assert sl["cv_rms_v_with"] <= SLEW_CV_RATIO * sl["cv_rms_v_without"]
    # a tip record says which part of the amplifier member was carried: the slew, never with the current-limit rebuild
    from selfsense.gap.counterfactual import amplifier_parts
    assert amplifier_parts(est)["slew"] and not amplifier_parts(est)["current_limit"]
    # the delivered command the member rebuilds is the simulator's to a fraction of the command's span
    rebuilt = with_slew(tr["val_disp"], rig.amplifier_gain, sl["rate_v_per_s"])["u_cmd"].to_numpy() * rig.amplifier_gain
    err = np.abs(rebuilt - np.asarray(truth["val_disp"]["V_c"]))
    raw = np.abs(tr["val_disp"]["u_cmd"].to_numpy() * rig.amplifier_gain - np.asarray(truth["val_disp"]["V_c"]))
    assert np.quantile(err, 0.99) < 0.1 * np.quantile(raw, 0.99)
    # the same fitted chain without the slew correction of its inputs estimates worse
    plain = SelfSensingEstimator.from_dict({**est.to_dict(), "amplifier": {**est.amplifier_, "slew": {}}}, rig)
    e_with = _summary(tip_table(tr, me, rig, None, estimator=est))["mean"]
    e_without = _summary(tip_table(tr, me, rig, None, estimator=plain))["mean"]
    assert e_with < e_without - 2.0


def test_model_file_and_stream_carry_the_slew(case):
    from selfsense.sensing.streaming import SelfSensingStream

    c, tr, me, rig, truth, est = case
    back = SelfSensingEstimator.from_dict(est.to_dict(), rig)
    assert back.amplifier_ == est.amplifier_
    t = "val_disp"
    df = tr[t]
    pd.testing.assert_frame_equal(back.estimate(df, trial=t), est.estimate(df, trial=t))
    v_shunt = df["V_s"].to_numpy() * float(rig.inamp_gain)
    batch = est.estimate(df, trial=t)
    for stamps in (None, df["t"].to_numpy()):
        stream = SelfSensingStream(est, dt=1.0 / FS_CASE, trial=t)
        out = stream.process(df["u_cmd"].to_numpy(), v_shunt, df["relay"].to_numpy(), t=stamps, full=True)
        for col in ("dx_hat", "f_hat"):
            rng = float(np.ptp(batch[col])) or 1.0
            assert np.max(np.abs(out[col] - batch[col].to_numpy())) < 1e-9 * rng, (col, stamps is None)
