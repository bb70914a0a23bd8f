"""The voltage link's amplifier member: an HV amplifier at its current limit delivers a fixed current, so the actuator
voltage lags the command that eq. (56) reads. The member finds the limit from the shunt current alone, rebuilds the
actuator voltage of the limited samples, and is not adopted on a device whose amplifier never limits."""
from __future__ import annotations

import numpy as np
import pytest

from selfsense.chain.amplifier import identify_current_limit, rebuild_voltage
from selfsense.gap.blind import FS_CASE, T_CASE
from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.counterfactual import _summary, tip_table
from selfsense.sensing import SelfSensingEstimator, SensingConfig

# case 60 of the gap diagnostic's tip campaign 4711 (selfsense.gap.blind.draw_tip_case): a Preisach device whose
# amplifier limits cost Table 3 about 40 points against its effect-free twin
FAMILY, DEVICE, NOISE = "preisach", 471164193, 37356469
M = 8.688984403864222   # amplifier limits: current limit 1 mA / M, slew limit 1500 V/s / M (selfsense.sim.effects)


@pytest.fixture(scope="module")
def limited():
    return simulate_family_case(FAMILY, DEVICE, {"rate.amplifier": M}, NOISE, T_CASE, FS_CASE, with_truth=True)


@pytest.fixture(scope="module")
def twin():
    return simulate_family_case(FAMILY, DEVICE, {}, NOISE, T_CASE, FS_CASE)


def _fit(trials, meta, rig, mode):
    return SelfSensingEstimator(config=SensingConfig(), rig=rig, members={"amplifier": mode}).fit(trials, meta)


def test_current_limit_recovered_from_the_shunt_current(limited, twin):
    tr, me, rig, _ = limited
    lim = identify_current_limit(tr, rig.shunt_resistance_ohm, rig.amplifier_gain)
    assert lim.supported
    assert lim.i_lim == pytest.approx(1e-3 / M, rel=0.01)
    tr0, _, rig0 = twin
    assert not identify_current_limit(tr0, rig0.shunt_resistance_ohm, rig0.amplifier_gain).supported


def test_rebuilt_voltage_follows_the_actuator(limited):
    tr, me, rig, truth = limited
    est = _fit(tr, me, rig, "auto")
    assert est.amplifier_["applied"]
    # a current limit is a rate limit too; with the plateau supported the slew part is not searched (a slew found
    # first left the rebuilt voltage 5.9 V from the actuator's on this device)
    assert not est.amplifier_["slew"]["applied"] and "no slew search" in est.amplifier_["slew"]["note"]
    for t, df in tr.items():
        v_true = truth[t]["V"].to_numpy()
        logged = np.mean(np.abs(df["V"].to_numpy() - v_true))
        rebuilt = np.mean(np.abs(est._with_voltage(df)["V"].to_numpy() - v_true))
        assert logged > 5.0          # the command is not the actuator voltage while limited
        assert rebuilt < 0.05 * logged
    # without H (V linear in q between anchors) the rebuild is coarser, but still far better than eq. (56)
    df = tr["val_force"]
    lin = rebuild_voltage(df, rig.shunt_resistance_ohm, rig.amplifier_gain,
                          identify_current_limit(tr, rig.shunt_resistance_ohm, rig.amplifier_gain))
    assert np.mean(np.abs(lin - truth["val_force"]["V"].to_numpy())) < 0.2 * np.mean(
        np.abs(df["V"].to_numpy() - truth["val_force"]["V"].to_numpy()))


def test_table3_moves_towards_the_effect_free_twin(limited, twin):
    tr, me, rig, _ = limited
    before = _summary(tip_table(tr, me, rig, None, estimator=_fit(tr, me, rig, "off")))["mean"]
    after = _summary(tip_table(tr, me, rig, None, estimator=_fit(tr, me, rig, "auto")))["mean"]
    tr0, me0, rig0 = twin
    est0 = _fit(tr0, me0, rig0, "auto")
    assert not est0.amplifier_["applied"]
    without = _summary(tip_table(tr0, me0, rig0, None, estimator=est0))["mean"]
    assert before - without > 5.0
    assert after - without < 0.75 * (before - without)


def test_not_adopted_without_a_limit_and_bit_identical(twin):
    tr0, me0, rig0 = twin
    auto, off = _fit(tr0, me0, rig0, "auto"), _fit(tr0, me0, rig0, "off")
    assert not auto.amplifier_["applied"] and "no current limit" in auto.amplifier_["note"]
    for t in me0.index[me0["role"] == "validation"]:
        assert np.array_equal(auto.estimate(tr0[t]).to_numpy(), off.estimate(tr0[t]).to_numpy())
    with pytest.raises(ValueError, match="amplifier"):
        SelfSensingEstimator(config=SensingConfig(), rig=rig0, members={"amplifier": "maybe"}).fit(tr0, me0)


def test_the_diagnostic_and_the_stream_see_the_adopted_member(limited):
    """One stage chain: the diagnostic's ``rate.amplifier`` is the estimator's amplifier member (its counterfactual
    recalibrates with the member on, its chain table scores the chain without it); a stream or a C export of a model
    that carries it is refused with the reason (the rebuild needs the sample where the limit lets go)."""
    from selfsense.gap.counterfactual import CHAIN_MEMBERS, adopted_members, amplifier_parts
    from selfsense.sensing.export_c import ExportError, c_sources
    from selfsense.sensing.streaming import SelfSensingStream

    tr, me, rig, _ = limited
    est = _fit(tr, me, rig, "auto")
    assert CHAIN_MEMBERS["rate.amplifier"] == "amplifier"
    assert adopted_members(est)["amplifier"]
    assert amplifier_parts(est)["current_limit"] and not amplifier_parts(est)["slew"]   # never both (chain.amplifier)
    off = SelfSensingEstimator(config=SensingConfig(amplifier="off"), rig=rig).fit(tr, me)   # the config switch
    assert not adopted_members(off)["amplifier"] and "config amplifier: off" in off.amplifier_["note"]
    assert not amplifier_parts(off)["current_limit"] and not amplifier_parts(off)["slew"]
    with pytest.raises(NotImplementedError, match="amplifier member"):
        SelfSensingStream(est, dt=1.0 / FS_CASE)
    with pytest.raises(ExportError, match="amplifier member"):
        c_sources(est, rig, 1.0 / FS_CASE)


def test_excitation_matched_twin_receives_the_applied_voltage(limited):
    """The tip tier's truth for an amplifier limit (selfsense.gap.blind.matched_twin_error): the effect-free device
    driven with the voltage the limited amplifier applied. Its actuators receive the case's voltage (to the DAQ's
    command resolution and the amplifier's bandwidth) and its log's V is that voltage, so the twin differs from the
    case only in what the estimator is told, not in the excitation."""
    tr, me, rig, truth = limited
    applied = {t: truth[t]["V_c"].to_numpy(float) for t in tr}
    trm, mem, rigm, truthm = simulate_family_case(FAMILY, DEVICE, {}, NOISE, T_CASE, FS_CASE, with_truth=True,
                                                  applied_v=applied)
    assert list(mem["signal"]) == list(me["signal"])   # trials.csv keeps the protocol's signal names
    for t in tr:
        span = np.ptp(applied[t])
        assert np.max(np.abs(truthm[t]["V_c"].to_numpy(float) - applied[t])) < 1e-3 * span
        assert np.max(np.abs(truthm[t]["V"].to_numpy(float) - truth[t]["V"].to_numpy(float))) < 1e-3 * span
        # the case's log is off by tens of volts while limited; the matched twin's log is its actuator voltage
        assert np.max(np.abs(tr[t]["V"].to_numpy() - truth[t]["V"].to_numpy())) > 0.1 * span
        assert np.max(np.abs(trm[t]["V"].to_numpy() - truthm[t]["V"].to_numpy())) < 1e-3 * span
