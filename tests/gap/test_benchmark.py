"""Fast benchmark tier: tens of blind cases, scores must stay above floors set a bit below what was measured.

Measured (see docs/gap.md): `selfsense gap benchmark --n 100 --seed 3 --tier fast --sim toy --estimator fast`.
"""
import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from selfsense.determinism import JSON_RTOL, compare_tree
from selfsense.gap.benchmark import run_scenario, score


@pytest.fixture(scope="module")
def records():
    return [run_scenario(i, 5, "fast", sim_kind="toy", estimator="fast") for i in range(24)]


def test_manifest_is_sealed_from_the_diagnostic(records):
    for r in records:
        # the prediction is computed before the truth; the record keeps them apart
        assert set(r) >= {"manifest", "truth", "prediction"}
        assert set(r["prediction"]["effects"]) <= {"slow.creep", "slow.leakage", "slow.offset_drift", "slow.absorption",
                                                   "slow.temperature", "rate.mechanism_mode", "rate.amplifier",
                                                   "hysteresis.one_sided", "hysteresis.preload",
                                                   "hysteresis.few_operators", "load.cross_terms",
                                                   "load.stress_hysteresis", "load.contact"}


def test_truth_shapley_sums_to_the_counterfactual_gap(records):
    for r in records:
        ts = r["truth"]["true_shrink"]
        if ts:
            assert sum(ts.values()) == pytest.approx(r["truth"]["gap"], abs=1e-9)


def test_fast_tier_scores_above_floors(records):
    sc = score(records)
    assert sc["n_effect_free"] >= 3
    assert sc["false_alarm_rate_effect_free"] <= FLOOR_FA
    assert sc["family_top1"] >= FLOOR_FAMILY
    assert sc["member_top1"] >= FLOOR_MEMBER


# measured on these 24 cases (seed 5, toy, 10 s trials, thresholds "toy" from 120 null cases): false alarms 0/6,
# family top-1 5/12, member top-1 3/12
FLOOR_FA = 0.2
FLOOR_FAMILY = 0.3
FLOOR_MEMBER = 0.15


CAMPAIGN = Path(__file__).resolve().parents[2] / "benchmarks" / "gap_campaign" / "cases.jsonl.gz"
#: campaign cases (seed 2026) whose single present effect the diagnostic named (top-1), and one open-set case it
#: flagged "unexplained": a change that loses them is a regression (README, 1,000-case campaign)
KNOWN_RIGHT = {20: "rate.amplifier", 45: "slow.creep", 73: "hysteresis.one_sided", 117: "slow.absorption",
               390: "slow.leakage", 89: "unexplained"}


@pytest.fixture(scope="module")
def campaign():
    with gzip.open(CAMPAIGN, "rt") as f:
        return {r["case"]: r for r in map(json.loads, f)}


@pytest.fixture(scope="module")
def rerun():
    return {i: run_scenario(i, 2026, "fast") for i in KNOWN_RIGHT}


def test_campaign_cases_are_reproduced(campaign, rerun):
    """Case i of seed 2026 rerun here gives the committed campaign record (per-case seeds, no state shared
    between cases): the same manifest, truth and verdict. The records were made on another machine: manifest
    numbers agree to JSON_RTOL, scores to 1e-6 (determinism contract, docs/reproducibility.md)."""
    for i, r in rerun.items():
        ref = campaign[i]
        assert compare_tree(r["manifest"], ref["manifest"], rtol=JSON_RTOL) == []
        assert r["truth"]["present"] == ref["truth"]["present"]
        assert r["truth"]["true_shrink"] == pytest.approx(ref["truth"]["true_shrink"], rel=1e-6, abs=1e-9)
        for k in ("effects", "families", "unexplained"):
            assert r["prediction"][k] == ref["prediction"][k]
        assert r["prediction"]["shrink"] == pytest.approx(ref["prediction"]["shrink"], rel=1e-6, abs=1e-9)


def test_known_right_campaign_cases_stay_right(rerun):
    for i, want in KNOWN_RIGHT.items():
        pred = rerun[i]["prediction"]
        if want == "unexplained":
            assert pred["unexplained"] and not pred["effects"]
        else:
            assert max(pred["shrink"], key=pred["shrink"].get) == want
            assert want in rerun[i]["truth"]["present"]


def test_campaign_scores_match_the_readme(campaign):
    """The README's numbers are recomputed from the committed case records."""
    sc = score(list(campaign.values()))
    assert sc["n_cases"] == 1000
    assert sc["strong.false_alarm_rate_effect_free"] == pytest.approx(6 / 187)
    assert sc["strong.family_top1"] == pytest.approx(0.185, abs=5e-4)
    assert sc["strong.member_top1"] == pytest.approx(0.116, abs=5e-4)


def test_no_false_alarms_on_effect_free_device_simulations():
    """Device simulator (selfsense.sim), effect-free: the family-wise null calibration keeps alarms rare
    (measured 6 / 187 effect-free cases in the 1,000-case campaign, README)."""
    recs = [run_scenario(i, 11, "fast", effects={}, sim_kind="device") for i in range(6)]
    fa = np.mean([bool(r["prediction"]["effects"]) for r in recs])
    assert fa <= 1 / 6 + 1e-9
