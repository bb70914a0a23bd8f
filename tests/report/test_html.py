"""The HTML report as a reviewer reads it: rendered Markdown, provenance, units, calibration trials, model-selection
table, gap section in words; no raw Markdown or JSON in the visible text."""
from __future__ import annotations

import html as _html
import json
import re
import shutil
from pathlib import Path

import pandas as pd
import pytest

from selfsense.report.browser import raw_markup
from selfsense.report.html import build_report, markdown_to_html
from selfsense.report.provenance import dataset_hash, provenance

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


def _visible(page: str) -> str:
    """Visible text, roughly as a browser shows it (closed <details> left out)."""
    page = re.sub(r"<details>.*?</details>", "", page, flags=re.S)
    page = re.sub(r"<(style|script)[^>]*>.*?</\1>", "", page, flags=re.S)
    page = re.sub(r"</?(code|b|i)>", "", page)
    page = re.sub(r"<(br|p|h\d|li|tr|figcaption|table|ul|pre)[^>]*>", "\n", page)
    return _html.unescape(re.sub(r"<[^>]+>", " ", page))


def test_markdown_rendering():
    md = ("# Held-out error (% of range)\n\n## Sub\n\n| a | b |\n|---|:---:|\n| `x` | **1** |\n\n"
          "add this:\n- the levels *hi*, 0\n- a rest\n")
    out = markdown_to_html(md, heading_level=3)
    assert "<h3>Held-out error (% of range)</h3>" in out and "<h4>Sub</h4>" in out
    assert "<td><code>x</code></td><td><b>1</b></td>" in out and "---" not in out
    assert "<li>the levels <i>hi</i>, 0</li>" in out and "<p>add this:</p>" in out
    assert raw_markup(_visible(out)) == []
    assert "&lt;script&gt;" in markdown_to_html("<script>alert(1)</script>")


def test_raw_markup_detector_can_fail():
    assert raw_markup("### Table 3\n| a | b |\n{\"effects\": []}\nplain") == [
        "Markdown heading: ### Table 3", "Markdown table row: | a | b |", 'JSON object: {"effects": []}']


def test_dataset_hash_tracks_content(tmp_path):
    d = tmp_path / "sample"
    shutil.copytree(SAMPLE, d)
    h1, n = dataset_hash(d)
    assert n == 2 + len(pd.read_csv(d / "trials.csv"))
    assert dataset_hash(d)[0] == h1
    (d / "rig.yaml").write_text((d / "rig.yaml").read_text() + "\n")
    assert dataset_hash(d)[0] != h1
    p = provenance(d)
    assert p["dataset"] == "sample" and p["selfsense_version"] and len(p["dataset_sha256"]) == 64
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d", p["data_date"])


@pytest.fixture()
def results(tmp_path):
    res = tmp_path / "results" / "sample"
    (res / "model").mkdir(parents=True)
    (res / "tables").mkdir()
    (res / "gap").mkdir()
    model = {"coef": {"A1": 1534.0, "A2": -1.9e-3, "A3": -1.2e5, "B21": -2.4e4, "B22": 3.1e-2, "extra_dx": {},
                      "extra_f": {}},
             "h_slope": 8e5, "config": {"h_model": "ri", "h_mode": "thesis"},
             "fit_report": {"hysteresis": {"h_model": "ri", "trial": "cal_free", "trials": ["cal_free", "cal_free2"],
                                           "rms_pct": 0.1, "max_pct": 0.5, "rms_v": 0.08}},
             "calibration_trials": ["cal_free", "cal_free2", "cal_blocked"], "ranges": {"dx": [0, 6e-3], "f": [0, 0.1]},
             "amplifier": {"applied": False, "note": "current plateau at 0.85 mA holds 0.1 % of the relay-open "
                                                     "samples: no current limit"}}
    (res / "model" / "sensing.json").write_text(json.dumps(model))
    (res / "tables" / "table3.md").write_text("### Table 3: x\n\n| Measurement | % of range |\n|---|---|\n| force | 9 % |\n")
    pd.DataFrame({"measurement": ["displacement", "force"], "percent_of_range": [9.05, 10.78]}).to_csv(
        res / "tables" / "table3.csv", index=False)
    verdict = {
        "message": "The largest gap is in the mechanical stage: slow.creep.",
        "effects": [{"effect": "slow.creep", "family": "slow", "stage": "mechanical"}], "unexplained": [],
        "stages": {"holds": {"observed": True, "rms_nominal": 2e-5, "rms_after": 2e-5, "accepted": []},
                   "electrical": {"observed": False},
                   "mechanical": {"observed": True, "rms_nominal": 4e-6, "rms_after": 2e-6,
                                  "accepted": [{"effect": "slow.creep", "member": "slow.creep"}]},
                   "load": {"observed": True, "rms_nominal": 0.01, "rms_after": 0.01, "accepted": [],
                            "unexplained": True}},
        "tip": {"before": {"displacement": 9.05, "force": 10.78},
                "effects": {"slow.creep": {"shrink": 0.4, "shrink_interval_90": [0.1, 0.7],
                                           "after": {"displacement": 8.5, "force": 10.5}}}},
        "table3": {"displacement": 9.05, "force": 10.78}, "reconciliation": {"displacement": 0.0, "force": 0.0},
        "candidates": [{"stage": "mechanical", "member": "slow.creep", "gain_alone": 0.5, "threshold": 0.05,
                        "accepted": True, "why": "accepted"},
                       {"stage": "mechanical", "member": "slow.leakage", "gain_alone": 0.01, "threshold": 0.048,
                        "accepted": False, "why": "held-out gain 0.010 is below its null threshold 0.048"}],
        "protocol_proposal": "add to the next acquisition:\n- the levels hi, 0, mid\n- a rest"}
    (res / "gap" / "verdict.json").write_text(json.dumps(verdict))
    (res / "gap" / "shrink.md").write_text("# Held-out error\n\n| measurement | before |\n|---|---|\n| force | 7.9 |\n")
    return res


def test_report_sections_in_words(results):
    cfg = {"datasets": ["sample"], "calibration": {"h_model": "ri", "n_play": 15}}
    page = build_report(SAMPLE, results, [], config=cfg, provenance=provenance(SAMPLE))
    text = _visible(page)
    assert raw_markup(text) == [], raw_markup(text)
    assert "Provenance" in text and "dataset content hash" in text and "git commit" in text
    assert "calibration.n_play" in page  # the layered configuration, as a table
    # the RI model: both free-tip trials named, fit error on the first
    assert "calibrated on trials cal_free, cal_free2" in " ".join(text.split())
    # units on every coefficient
    for name, unit in (("A1", "m/C"), ("A2", "m/V"), ("A3", "N/C"), ("B21", "N/C"), ("B22", "N/V"), ("h_slope", "V/C")):
        assert re.search(rf"<td>{name}</td><td>[^<]+</td><td>{re.escape(unit)}</td>", page), name
    # gap: the stage that carries it, reconciliation with Table 3, the shrink, why a candidate was not confirmed
    flat = " ".join(text.split())
    assert "mechanical (laser against the measured charge, free-tip trials)" in flat
    assert "These are Table 3's numbers (9.05 % / 10.78 %)" in flat
    assert "slow.creep: +0.40 points of range (+0.10 to +0.70)" in flat
    assert "slow.leakage (mechanical): held-out gain 0.010 is below its null threshold 0.048" in flat
    assert "not observed in this dataset" in flat and "(unexplained structure remains)" in flat
    assert "<li>the levels hi, 0, mid</li>" in page
    assert "H(q) model selection" not in text  # no h_selection.csv: no section
    # the voltage link's amplifier member: the decision and its measurement, also where it was not adopted
    assert ("current limit (shunt current of every trial, docs/method.md 1a): read from the command, eq. (56), "
            "current plateau at 0.85 mA holds 0.1 % of the relay-open samples: no current limit") in flat


def test_model_selection_table(results):
    pd.DataFrame({"model_kind": ["linear", "modified_pi", "ri"], "regularisation": [0.0, 1e-3, 1e-2],
                  "cv_rms_fold1": [0.5, 0.3, 0.2], "cv_rms_fold2": [0.6, 0.35, 0.25], "cv_rms_mean": [0.55, 0.325, 0.225],
                  "linear_baseline_rms": [0.55, 0.55, 0.55], "selected": [False, False, True]}).to_csv(
        results / "model" / "h_selection.csv", index=False)
    page = build_report(SAMPLE, results, [])
    assert "<h2>H(q) model selection</h2>" in page
    rows = re.findall(r"<tr class='([^']*)'>(.*?)</tr>", page)
    assert [c for c, _ in rows] == ["", "", "selected"]
    assert "<td>ri</td>" in rows[2][1] and "The selected model (highlighted) is ri" in page
    assert raw_markup(_visible(page)) == []


def test_model_selection_table_is_the_final_models(results):
    """The sensing regression may calibrate H(q) again (the offset drift beside the creep member): the report shows
    the selection of the final model (sensing.json), not the calibration's h_selection.csv."""
    pd.DataFrame({"model": ["linear", "stale"], "kind": ["linear", "preisach"], "cv_rms_mean_V": [0.5, 0.1],
                  "selected": [False, True]}).to_csv(results / "model" / "h_selection.csv", index=False)
    p = results / "model" / "sensing.json"
    d = json.loads(p.read_text())
    d.setdefault("fit_report", {}).setdefault("hysteresis", {})["selection"] = [
        {"label": "linear", "kind": "linear", "cv_rms_v": [0.5, 0.6], "cv_rms_mean_v": 0.55, "selected": False,
         "status": "ok"},
        {"label": "final-preisach", "kind": "preisach", "cv_rms_v": [0.2, None], "cv_rms_mean_v": 0.2,
         "selected": True, "status": "ok"}]
    p.write_text(json.dumps(d))
    page = build_report(SAMPLE, results, [])
    assert "<h2>H(q) model selection</h2>" in page
    assert "final-preisach" in page and "stale" not in page
    rows = re.findall(r"<tr class='([^']*)'>(.*?)</tr>", page)
    assert [c for c, _ in rows] == ["", "selected"]
