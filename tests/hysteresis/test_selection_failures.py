"""No candidate can break an H(q) selection or a run: a candidate that raises, returns NaN or explodes on some folds
is recorded with its reason and never selected; the artefacts stay valid JSON and name any NaN they refuse."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from selfsense.hysteresis.models import REGISTRY, PlayH
from selfsense.hysteresis.models.select import json_safe_table, select_h_model
from selfsense.io.atomic import dumps_json, write_json_atomic


class _Base:
    joint_extra = True
    convex = True

    def __init__(self, **kw):
        self.extra_coef_ = np.zeros(0)
        self.inner = PlayH(n_play=8, ridge=1e-6, creep=False)

    def label(self):
        return self.kind

    def to_dict(self):
        return {"kind": self.kind}


class NaNH(_Base):
    """A candidate whose fit 'succeeds' and whose prediction is NaN."""
    kind = "test_nan"

    def fit(self, qs, ys, dt, extra=None, row_mask=None):
        return self

    def predict(self, q, dt=None):
        return np.full(len(q), np.nan)


class RaiseH(_Base):
    """A candidate whose fit raises."""
    kind = "test_raise"

    def fit(self, qs, ys, dt, extra=None, row_mask=None):
        raise RuntimeError("solver diverged")

    def predict(self, q, dt=None):  # pragma: no cover - never reached
        raise AssertionError


class ExplodeH(_Base):
    """A good fit that runs away on the last fifth of every segment (a state wandering where no data were)."""
    kind = "test_explode"

    def fit(self, qs, ys, dt, extra=None, row_mask=None):
        self.inner.fit(list(qs), list(ys), dt)
        return self

    def predict(self, q, dt=None):
        p = self.inner.predict(q, dt)
        p[int(0.8 * len(q)):] += 1e3
        return p


@pytest.fixture
def registered(monkeypatch):
    for c in (NaNH, RaiseH, ExplodeH):
        monkeypatch.setitem(REGISTRY, c.kind, c)


def _segments():
    t = np.linspace(0.0, 8.0, 4000)
    q = np.sin(2 * np.pi * 0.5 * t) * (1 + 0.3 * np.sin(2 * np.pi * 0.07 * t))
    truth = PlayH(n_play=6, ridge=0.0, creep=False)
    y = 0.5 * q + 0.2 * np.sign(np.gradient(q)) * (1 - np.exp(-3 * np.abs(q)))  # a loop
    return [q], [y], float(t[1] - t[0]), truth


def test_failed_candidates_are_recorded_and_never_selected(registered):
    qs, ys, dt, _ = _segments()
    cands = (("linear", {}), ("pi", {"n_play": 10, "ridge": 1e-6, "creep": False}), ("test_nan", {}),
             ("test_raise", {}), ("test_explode", {}))
    sel = select_h_model(qs, ys, dt, candidates=cands, n_blocks=5)
    rows = {r["kind"]: r for r in sel.table}
    assert sel.model.kind == "pi"
    assert rows["test_nan"]["status"].startswith("failed: non-finite held-out error")
    assert rows["test_raise"]["status"] == "failed: RuntimeError: solver diverged"
    assert rows["test_explode"]["status"].startswith("rejected: unstable out of sample")
    assert not any(rows[k]["selected"] for k in ("test_nan", "test_raise", "test_explode"))
    # the table goes into the model JSON: the failed rows stay, their numbers as null
    text = dumps_json({"selection": json_safe_table(sel.table)})
    back = {r["kind"]: r for r in json.loads(text)["selection"]}
    assert back["test_nan"]["cv_rms_mean_v"] is None and back["test_raise"]["cv_rms_v"] == [None] * 5


def test_json_writer_names_the_file_and_key_of_a_nan(tmp_path):
    p = tmp_path / "model.json"
    with pytest.raises(ValueError, match=r"model\.json: .*found nan at fit\.selection\[1\]\.cv_rms_v\[2\]"):
        write_json_atomic({"fit": {"selection": [{"cv_rms_v": [1.0]}, {"cv_rms_v": [1.0, 2.0, float("nan")]}]}}, p)
    assert not p.exists()  # nothing half-written


def test_calibration_stage_completes_with_failing_candidates(registered, monkeypatch, tmp_path):
    """The pipeline's calibration stage (the function the rule calls) on the bundled sample dataset, with the three
    broken candidates among the default ones: it completes, writes valid JSON and lists them with their reasons."""
    import selfsense.hysteresis.models.select as sel_mod
    from selfsense import stages

    monkeypatch.setattr(sel_mod, "DEFAULT_CANDIDATES", tuple(sel_mod.DEFAULT_CANDIDATES)
                        + (("test_nan", {}), ("test_raise", {}), ("test_explode", {})))
    ds = Path(__file__).resolve().parents[2] / "data" / "raw" / "sample"
    meta = pd.read_csv(ds / "trials.csv")
    paths = {}
    for t in meta["trial"]:
        paths[t] = tmp_path / f"{t}.parquet"
        stages.ingest(ds, t, paths[t])
    out = tmp_path / "model" / "hysteresis.json"
    out.parent.mkdir()
    est = stages.calibrate(ds, paths, {"calibration": {}, "estimation": {}}, out)
    d = json.loads(out.read_text())
    rows = {r["kind"]: r for r in d["fit_report"]["hysteresis"]["selection"]}
    assert rows["test_nan"]["status"].startswith("failed") and rows["test_raise"]["status"].startswith("failed")
    assert rows["test_explode"]["status"].startswith(("rejected", "failed"))
    assert est.hysteresis_.kind not in ("test_nan", "test_raise", "test_explode")
    csv = pd.read_csv(out.parent / "h_selection.csv")
    assert set(csv["kind"]) >= {"test_nan", "test_raise", "test_explode"}
