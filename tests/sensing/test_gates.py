"""The member gates of the estimator at their documented thresholds (docs/method.md 6c, 6c'): leakage from the
calibration rows (blocked-CV error not higher, leave-one-block-out estimates within 50 %), leakage from the holds
(calibration error at most 2 % higher), offset drift (gain > 1 %), rest offset (gain > 2 %); and the docs state the
same numbers as the code."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from selfsense.sensing import estimator as E

ROOT = Path(__file__).resolve().parents[2]
EPS = 1e-6


def test_leakage_from_the_calibration_rows_at_its_threshold():
    g = 2e-9
    assert E.leakage_supported_by_calibration(g, [g, 1.1 * g], 1.0, 1.0)               # CV equal: supported
    assert not E.leakage_supported_by_calibration(g, [g, 1.1 * g], 1.0 + EPS, 1.0)     # CV higher: not
    assert E.leakage_supported_by_calibration(g, [0.5 * g + 1e-15, 1.5 * g - 1e-15], 0.9, 1.0)
    assert not E.leakage_supported_by_calibration(g, [0.5 * g - 1e-12], 0.9, 1.0)      # folds disagree by > 50 %
    assert not E.leakage_supported_by_calibration(0.05e-9, [0.05e-9], 0.5, 1.0)        # below 0.1 nS
    # a majority of the leave-one-block-out estimates must agree: 2 of 3, not 1 of 3 (nor 1 of 2)
    assert E.leakage_supported_by_calibration(g, [g, 1.4 * g, 3 * g], 0.9, 1.0)
    assert not E.leakage_supported_by_calibration(g, [g, 0.4 * g, 3 * g], 0.9, 1.0)
    assert not E.leakage_supported_by_calibration(g, [g, 3 * g], 0.9, 1.0)


def test_leakage_from_the_holds_at_its_threshold():
    assert E.leakage_supported_by_holds(True, 1.02 - EPS, 1.0)
    assert not E.leakage_supported_by_holds(True, 1.02 + EPS, 1.0)
    assert not E.leakage_supported_by_holds(False, 0.5, 1.0)


def test_holds_measure_leakage_only_with_a_clear_positive_slope_over_levels_and_trials():
    ev = {"g_s": 4.6e-9, "z": 7.6, "n_levels": 3, "n_trials": 8, "supported": False}
    assert E.leakage_measured_by_holds(ev) == pytest.approx(4.6e-9)    # measured although not supported
    assert E.leakage_measured_by_holds(dict(ev, z=3.9)) is None           # z below Z_SUPPORT
    assert E.leakage_measured_by_holds(dict(ev, g_s=-4.6e-9, z=-7.6)) is None
    assert E.leakage_measured_by_holds(dict(ev, n_levels=1)) is None      # one level: no slope over V
    assert E.leakage_measured_by_holds(dict(ev, n_trials=1)) is None
    assert E.leakage_measured_by_holds({}) is None


def test_calibration_leakage_contradicted_by_the_holds_above_one_and_a_half_times():
    g = 4e-9
    assert E.leakage_contradicted_by_holds(1.5 * g * (1 + EPS), g)
    assert not E.leakage_contradicted_by_holds(1.5 * g * (1 - EPS), g)
    assert not E.leakage_contradicted_by_holds(0.2 * g, g)      # below the holds' value: a relaxation inflates theirs
    assert not E.leakage_contradicted_by_holds(10 * g, None)    # no measurement, no contradiction


def test_calibration_leakage_bounded_by_holds_that_measure_none():
    """Holds that measure no conductance still bound it: a calibration g above 1.5x the largest g they leave
    possible is contradicted; nothing is bounded without a bound, and a g at or below 0.1 nS is none found."""
    from selfsense.chain.charge import Z_SUPPORT, leakage_upper_bound

    ev = {"g_s": -8.4e-12, "g_se_s": 5.4e-11, "g_slow_s": -6.4e-11, "g_slow_se_s": 8.0e-11, "n_levels": 8,
          "n_trials": 8, "resolved": True, "resolution_floor_a": 0.0}
    ub = leakage_upper_bound(ev)
    assert ub == pytest.approx(max(-8.4e-12 + Z_SUPPORT * 5.4e-11, -6.4e-11 + Z_SUPPORT * 8.0e-11))
    assert E.leakage_bounded_by_holds(23.5e-9, ub)
    assert not E.leakage_bounded_by_holds(1.5 * max(ub, E.LEAK_FOUND_S) * (1 - EPS), ub)
    assert E.leakage_bounded_by_holds(1.5 * max(ub, E.LEAK_FOUND_S) * (1 + EPS), ub)
    assert not E.leakage_bounded_by_holds(0.1e-9, 0.0)       # none found is never contradicted
    assert not E.leakage_bounded_by_holds(23.5e-9, None) and not E.leakage_bounded_by_holds(None, ub)
    # a slow relaxation that could hide leakage widens the bound, never narrows it
    assert leakage_upper_bound(dict(ev, g_slow_s=20e-9)) == pytest.approx(20e-9 + Z_SUPPORT * 8.0e-11)
    # no bound from holds in one trial, at one level, on an undithered channel, without a standard error, or with an
    # estimate below zero by more than 4 standard errors (a misspecified hold model: measured -84 +- 7 nS)
    for bad in ({"n_trials": 1}, {"n_levels": 1}, {"resolved": False}, {"resolution_floor_a": 1e-7},
                {"g_se_s": None}, {"g_slow_se_s": None}, {"g_s": -84e-9, "g_se_s": 6.7e-9},
                {"g_slow_s": -1e-9, "g_slow_se_s": 2e-10}):
        assert leakage_upper_bound(dict(ev, **bad)) is None, bad


def test_forced_leakage_from_the_calibration_rows_gives_way_to_the_holds_only_where_the_rows_found_none():
    """Leakage forced on: a calibration-row g of at most 0.1 nS (none found) gives way to the holds' measured
    conductance; any g the rows did find stands, however far below the holds' value (a relaxation inflates theirs:
    tweezer_sim 1.6 nS against 3.2 nS, 0.5 nS true); with nothing measured there is nothing to give way to."""
    g = 58e-9
    assert E.leakage_understated_by_holds(0.1e-9, g) and E.leakage_understated_by_holds(0.02e-9, g)
    assert not E.leakage_understated_by_holds(0.1e-9 * (1 + EPS), g)
    assert not E.leakage_understated_by_holds(1.6e-9, 3.2e-9)
    assert not E.leakage_understated_by_holds(0.0, None)
    assert not E.leakage_understated_by_holds(0.0, 0.05e-9)    # the holds found no more than that either


def test_offset_drift_at_its_threshold():
    assert E.offset_drift_supported(0.99 - EPS, 1.0)
    assert not E.offset_drift_supported(0.99 + EPS, 1.0)


def test_rest_offset_at_its_threshold():
    assert E.rest_offset_supported(0.98 - EPS, 1.0)
    assert not E.rest_offset_supported(0.98 + EPS, 1.0)


def test_rest_offset_gate_is_the_one_the_estimator_applies():
    """_rest_offset decides with the gate: a displacement row with a constant offset adopts it, one without does
    not."""
    import numpy as np

    rng = np.random.default_rng(3)
    n = 600
    X = rng.normal(size=(n, 2))
    y = X @ np.array([1.0, -0.5]) + 0.001 * rng.normal(size=n)
    ok, info = E._rest_offset(X, y + 0.05, [n // 2, n // 2])
    assert ok and info["cv_rms_m_with"] < 0.98 * info["cv_rms_m_without"]
    ok, info = E._rest_offset(X, y, [n // 2, n // 2])
    assert not ok


@pytest.mark.parametrize("const,pct", [("LEAK_HOLD_MAX_CV_RATIO", "2"), ("OFFSET_DRIFT_MIN_GAIN", "1"),
                                       ("REST_OFFSET_MIN_GAIN", "2"), ("LEAK_HOLD_CONTRADICTION", "150")])
def test_docs_state_the_thresholds_the_code_uses(const, pct):
    value = getattr(E, const)
    if const == "LEAK_HOLD_CONTRADICTION":
        assert round(value * 100, 6) == float(pct)
    else:
        assert round(abs(value - 1.0) * 100 if value > 0.5 else value * 100, 6) == float(pct)
    text = (ROOT / "docs" / "method.md").read_text()
    phrase = {"LEAK_HOLD_MAX_CV_RATIO": r"blocked-CV error grows by at most (\d+) % with it",
              "OFFSET_DRIFT_MIN_GAIN": r"lower the blocked-CV error by more than (\d+) %",
              "REST_OFFSET_MIN_GAIN": r"calibration trial\) by more than (\d+) %",
              "LEAK_HOLD_CONTRADICTION": r"more than (\d+) % of the conductance the holds"}[const]
    m = re.search(phrase, text.replace("\n", " ").replace("  ", " "))
    assert m and m.group(1) == pct, (const, m.group(0) if m else None)


def test_offset_drift_config_forces_the_member_and_forced_members_win():
    """``calibration: offset_drift: on|off`` forces the charge link's offset-drift member for every fit of the
    configuration (the gap diagnostic's own forcing through ``members`` still wins); YAML's unquoted on / off
    (booleans) mean the same; an unknown value, or ``on`` with ``drift: off``, is refused by name."""
    rig = {"n_actuators": 2, "actuator_catalog": {"capacitance_f": 1e-6}}
    on = E.SensingConfig.from_mapping({"offset_drift": True})
    assert on.offset_drift == "on" and E.SensingConfig.from_mapping({"offset_drift": False}).offset_drift == "off"
    assert E.SelfSensingEstimator(config=on, rig=rig)._member_modes()["offset_drift"] == "on"
    assert E.SelfSensingEstimator(config=E.SensingConfig(), rig=rig)._member_modes()["offset_drift"] == "auto"
    forced = E.SelfSensingEstimator(config=on, rig=rig, members={"offset_drift": "off"})
    assert forced._member_modes()["offset_drift"] == "off"
    assert E.SelfSensingEstimator(config=on, rig=rig)._member_modes()["leakage"] == "auto"
    with pytest.raises(ValueError, match="SensingConfig.offset_drift: expected 'auto', 'on' or 'off'"):
        E.SensingConfig(offset_drift="sometimes")
    with pytest.raises(ValueError, match="offset_drift 'on' needs drift 'auto'"):
        E.SensingConfig(offset_drift="on", drift="off")
