"""Real measured data (the external data folder, PROVENANCE.md): the H model selected by blocked CV on the fit record
must beat a straight line and the plain 10-operator PI out of sample on every pair, with no solver failure; and
``selfsense fit-external`` takes any record pair a user names, with the records' declared prehistory."""

import os
from pathlib import Path

import numpy as np
import pytest

# the external measurements are not part of the repository: SELFSENSE_EXTERNAL_DATA names their folder
_EXT = os.environ.get("SELFSENSE_EXTERNAL_DATA", "").strip()
DATA = Path(_EXT) if _EXT else Path("SELFSENSE_EXTERNAL_DATA-is-not-set")


@pytest.mark.slow
def test_selected_h_beats_line_and_pi10_out_of_sample_on_every_external_pair():
    if not all((DATA / d).is_dir() for d in ("smart_hysteresis", "danny_preisach", "slac_quadrupole")):
        pytest.skip("external measurements not available (set SELFSENSE_EXTERNAL_DATA to their folder)")
    from selfsense.hysteresis.external import run

    rows = {r["key"]: r for r in run(DATA)}
    assert set(rows) == {"smart", "sine50_1", "prbn_1", "slac_ru3_ru4", "slac_ru4_ru3"}
    for key, r in rows.items():
        assert r["h_selected"][0] < r["linear"][0], r["pair"]
        assert r["h_selected"][0] < r["baseline_pi10"][0], r["pair"]
        # no solver failure: a candidate is fitted, not offered (it cannot start from a declared prehistory), or
        # refused by the degenerate-fit guard (a QP answer worse than a straight line)
        for c in r["selection"]:
            assert (c["status"] == "ok" or c["status"].startswith("not offered")
                    or c["status"].startswith("failed: DegenerateFitError")), (r["pair"], c["label"], c["status"])
        assert any(c["selected"] and c["status"] == "ok" for c in r["selection"]), r["pair"]
    for key in ("smart", "sine50_1", "prbn_1"):
        r = rows[key]
        assert r["h_selected"][0] < r["provenance_baseline"][0], r["pair"]
        # our NNLS baseline reproduces PROVENANCE's within 15 % (RMS): the comparison is like for like
        assert r["baseline_pi10"][0] == pytest.approx(r["provenance_baseline"][0], rel=0.15), r["pair"]
    for key in ("slac_ru3_ru4", "slac_ru4_ru3"):
        # both magnet runs start at remanence after the 0 -> 165 A -> 0 standardisation: the declared prehistory
        assert "from prehistory 0 -> 165" in rows[key]["selected"], rows[key]["selected"]


def _magnet(x, top=100.0):
    """One-sided synthetic 'magnet': linear + saturating (memoryless) + non-negative play density whose state is the
    remanence of a standardisation cycle 0 -> top -> 0 before the record (thresholds off the models' grids)."""
    from selfsense.hysteresis.operators import play_operator

    r = np.array([3.0, 8.0, 15.0, 25.0, 40.0])
    w = np.array([0.004, 0.003, 0.002, 0.0015, 0.001])
    xx = np.concatenate([[0.0, top, 0.0], x])
    return (0.02 * xx + 0.3 * np.tanh(xx / 80.0) + play_operator(xx, r) @ w)[3:]


def _steps(points, n=12):
    out = [float(points[0])]
    for a, b in zip(points[:-1], points[1:]):
        out += list(np.linspace(a, b, n + 1)[1:])
    return np.array(out)


def test_declared_prehistory_is_the_initial_state_and_wins_out_of_sample():
    """Fitted on minor loops up to 60 and scored on loops up to 90 (range extrapolation): with the declared
    standardisation cycle the selected H beats the straight line and the PI-10 by a clear margin; from the relaxed
    state (the memory the device does not have) it does not even beat the line."""
    from selfsense.hysteresis.external import PrehistoryH, fit_pair
    from selfsense.hysteresis.models import make_model

    xf, xe = _steps([0, 60, 30, 55, 35, 50, 20, 60, 0]), _steps([0, 90, 10, 70, 40, 90, 0])
    yf = _magnet(xf) + 1e-4 * np.random.default_rng(0).standard_normal(xf.size)
    ye = _magnet(xe)
    with_pre = fit_pair(xf, yf, 1.0, xe, ye, 1.0, quasi_static=True, prehistory=(0.0, 100.0, 0.0))
    relaxed = fit_pair(xf, yf, 1.0, xe, ye, 1.0, quasi_static=True)
    assert "from prehistory 0 -> 100 -> 0" in with_pre["selected"]
    assert with_pre["h_selected"][0] < 0.7 * min(with_pre["linear"][0], with_pre["baseline_pi10"][0])
    assert relaxed["h_selected"][0] > 3 * with_pre["h_selected"][0]
    # the prehistory's outputs never enter the fit and the strided design keeps the record's own samples
    m = PrehistoryH(make_model("pi", n_play=10, creep=False), (0.0, 100.0, 0.0))
    m.prepare(xf, 1.0)
    for stride in (1, 2, 5):
        X, _ = m.design(xf, 1.0, stride)
        assert X.shape[0] == xf[::stride].size
    assert m.fit(xf, yf, 1.0).predict(xf).shape == xf.shape


def test_fit_external_accepts_any_record_pair(tmp_path):
    """A user-named pair of CSV records (FILE:X:Y[:T]) is fitted and scored, also with a declared prehistory; a
    missing column or a bad prehistory is one clear error (exit code 2)."""
    import pandas as pd

    from selfsense.cli.fit_external import main
    from selfsense.hysteresis.operators import play_operator

    t = np.arange(4000) * 1e-3
    x = 100 * np.sin(2 * np.pi * 1.0 * t) * np.linspace(1, 0.4, t.size)
    y = 0.02 * x + 0.3 * play_operator(x, [13.0])[:, 0] + 0.8 * np.tanh(x / 40)   # not in the PI-10 class
    pd.DataFrame({"time": t, "volt": x, "disp": y}).to_csv(tmp_path / "a.csv", index=False)
    out = tmp_path / "pair.md"
    assert main(["--fit", f"{tmp_path / 'a.csv'}:volt:disp:time", "--out", str(out)]) == 0
    assert "1st half -> 2nd half" in out.read_text()
    assert main(["--fit", f"{tmp_path / 'a.csv'}:volt:nope"]) == 2

    xf, xe = _steps([0, 60, 30, 55, 35, 50, 20, 60, 0]), _steps([0, 90, 10, 70, 40, 90, 0])
    pd.DataFrame({"I_A": xf, "B_T": _magnet(xf)}).to_csv(tmp_path / "fit.csv", index=False)
    pd.DataFrame({"I_A": xe, "B_T": _magnet(xe)}).to_csv(tmp_path / "eval.csv", index=False)
    pair = ["--fit", f"{tmp_path / 'fit.csv'}:I_A:B_T", "--eval", f"{tmp_path / 'eval.csv'}:I_A:B_T"]
    out2 = tmp_path / "magnet.md"
    assert main(pair + ["--prehistory", "0,100,0", "--quasi-static", "--out", str(out2)]) == 0
    assert "from prehistory 0 -> 100 -> 0" in out2.read_text()
    assert main(pair + ["--prehistory", "0,abc"]) == 2
