"""`selfsense gap diagnose` writes the contract files with the exact columns (on the bundled sample dataset)."""
import json
from pathlib import Path

import pandas as pd
import pytest

from selfsense.gap.cli import main

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


@pytest.mark.skipif(not SAMPLE.is_dir(), reason="bundled sample dataset missing")
def test_diagnose_cli_writes_contract_files(tmp_path):
    out = tmp_path / "gap"
    assert main(["diagnose", str(SAMPLE), "--out", str(out), "--method", "library", "--n-boot", "4"]) == 0
    att = pd.read_csv(out / "attribution.csv")
    assert list(att.columns) == ["effect", "family", "selected", "selection_frequency", "cv_gain", "error_before",
                                 "error_after", "shapley_share", "measurement"]
    assert set(att["measurement"]) == {"displacement", "force"}
    assert att["selection_frequency"].between(0, 1).all()
    assert (att["error_before"] > 0).all()
    v = json.loads((out / "verdict.json").read_text())
    assert isinstance(v["effects"], list) and isinstance(v["unexplained"], bool)
    # the excitation check runs on every dataset; the sample has no rest-then-repeat pair, so a protocol is proposed
    assert set(v["excitation"]["missing"]) | set(v["excitation"]["present"]) == {
        "hold_0V", "hold_high_V", "symmetric_steps", "rest_then_repeat"}
    assert "rest_then_repeat" in v["excitation"]["missing"]
    assert "repeated after a >= 60 s rest" in v["protocol_proposal"]
    # Shapley efficiency: the shares of the confirmed effects sum to before - after (mean over measurements)
    tot = sum(v["shapley_pts"].get("mean", {}).values())
    assert tot == pytest.approx(v["score_before"] - v["score_after_all"], abs=1e-9)
    budget = pd.read_csv(out / "budget.csv")
    assert {"total", "free_case", "sensitivity"} <= set(budget["section"])
    assert any(s.startswith("regime:") for s in budget["section"])
    assert "stage" in set(budget["section"])          # the sample dataset has its truth folder beside it
    shrink = pd.read_csv(out / "shrink.csv")
    assert list(shrink.columns) == ["measurement", "trial", "model", "error_pct", "ci_low", "ci_high"]
    assert (shrink["ci_low"] <= shrink["error_pct"] + 1e-12).all() and (shrink["error_pct"] <= shrink["ci_high"] + 1e-12).all()
    assert (out / "shrink.md").read_text().startswith("# Held-out error")
    for png in ("budget_regimes.png", "shrink.png", "residual_vs_voltage.png"):
        assert (out / png).stat().st_size > 1000


@pytest.mark.skipif(not SAMPLE.is_dir(), reason="bundled sample dataset missing")
def test_stage_diagnose_cli_on_the_sample(tmp_path):
    """The default (stage-wise) diagnosis: every stage reported, the configured estimator's before equals its own
    Table 3 scoring, every candidate has a reason, the excitation check and the figure are there."""
    from selfsense.gap.counterfactual import _summary, tip_table
    from selfsense.gap.data import load_case
    from selfsense.sensing.estimator import SelfSensingEstimator, SensingConfig

    out = tmp_path / "gap"
    assert main(["diagnose", str(SAMPLE), "--out", str(out), "--no-figures"]) == 0
    v = json.loads((out / "verdict.json").read_text())
    assert set(v["stages"]) == {"holds", "electrical", "mechanical", "load"}
    assert v["stages"]["mechanical"]["observed"]
    case = load_case(SAMPLE, with_truth=False)
    ref = _summary(tip_table(case.trials, case.meta, case.rig,
                             lambda r: SelfSensingEstimator(config=SensingConfig(), rig=r)))
    for m in ("displacement", "force"):
        assert v["tip"]["before"][m] == pytest.approx(ref[m], rel=1e-9)
    cands = pd.read_csv(out / "candidates.csv")
    assert cands["why"].str.len().min() > 10 and set(cands["stage"]) <= set(v["stages"])
    assert {"stages.csv", "effects.csv", "shrink.csv", "shrink.md"} <= {p.name for p in out.iterdir()}
    assert "rest_then_repeat" in v["excitation"]["missing"]


def test_cli_rejects_missing_dataset(tmp_path):
    with pytest.raises(Exception):
        main(["diagnose", str(tmp_path / "nope"), "--out", str(tmp_path / "o")])
