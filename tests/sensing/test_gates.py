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


def test_leakage_from_the_holds_at_its_threshold():
    assert E.leakage_supported_by_holds(True, 1.02 - EPS, 1.0)
    assert not E.leakage_supported_by_holds(True, 1.02 + EPS, 1.0)
    assert not E.leakage_supported_by_holds(False, 0.5, 1.0)


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
                                       ("REST_OFFSET_MIN_GAIN", "2")])
def test_docs_state_the_thresholds_the_code_uses(const, pct):
    value = getattr(E, const)
    assert round(abs(value - 1.0) * 100 if value > 0.5 else value * 100, 6) == float(pct)
    text = (ROOT / "docs" / "method.md").read_text()
    phrase = {"LEAK_HOLD_MAX_CV_RATIO": r"blocked-CV error grows by at most (\d+) % with it",
              "OFFSET_DRIFT_MIN_GAIN": r"lower the blocked-CV error by more than (\d+) %",
              "REST_OFFSET_MIN_GAIN": r"calibration trial\) by more than (\d+) %"}[const]
    m = re.search(phrase, text.replace("\n", " ").replace("  ", " "))
    assert m and m.group(1) == pct, (const, m.group(0) if m else None)
