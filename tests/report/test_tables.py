"""Table 3 arithmetic (thesis Table 3 convention) and Markdown rendering."""
import numpy as np
import pandas as pd
import pytest

from selfsense.report import tables


def _est(hat, ref, kind):
    if kind == "displacement":
        return pd.DataFrame({"t": np.arange(len(ref)), "dx_hat": hat, "dx_ref": ref, "f_hat": 0.0, "f_ref": np.nan})
    return pd.DataFrame({"t": np.arange(len(ref)), "f_hat": hat, "f_ref": ref, "dx_hat": 0.0, "dx_ref": np.nan})


def test_percent_of_range_is_mean_abs_error_over_reference_span():
    ref = np.array([0.0, 1.0, 2.0, 4.0])
    hat = ref + np.array([0.4, -0.4, 0.4, -0.4])
    e = tables.trial_errors(_est(hat, ref, "displacement"), "displacement")
    assert e["mean_abs_error"] == pytest.approx(0.4)
    assert e["percent_of_range"] == pytest.approx(10.0)


def test_table3_averages_validation_trials_only_and_has_reference_columns():
    meta = pd.DataFrame({"trial": ["c", "v1", "v2", "v3"], "role": ["calibration", "validation", "validation", "validation"],
                         "tip": "free", "signal": "sine", "reference": ["displacement", "displacement", "displacement", "force"]})
    ref = np.linspace(0, 1, 11)
    ests = {"c": _est(ref + 0.5, ref, "displacement"), "v1": _est(ref + 0.1, ref, "displacement"),
            "v2": _est(ref + 0.3, ref, "displacement"), "v3": _est(ref + 0.05, ref, "force")}
    pt = tables.per_trial_table(ests, meta)
    t3 = tables.table3(pt).set_index("measurement")
    assert t3.loc["displacement", "percent_of_range"] == pytest.approx(20.0)  # (10 + 30) / 2, calibration excluded
    assert t3.loc["displacement", "n_trials"] == 2
    assert t3.loc["force", "percent_of_range"] == pytest.approx(5.0)
    assert t3.loc["force", "thesis_percent"] == 12 and t3.loc["force", "badel_percent"] == 2
    md = tables.table3_markdown(tables.table3(pt))
    assert "| displacement |" in md and "12 %" in md and "Kurita" in md


def test_trial_without_reference_is_a_clear_error():
    est = _est(np.zeros(5), np.full(5, np.nan), "force")
    with pytest.raises(ValueError, match="no finite f_ref"):
        tables.trial_errors(est, "force")
