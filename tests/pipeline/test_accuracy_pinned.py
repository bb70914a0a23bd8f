"""End-to-end accuracy pinned near the measured figures: the pipeline's stages (ingest -> calibrate H(q) ->
regress the coefficients -> estimate -> Table 3), in process, with the default configuration, on the bundled
datasets. A regression of the estimator that doubles Table 3 fails here.

Tolerance: 0.3 points of range on each figure (``TABLE3_TOL_POINTS`` in tests/conftest.py). Across machines the inputs differ by at most one ADC code on 0.5 % of
the samples and the fits in their last bits (docs/reproducibility.md), which moves Table 3 by far less than 0.01
points; the margin leaves room for small last-bit differences to move a fit, and is still small against the errors
themselves (a 2x regression moves them by 2-5 points). If a near-tie of two H(q) candidates in the blocked CV
(h_selection.csv) resolves the other way on another machine, this test says so, which is what it is for."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import yaml

from selfsense import io as sio
from selfsense import stages

ROOT = Path(__file__).resolve().parents[2]
#: Table 3 of tweezer_sim (displacement, force, % of range) measured with the default configuration on this
#: project's machine (`selfsense run --cores 2`; benchmarks/RESULTS.md, the README's table); the sample's figures
#: and the tolerance are the suite's (tests/conftest.py). 1.93 until the leakage fold majority (2026-11-27) adopted
#: 1.62 nS of leakage on it (0.5 nS simulated): docs/method.md 6c
TWEEZER_SIM = {"displacement": 2.05, "force": 3.62}


def _table3(dataset: str, tmp: Path) -> pd.Series:
    ds = ROOT / "data" / "raw" / dataset
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    sensing = {k: cfg.get(k, {}) for k in ("calibration", "estimation")}
    meta = sio.load_trials(ds).set_index("trial")
    sig = {t: tmp / "signals" / f"{t}.parquet" for t in meta.index}
    for t, p in sig.items():
        stages.ingest(ds, t, p)
    cal = {t: p for t, p in sig.items() if meta.loc[t, "role"] == "calibration"}
    stages.calibrate(ds, sig, sensing, tmp / "model" / "hysteresis.json")
    stages.regress(ds, cal, tmp / "model" / "hysteresis.json", tmp / "model" / "sensing.json")
    est = {t: tmp / "estimates" / f"{t}.parquet" for t in meta.index}
    for t in meta.index:
        stages.estimate(ds, sig[t], tmp / "model" / "sensing.json", est[t])
    t3 = stages.score(ds, est, tmp / "tables")
    return t3.set_index("measurement")["percent_of_range"]


@pytest.mark.slow
@pytest.mark.parametrize("dataset", ["sample", "tweezer_sim"])
def test_table3_of_the_default_estimator_is_pinned_near_the_measured_figures(dataset, tmp_path, sample_table3_pins):
    t3 = _table3(dataset, tmp_path)
    pins = sample_table3_pins if dataset == "sample" else {m: (v, sample_table3_pins[m][1])
                                                           for m, v in TWEEZER_SIM.items()}
    for m, (pct, tol) in pins.items():
        assert t3[m] == pytest.approx(pct, abs=tol), (dataset, m, float(t3[m]))
