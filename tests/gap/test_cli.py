"""`selfsense gap diagnose` (stage-wise) writes its contract files on the bundled sample dataset."""
import json
from pathlib import Path

import pandas as pd
import pytest

from selfsense.cli.gap import main

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


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
    # the five stages of the signals and the one read from the fitted chain (its temperature anchors)
    assert set(v["stages"]) == {"holds", "electrical", "mechanical", "blocked", "load", "anchors"}
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
    """A missing dataset folder is a contract error naming the folder and what was expected; nothing is written."""
    from selfsense.io.errors import ContractError

    missing = tmp_path / "nope"
    with pytest.raises(ContractError, match="expected a dataset folder") as e:
        main(["diagnose", str(missing), "--out", str(tmp_path / "o")])
    assert str(missing) in str(e.value)
    assert not (tmp_path / "o").exists()
