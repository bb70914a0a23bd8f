"""The .mat / .csv export of one trial: every column with its unit, sample rate, coefficients with units, config."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io

from selfsense.cli import main as selfsense_main
from selfsense.report.export import EXPORT_COLUMNS, export_trial

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


@pytest.fixture()
def results(tmp_path):
    rng = np.random.default_rng(3)
    n = 500
    t = np.arange(n) / 1000.0
    sig = pd.DataFrame({"t": t, "V": 50 * np.sin(t), "q": 1e-5 * np.sin(t), "u_cmd": 3.3 * np.sin(t),
                        "relay": (t < 0.1).astype(float), "dx_ref": rng.normal(size=n) * 1e-3,
                        "f_ref": np.full(n, np.nan), "V_c": 50 * np.sin(t), "V_s": np.zeros(n)})
    internals = pd.DataFrame({c: rng.normal(size=n) for c in
                              ("dx_hat", "f_hat", "dx_raw", "f_raw", "V_p", "V_H")})
    internals["t"], internals["q"] = t, sig["q"]
    internals["dx_ref"], internals["f_ref"] = sig["dx_ref"], sig["f_ref"]
    res = tmp_path / "results" / "sample"
    for sub in ("signals", "internals", "model"):
        (res / sub).mkdir(parents=True)
    sig.to_parquet(res / "signals" / "cal_free.parquet", index=False)
    internals.to_parquet(res / "internals" / "cal_free.parquet", index=False)
    model = {"coef": {"A1": 1534.0, "A2": -1.9e-3, "A3": -1.2e5, "B21": -2.4e4, "B22": 3.1e-2, "extra_dx": {},
                      "extra_f": {}},
             "h_slope": 8e5, "config": {"h_model": "ri", "h_mode": "thesis", "n_play": 15},
             "fit_report": {"hysteresis": {"trials": ["cal_free"], "rms_pct": 0.4}},
             "calibration_trials": ["cal_free", "cal_blocked"]}
    (res / "model" / "sensing.json").write_text(json.dumps(model))
    return res, sig, internals


def test_mat_and_csv_hold_everything_with_units(results, tmp_path):
    res, sig, internals = results
    out = tmp_path / "out"
    paths = export_trial(SAMPLE, "cal_free", res / "signals" / "cal_free.parquet",
                         res / "internals" / "cal_free.parquet", res / "model" / "sensing.json",
                         out / "cal_free.mat", out / "cal_free.csv")
    assert [p.name for p in paths] == ["cal_free.mat", "cal_free.csv"]
    m = scipy.io.loadmat(out / "cal_free.mat", simplify_cells=True)
    assert set(m["data"]) == set(EXPORT_COLUMNS)
    np.testing.assert_array_equal(m["data"]["V"], sig["V"].to_numpy())
    np.testing.assert_array_equal(m["data"]["q"], sig["q"].to_numpy())
    np.testing.assert_array_equal(m["data"]["dx_raw"], internals["dx_raw"].to_numpy())
    np.testing.assert_array_equal(m["data"]["f_hat"], internals["f_hat"].to_numpy())
    assert m["units"]["q"] == "C" and m["units"]["V"] == "V" and m["units"]["dx_hat"] == "m"
    assert m["units"]["f_raw"] == "N" and m["units"]["t"] == "s"
    assert m["meta"]["sample_rate_hz"] == 1000.0 and m["meta"]["tip"] == "free" and m["meta"]["h_model"] == "ri"
    assert m["coef"]["A1"] == 1534.0 and m["coef_units"]["A1"] == "m/C" and m["coef_units"]["B22"] == "N/V"
    assert json.loads(m["config_json"])["estimator_config"]["n_play"] == 15
    text = (out / "cal_free.csv").read_text()
    assert "# sample_rate_hz: 1000" in text and "A1 = 1534 m/C" in text and "h_slope = 800000 V/C" in text
    csv = pd.read_csv(out / "cal_free.csv", comment="#")
    assert list(csv.columns)[:5] == ["t [s]", "u_cmd [V]", "relay [1]", "V [V]", "q [C]"]
    np.testing.assert_allclose(csv["q [C]"], sig["q"], rtol=1e-8)
    # the same input gives the same bytes (no time stamps)
    first = (out / "cal_free.mat").read_bytes()
    export_trial(SAMPLE, "cal_free", res / "signals" / "cal_free.parquet", res / "internals" / "cal_free.parquet",
                 res / "model" / "sensing.json", out / "cal_free.mat")
    assert (out / "cal_free.mat").read_bytes() == first


def test_cli_export_and_its_errors(results, tmp_path, capsys):
    res, _, _ = results
    assert selfsense_main(["export", str(res), str(SAMPLE), "--out", str(tmp_path / "e"), "--format", "csv"]) == 0
    assert (tmp_path / "e" / "cal_free.csv").exists() and not (tmp_path / "e" / "cal_free.mat").exists()
    capsys.readouterr()
    assert selfsense_main(["export", str(res), str(SAMPLE), "--out", str(tmp_path / "e"),
                           "--trial", "val_force_small"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no results for trial 'val_force_small'" in err
    assert selfsense_main(["export", str(tmp_path / "nothing"), str(SAMPLE), "--out", str(tmp_path / "e")]) == 2
    assert "run 'selfsense run' first" in capsys.readouterr().err
