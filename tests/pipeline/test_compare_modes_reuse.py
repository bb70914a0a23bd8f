"""``compare_modes`` reuses the pipeline's fitted model for its own configuration's row and no longer needs the
pipeline's estimates: it estimates that row itself, so that the rule runs beside the estimate jobs. The modes table
must be the same bits whether the row is scored on the pipeline's estimates or on its own."""
from __future__ import annotations

from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


def test_modes_table_is_the_same_with_and_without_the_pipeline_estimates(tmp_path, monkeypatch):
    from selfsense import stages
    from selfsense.hysteresis.models import select

    # a short candidate list for the table's rows selected by blocked CV (no non-convex searches) keeps it quick
    monkeypatch.setattr(select, "DEFAULT_CANDIDATES", (("linear", {}), ("pi", {"n_play": 20, "ridge": 1e-6}),
                                                       ("preisach", {"n_grid": 12, "n_play": 0, "ridge": 1e-4})))

    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    cfg = {k: cfg.get(k, {}) for k in ("calibration", "estimation")}
    # the pipeline model: the thesis' identification of the RI model, one of the table's rows (quick to calibrate)
    cfg["calibration"] = dict(cfg["calibration"], h_model="ri", h_identification="thesis", h_mode="thesis", drift="off")
    trials = sorted(p.stem for p in SAMPLE.glob("*.parquet"))
    sig = {t: tmp_path / "signals" / f"{t}.parquet" for t in trials}
    for t, p in sig.items():
        stages.ingest(SAMPLE, t, p)
    model = tmp_path / "model"
    stages.calibrate(SAMPLE, sig, cfg, model / "hysteresis.json")
    stages.regress(SAMPLE, sig, model / "hysteresis.json", model / "sensing.json")
    est = {t: tmp_path / "estimates" / f"{t}.parquet" for t in trials}
    for t in trials:
        stages.estimate(SAMPLE, sig[t], model / "sensing.json", est[t])
    from selfsense.sensing.estimator import SelfSensingEstimator

    fits = []
    fit = SelfSensingEstimator.fit
    monkeypatch.setattr(SelfSensingEstimator, "fit", lambda self, *a, **k: (fits.append(self.config), fit(self, *a, **k))[1])
    out = {}
    for name, paths in (("read", est), ("own", None)):
        d = tmp_path / name
        d.mkdir()
        stages.compare_modes(SAMPLE, sig, cfg, d / "modes.csv", d / "modes.md", model_json=model / "sensing.json",
                             estimate_paths=paths)
        out[name] = ((d / "modes.csv").read_bytes(), (d / "modes.md").read_bytes())
    assert out["own"] == out["read"]
    assert b"RI (third seed)" in out["own"][1]
    # six rows, five fits each time: the pipeline's own configuration is not fitted again
    assert len(fits) == 10 and all(c.h_model != "ri" or c.h_mode != "thesis" for c in fits)
