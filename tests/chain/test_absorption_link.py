"""The charge link's absorption member: a series R-C branch in parallel with the actuators (dielectric absorption)
takes charge through the shunt that polarises nothing, so after a step the measured charge keeps rising while the tip
rests. The member finds the branch on the free-tip calibration laser, takes its charge out of Q, and is not adopted on
the same device without the branch."""
from __future__ import annotations

import numpy as np
import pytest

from selfsense.chain.charge import ABSORPTION_TAUS_S, absorption_column, fit_absorption
from selfsense.gap.blind import FS_CASE, T_CASE, draw_tip_case
from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.counterfactual import _summary, tip_table
from selfsense.sensing import SelfSensingEstimator, SensingConfig

# case 28 of the gap diagnostic's tip campaign 4711 (a development case of the member): a Preisach device whose
# absorption branch (C_da / (n_A C_p) = 0.107, R_da C_da = 3.7 s) costs Table 3 about 10 points against its twin
CASE = draw_tip_case(28, 4711)
TAU_TRUE = 3.7


@pytest.fixture(scope="module")
def absorbing():
    return simulate_family_case(CASE["family"], CASE["device_seed"], CASE["effects"], CASE["noise_seed"], T_CASE,
                                FS_CASE, with_truth=True)


@pytest.fixture(scope="module")
def twin():
    return simulate_family_case(CASE["family"], CASE["device_seed"], {}, CASE["noise_seed"], T_CASE, FS_CASE)


def _free(tr, me):
    return {t: tr[t] for t, r in me.iterrows() if r["role"] == "calibration" and r["tip"] == "free"
            and r["reference"] == "displacement"}


def _fit(tr, me, rig, mode):
    return SelfSensingEstimator(config=SensingConfig(), rig=rig, members={"absorption": mode}).fit(tr, me)


def test_absorption_column_is_the_branch_voltage():
    """A step of V charges the branch capacitor with its time constant: LP_tau(V) = V (1 - exp(-t / tau))."""
    dt, tau = 1e-3, 2.0
    V = np.r_[np.zeros(100), np.full(10_000, 50.0)]
    col = absorption_column(V, dt, tau)
    t = np.arange(1, 10_001) * dt
    assert np.max(np.abs(col[:100])) == 0.0
    assert np.allclose(col[100:], 50.0 * (1 - np.exp(-t / tau)), rtol=0, atol=1e-9)


def test_branch_found_on_the_free_tip_laser_and_not_on_its_twin(absorbing, twin):
    tr, me, _, _ = absorbing
    fit = fit_absorption(_free(tr, me))
    assert fit.supported and fit.cv_gain > 0.5          # measured 0.87
    i = ABSORPTION_TAUS_S.index(fit.tau_s)
    assert ABSORPTION_TAUS_S[i - 1] < TAU_TRUE < ABSORPTION_TAUS_S[i + 1]   # the grid point next to 3.7 s
    assert fit.c_f > 0
    tr0, me0, _ = twin
    f0 = fit_absorption(_free(tr0, me0))
    assert not f0.supported and f0.cv_gain < 0.1        # measured 0.001


def test_corrected_charge_follows_the_actuators_charge(absorbing):
    """With the member, the charge the estimator uses is the actuators' own (the simulator's truth), not the
    shunt's: the error against the truth falls by more than 70 % on every trial."""
    tr, me, rig, truth = absorbing
    est = _fit(tr, me, rig, "auto")
    assert est.absorption_["applied"] and est.absorption_["source"] == "free-tip laser"
    for t, df in tr.items():
        m = df["relay"].to_numpy() < 0.5
        q_act = truth[t]["q_act"].to_numpy()[m]
        raw = np.mean(np.abs(df["q"].to_numpy()[m] - q_act))
        corr = np.mean(np.abs(est._with_absorption(df)["q"].to_numpy()[m] - q_act))
        assert corr < 0.3 * raw, (t, raw, corr)


def test_member_lowers_table3_and_leaves_the_twin_bit_identical(absorbing, twin):
    tr, me, rig, _ = absorbing
    on = _summary(tip_table(tr, me, rig, None, estimator=_fit(tr, me, rig, "auto")))["mean"]
    off = _summary(tip_table(tr, me, rig, None, estimator=_fit(tr, me, rig, "off")))["mean"]
    # measured 6.60 against 10.78 (twin 4.55); 14.33 before the leakage fold majority (docs/method.md 6c): without
    # the member the calibration now adopts 20 nS of leakage, which takes up part of the absorbed charge
    assert on < 0.7 * off
    tr0, me0, rig0 = twin
    a, b = _fit(tr0, me0, rig0, "auto"), _fit(tr0, me0, rig0, "off")
    assert not a.absorption_["applied"]
    for t, df in tr0.items():
        pa, pb = a.estimate(df), b.estimate(df)
        assert np.array_equal(pa["dx_hat"].to_numpy(), pb["dx_hat"].to_numpy())
        assert np.array_equal(pa["f_hat"].to_numpy(), pb["f_hat"].to_numpy())


def test_one_chain_diagnostic_names_the_member_and_the_stream_carries_it(absorbing):
    """The diagnostic's ``slow.absorption`` is the estimator's member (its counterfactual switches it, its chain
    table scores the chain without it); the config switch turns it off; the stream carries it (the same recursion,
    sample by sample: equal to the batch estimate; the C export is checked in tests/sensing/test_export_c.py); the
    model JSON keeps it."""
    from selfsense.gap.counterfactual import CHAIN_MEMBERS, adopted_members
    from selfsense.sensing.export_c import c_sources
    from selfsense.sensing.streaming import SelfSensingStream

    tr, me, rig, _ = absorbing
    est = _fit(tr, me, rig, "auto")
    assert CHAIN_MEMBERS["slow.absorption"] == "absorption"
    assert adopted_members(est)["absorption"]
    off = SelfSensingEstimator(config=SensingConfig(absorption="off"), rig=rig).fit(tr, me)
    assert not adopted_members(off)["absorption"] and "config absorption: off" in off.absorption_["note"]
    assert "DA_C" in c_sources(est, rig, 1.0 / FS_CASE)[1]
    assert not est.offset_drift_ and not est.amplifier_.get("applied")   # members a plain stream refuses
    for t in ("val_force", "val_disp"):
        df = tr[t]
        stream = SelfSensingStream(est, dt=1.0 / FS_CASE)
        v_shunt = df["V_s"].to_numpy() * float(rig.inamp_gain)   # the in-amp output the DAQ logged
        out = stream.process(df["u_cmd"].to_numpy(), v_shunt, df["relay"].to_numpy(), full=True)
        batch = est.estimate(df)
        for col in ("dx_hat", "f_hat"):
            rng = float(np.ptp(batch[col])) or 1.0
            assert np.max(np.abs(out[col] - batch[col].to_numpy())) < 1e-9 * rng, (t, col)
    back = SelfSensingEstimator.from_dict(est.to_dict(), rig)
    df = tr["val_force"] if "val_force" in tr else next(iter(tr.values()))
    assert np.array_equal(back.estimate(df)["f_hat"].to_numpy(), est.estimate(df)["f_hat"].to_numpy())
    with pytest.raises(ValueError, match="SensingConfig.absorption"):
        SensingConfig(absorption="on")


def test_a_leakage_path_is_not_taken_for_an_absorption_branch():
    """The same device with leakage instead of the branch: a long-tau absorption column fits the slow charge path too,
    but no better than the leakage column int V dt, so the member is not adopted (the leakage member carries it)."""
    tr, me, _ = simulate_family_case(CASE["family"], CASE["device_seed"], {"slow.leakage": 10.0}, CASE["noise_seed"],
                                     T_CASE, FS_CASE)
    fit = fit_absorption(_free(tr, me))
    assert not fit.supported
    assert fit.cv_rms_m_with > 0.95 * fit.cv_rms_m_leak, fit.note


def test_absorption_and_hold_evidence_are_memoised_on_the_trials_content(absorbing, monkeypatch):
    """fit_absorption and hold_evidence are pure functions of the trials' columns: a second call on the same content
    (the gap diagnostic's recalibrations that toggle a member) takes the kept result -- equal, and a copy of its own --
    while a changed charge, another argument or another value of a module threshold the function reads computes
    again."""
    import selfsense.chain.charge as ch

    tr, me, rig = absorbing[:3]
    free = _free(tr, me)
    ch.fit_absorption.cache.clear()
    a = fit_absorption(free)
    b = fit_absorption({t: df.copy() for t, df in free.items()})
    assert len(ch.fit_absorption.cache) == 1 and a.to_dict() == b.to_dict() and a is not b
    b.note = "changed by a caller"
    assert fit_absorption(free).note == a.note
    t0 = next(iter(free))
    moved = dict(free, **{t0: free[t0].assign(q=free[t0]["q"] + 1e-12)})
    fit_absorption(moved)
    fit_absorption(free, n_blocks=4)
    assert len(ch.fit_absorption.cache) == 3
    frames = {t: df[["t", "V", "q", "relay"]] for t, df in tr.items()}
    ch.hold_evidence.cache.clear()
    e1 = ch.hold_evidence(frames).to_dict()
    monkeypatch.setattr(ch, "Z_SUPPORT", ch.Z_SUPPORT * 2)
    e2 = ch.hold_evidence(frames).to_dict()
    assert len(ch.hold_evidence.cache) == 2
    monkeypatch.undo()
    assert ch.hold_evidence(frames).to_dict() == e1 and len(ch.hold_evidence.cache) == 2
    assert e2["g_s"] == e1["g_s"]


def test_clear_memos_lets_a_replaced_callee_take_effect(absorbing, monkeypatch):
    """The memo's key holds the trials, the arguments and the module constants, not the functions called: after one
    of those is replaced, the kept result is still served until :func:`clear_memos` empties the caches."""
    import selfsense.chain.charge as ch

    tr = absorbing[0]
    frames = {t: df[["t", "V", "q", "relay"]] for t, df in tr.items()}
    before = ch.hold_evidence(frames).to_dict()
    assert before["n_holds"] > 0
    real, calls = ch._hold_rows, []

    def no_holds(*args, **kwargs):  # a replaced callee: no trial has a hold
        calls.append(args[0])
        return []

    monkeypatch.setattr(ch, "_hold_rows", no_holds)
    assert ch.hold_evidence(frames).to_dict() == before and calls == []  # served from the memo
    ch.clear_memos()
    assert all(len(f.cache) == 0 for f in (ch.hold_evidence, ch.fit_absorption))
    after = ch.hold_evidence(frames).to_dict()
    assert calls and after["n_holds"] == 0 and after != before
    assert real is not no_holds
