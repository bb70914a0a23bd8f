"""Blind check of the stage-wise diagnostic: the committed 1,000-case campaigns (benchmarks/gap_stages: seed 7 and
the seed_* folders; seed_20261226 is the current code and simulator) reproduce from their records and, case by case
(the current code's campaign), on this machine (within stated tolerances, never bit for bit across machines), and a
fast tier of new cases meets floors derived from the campaign."""
from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from selfsense.determinism import STAGE_RMS_RTOL
from selfsense.gap import blind

ROOT = Path(__file__).resolve().parents[2]
CAMPAIGN = ROOT / "benchmarks" / "gap_stages" / "seed_20261226"   #: made with the current diagnostic and simulator


def _records(folder: Path) -> list[dict]:
    with gzip.open(folder / "cases.jsonl.gz", "rt") as fh:
        return [json.loads(line) for line in fh]


@pytest.fixture(scope="module")
def records():
    return _records(CAMPAIGN)


@pytest.mark.parametrize("folder", [CAMPAIGN.parent, CAMPAIGN.parent / "seed_16180", CAMPAIGN.parent / "seed_31337",
                                    CAMPAIGN.parent / "seed_20261201", CAMPAIGN.parent / "seed_20261207",
                                    CAMPAIGN.parent / "seed_20261223", CAMPAIGN.parent / "seed_20261225_before",
                                    CAMPAIGN.parent / "seed_20261225_runmax", CAMPAIGN.parent / "seed_20261226_before",
                                    CAMPAIGN])
def test_committed_scores_recompute_from_the_records(folder):
    records = _records(folder)
    sc = blind.score(records)
    ref = json.loads((folder / "scores.json").read_text())
    assert len(records) == ref["n_cases"] >= 1000
    for k in ("family_top1", "member_top1", "false_alarm_rate", "median_shrink_error", "open_set_flagged"):
        assert sc[k] == pytest.approx(ref[k], rel=1e-9, abs=1e-12), k
    # the campaign spans the four device families, a quarter each
    fams = [r["family"] for r in records]
    assert {f: fams.count(f) for f in blind.FAMILIES} == {f: len(records) // 4 for f in blind.FAMILIES}


def _margin(rec) -> float:
    """Smallest |gain / threshold - 1| over every member of every stage of a record (how close a decision was)."""
    thr = blind.load_stage_thresholds()
    m = np.inf
    for st in rec["prediction"]["stages"].values():
        for k, g in (st.get("gains_alone") or {}).items():
            t = thr.get(k if k != "generic" else f"generic@{st['stage']}")
            if t and np.isfinite(t):
                m = min(m, abs(g / t - 1.0))
    return m


def test_committed_cases_rerun_on_this_machine(records):
    """Four committed cases with clear decisions (every member at least 20 % away from its threshold, one per
    family) rerun here: the same effects named, stage residuals within STAGE_RMS_RTOL (the case's DAQ log simulated
    again on this machine may sit one ADC code away on a few samples)."""
    picked = {}
    for r in records[:200]:
        if r["family"] not in picked and r["manifest"]["effects"] and _margin(r) > 0.2:
            picked[r["family"]] = r
    assert len(picked) == 4
    for r in picked.values():
        new = blind.run_case(r["case"], r["seed"], truth=False)
        assert new["prediction"]["top"] == r["prediction"]["top"]
        assert [e["effect"] for e in new["prediction"]["effects"]] == [e["effect"] for e in r["prediction"]["effects"]]
        for st, d in r["prediction"]["stages"].items():
            if d.get("observed"):
                assert new["prediction"]["stages"][st]["rms_nominal"] == pytest.approx(d["rms_nominal"],
                                                                                       rel=STAGE_RMS_RTOL), (r["case"], st)


def test_fast_tier_meets_floors_from_the_campaign():
    """24 new cases (a seed the campaign did not use). Floors well below the campaign's scores (benchmarks/
    gap_stages/scores.md) so that sampling noise of a small tier does not fail them, but a broken stage does."""
    recs = [blind.run_case(i, 424242) for i in range(24)]
    sc = blind.score(recs)
    # measured on this seed: 13 cases with a present library effect, family and member top-1 0.85, false alarms 0 of
    # 7 effect-free cases, median stage-shrink error 0.14 (the Preisach stand-in; the PI stand-in before it: 0.85,
    # 1 of 7, 0.14); chance for top-1 is about 0.1 (ten library families)
    assert sc["n_library_present"] >= 6
    assert sc["family_top1"] >= 0.7
    assert sc["member_top1"] >= 0.7
    assert sc["false_alarm_rate"] <= 0.25
    assert sc["median_shrink_error"] <= 0.3


@pytest.mark.parametrize("folder", ["gap_stages", "gap_tip", "gap_tip/seed_90210", "gap_tip/seed_27182",
                                    "gap_tip/seed_14142", "gap_tip/seed_20261202"])
def test_committed_tip_tier_recomputes(folder):
    """The tip tier (default estimator, predicted against re-simulated tip shrink) recomputes from its records."""
    camp = ROOT / "benchmarks" / folder
    with gzip.open(camp / "tip_cases.jsonl.gz", "rt") as fh:
        recs = [json.loads(line) for line in fh]
    sc = blind.score_tip(recs)
    ref = json.loads((camp / "tip_scores.json").read_text())
    for k in ("median_tip_shrink_error", "interval_coverage", "tip_noise_floor", "n_costly", "n_costly_named"):
        if k in ref:
            assert sc[k] == pytest.approx(ref[k], rel=1e-9, nan_ok=True), k
    assert sc["n"] == ref["n"] >= 32


def test_tip_shrink_of_a_carried_member_is_scored_from_its_own_base():
    """A member the estimator carries is predicted by its own contribution (the chain without it minus Table 3); its
    truth is the chain without it minus the effect-free twin, not Table 3 minus the twin (which a member that
    recovers the effect drives to 0, making any prediction an error of 1 or more)."""
    def rec(i, e, pred, before, base, twin):
        r = {"case": i, "manifest": {"effects": {e: 1.0}}, "top": e, "effects": [e], "before": before,
             "predicted_shrink": {e: pred}, "interval": {e: [pred - 1, pred + 1]}, "error_without": twin,
             "error_noise": twin + 0.1, "true_shrink": before - twin}
        if base is not None:
            r.update({"base": {e: base}, "true_shrink_from_base": {e: base - twin}})
        return r

    # carried leakage: Table 3 5.4 with the member, 10.5 without it, twin 5.0; the member gives back 5.1 of 5.5
    carried = rec(0, "slow.leakage", 5.1, 5.4, 10.5, 5.0)
    corrected = rec(1, "slow.absorption", 2.0, 9.0, 9.0, 5.0)   # a stage correction: base = Table 3
    sc = blind.score_tip([carried, corrected])
    assert sc["n_scored"] == 2
    errs = sorted([abs(5.1 - 5.5) / 5.5, abs(2.0 - 4.0) / 4.0])
    assert sc["median_tip_shrink_error"] == pytest.approx(np.median(errs))
    assert sc["interval_coverage"] == pytest.approx(0.5)   # 5.5 inside [4.1, 6.1]; 4.0 outside [1, 3]
    # a record written before the base was recorded is scored as it was (Table 3 minus the twin)
    old = rec(2, "slow.leakage", 0.0, 5.4, None, 5.0)
    assert blind.score_tip([old])["median_tip_shrink_error"] == pytest.approx(1.0)   # |0 - 0.4| / 0.4


def _tip_joint():
    import importlib
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        return importlib.import_module("tip_joint")
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_joint_tier_draws_distinct_library_effects_deterministically():
    """The joint tip tier (benchmarks/tip_joint.py) draws 2-3 distinct library effects per case, the families in turn,
    the same for the same seed and case, and its device seeds never meet the single-effect tier's."""
    tj = _tip_joint()
    from selfsense.gap.blindsim import SIM_EFFECTS

    lib = {v[0] for v in SIM_EFFECTS.values() if not v[0].startswith("open.")}
    cases = [tj.draw_joint_case(i, 5) for i in range(40)]
    assert cases == [tj.draw_joint_case(i, 5) for i in range(40)]
    for i, c in enumerate(cases):
        assert 2 <= len(c["effects"]) <= 3 and set(c["effects"]) <= lib
        assert all(1.0 <= m <= 30.0 for m in c["effects"].values())
        assert c["family"] == blind.FAMILIES[i % len(blind.FAMILIES)]
    assert {len(c["effects"]) for c in cases} == {2, 3}
    single = {blind.draw_tip_case(i, 5)["device_seed"] for i in range(40)}
    assert not single & {c["device_seed"] for c in cases}


def test_joint_tier_scores_the_all_together_prediction_against_the_twin():
    """Scored from the prediction's base: error |p - t| / |t|, the interval hit, runaways (error > 1); a case whose
    true joint shrink is within 3 noise floors of 0 is not scored; named effects not drawn are counted."""
    tj = _tip_joint()

    def rec(i, drawn, named, pred, lo, hi, base, twin, noise=0.1):
        return {"case": i, "family": "gpi", "manifest": {"effects": {e: 1.0 for e in drawn}}, "effects": named,
                "shrink_all": pred, "shrink_all_interval_90": [lo, hi], "base_all": base, "error_without": twin,
                "error_noise": twin + noise, "true_all_from_base": base - twin, "true_shrink": base - twin}

    recs = [rec(0, ["slow.leakage", "slow.creep"], ["slow.leakage"], 4.0, 3.0, 5.0, 10.0, 5.0),     # t 5: in
            rec(1, ["slow.leakage", "slow.temperature"], ["slow.temperature", "rate.amplifier"], -2.0, -3.0, -1.0,
                8.0, 4.0),                                                                            # t 4: runaway
            rec(2, ["hysteresis.preload", "load.contact"], [], 0.0, 0.0, 0.0, 3.0, 2.95)]              # t 0.05: not
    s = tj.score(recs)
    floor = np.sqrt(np.mean(np.square([0.1, 0.1, 0.1])) / 2.0)
    assert s["tip_noise_floor"] == pytest.approx(floor)
    assert s["n_scored"] == 2 and [x["scored"] for x in s["rows"]] == [True, True, False]
    assert s["median_error"] == pytest.approx(np.median([1.0 / 5.0, 6.0 / 4.0]))
    assert s["coverage"] == pytest.approx(0.5) and s["runaways"] == 1
    assert (s["drawn_named"], s["n_drawn"], s["false_named"]) == (2, 6, 1)
    assert "| 1 | gpi | slow.leakage, slow.temperature |" in tj.markdown(s, "cmd", None)


def test_matched_twin_rescoring_changes_only_the_truth_of_excitation_effects(monkeypatch, tmp_path):
    """benchmarks/tip_matched_twin.py: an amplifier case's "how far" truth becomes its base minus the excitation-matched
    twin's Table 3 (all together too); its cost (case minus the effect-free twin) and every other case stay as
    recorded; the campaign's own folder is never overwritten."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("tip_matched_twin", ROOT / "benchmarks" / "tip_matched_twin.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    monkeypatch.setattr(mod, "_matched", lambda rec: 29.75)

    def rec(effect, base, before):
        return {"manifest": {"effects": {effect: 5.0}}, "base": {effect: base}, "base_all": base, "before": before,
                "error_without": 5.0, "true_shrink": before - 5.0, "true_shrink_from_base": {effect: base - 5.0},
                "true_all_from_base": base - 5.0, "predicted_shrink": {effect: -0.96},
                "interval": {effect: [-17.7, 13.9]},
                "top": effect, "effects": [effect], "error_noise": 5.3}

    amp, leak = rec("rate.amplifier", 36.61, 37.56), rec("slow.leakage", 10.0, 10.0)
    out = mod.rescore([amp, leak], jobs=1)
    assert out[0]["error_without_matched"] == 29.75
    assert out[0]["true_shrink_from_base"] == {"rate.amplifier": pytest.approx(36.61 - 29.75)}
    assert out[0]["true_all_from_base"] == pytest.approx(36.61 - 29.75)
    assert out[0]["true_shrink"] == pytest.approx(37.56 - 5.0)   # the cost to the user: the effect-free twin
    assert out[1] == leak and amp["true_shrink_from_base"] == {"rate.amplifier": pytest.approx(31.61)}  # inputs kept
    (tmp_path / "tip_cases.jsonl.gz").write_bytes(b"")
    with pytest.raises(SystemExit, match="--out must differ"):
        mod.main(["--records", str(tmp_path), "--out", str(tmp_path)])


def test_a_weak_tip_mode_is_named_and_its_threshold_clears_its_null():
    """The tip-mode member's own null floor (docs/gap.md, seed 5772156): its threshold sits well above every gain it
    took on the 200 effect-free threshold cases, and case 252 of stage seed 20261226 (a tip mode alone, 4 noise floors
    of its stage, member gain 0.02) is now named; under the stage's default floor (threshold 0.056) it was not."""
    doc = json.loads(Path(blind.THRESHOLDS_FILE).read_text())
    thr = doc["thresholds"]["rate.mechanism_mode"]
    nulls = [r["rate.mechanism_mode"] for r in doc["null_gains"] if r.get("rate.mechanism_mode") is not None]
    assert len(nulls) == doc["n"] and max(nulls) < 0.25 * thr < thr < 0.01
    rec = blind.run_case(252, 20261226, truth=False)
    assert rec["manifest"]["effects"].keys() == {"rate.mechanism_mode"}
    gain = rec["prediction"]["stages"]["mechanical"]["gains_alone"]["rate.mechanism_mode"]
    assert 2 * thr < gain < 0.056
    assert rec["prediction"]["top"] == "rate.mechanism_mode"
