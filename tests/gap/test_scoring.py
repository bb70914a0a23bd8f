"""Benchmark bookkeeping: null-calibrated thresholds, the noise floor and the "effects at least 3x the noise floor"
subset, target bookkeeping (no simulation), and the parallel / resumable campaign (four small device cases)."""
import json

import numpy as np
import pytest

from selfsense.gap import benchmark as B


def test_studentised_thresholds_control_the_familywise_rate_and_follow_each_members_null():
    rng = np.random.default_rng(0)
    n = 400
    null = {"narrow": list(rng.normal(0.0, 0.01, n)), "wide": list(rng.normal(0.0, 0.2, n)),
            "never": list(-np.abs(rng.normal(0.0, 0.1, n)))}
    thr, T = B.studentised_thresholds(null, q=0.95, floor=0.02)
    # family-wise: at most 5 % of the null cases have ANY member above its threshold
    any_hit = np.mean([any(null[k][i] > thr[k] for k in null) for i in range(n)])
    assert any_hit <= 0.05 + 1e-12
    # a member with a wide null gets a higher threshold than one with a narrow null; the floor applies
    assert thr["wide"] > 5 * thr["narrow"]
    assert thr["never"] == pytest.approx(T * 0.02)
    assert T >= 1.0


def _rec(effects, present, shrink, gap, noise_delta, pred=(), open_set=False, shrink_pred=None):
    return {"case": 0, "manifest": {"effects": effects},
            "truth": {"present": list(present), "true_shrink": shrink, "gap": gap, "open_set": open_set,
                      "threshold_present": 0.0, "noise_delta": noise_delta},
            "prediction": {"effects": list(pred), "families": sorted({p.split(".")[0] for p in pred}),
                           "shrink": shrink_pred or {p: 1.0 for p in pred}, "unexplained": False},
            "seconds": {"simulate_calibrate_diagnose": 1.0}}


def test_noise_floor_and_strong_subset():
    recs = [_rec({}, [], {}, 0.0, d) for d in (0.2, -0.2, 0.2, -0.2)]
    assert B.noise_floor(recs) == pytest.approx(0.2 / np.sqrt(2))
    fl = B.noise_floor(recs)
    weak = _rec({"slow.creep": 1.0}, ["slow.creep"], {"slow.creep": 2 * fl}, 2 * fl, 0.2)
    strong = _rec({"slow.creep": 1.0, "rate.amplifier": 1.0}, ["slow.creep", "rate.amplifier"],
                  {"slow.creep": 2 * fl, "rate.amplifier": 10 * fl}, 12 * fl, 0.2)
    sub = B.strong_subset(recs + [weak, strong], fl, 3.0)
    assert len(sub) == 5                                  # 4 effect-free + the strong case, not the weak one
    assert sub[-1]["truth"]["present"] == ["rate.amplifier"]


def test_scores_count_top1_and_false_alarms_and_mark_targets(tmp_path):
    recs = [_rec({}, [], {}, 0.0, 0.01), _rec({}, [], {}, 0.0, -0.01, pred=["slow.creep"]),
            _rec({"rate.amplifier": 5.0}, ["rate.amplifier"], {"rate.amplifier": 3.0}, 3.0, 0.01,
                 pred=["rate.amplifier"], shrink_pred={"rate.amplifier": 3.3}),
            _rec({"slow.creep": 5.0}, ["slow.creep"], {"slow.creep": 3.0}, 3.0, 0.01,
                 pred=["slow.leakage"], shrink_pred={"slow.leakage": 1.0})]
    sc = B.score(recs)
    assert sc["false_alarm_rate_effect_free"] == 0.5
    assert sc["member_top1"] == 0.5 and sc["family_top1"] == 1.0
    assert sc["median_shrink_error_detected"] == pytest.approx(np.median([0.1, 2 / 3]))
    assert sc["strong.n_with_present_effect"] == 2
    B.write_scores(sc, tmp_path, "test")
    md = (tmp_path / "scores.md").read_text()
    assert "| strong.false_alarm_rate_effect_free | 0.500 | <= 0.05 | no (off by 0.450) |" in md
    assert "| family_top1 | 1.000 | >= 0.95 | yes |" in md


def test_campaign_is_independent_of_jobs_and_resumes(tmp_path):
    a = B.run_benchmark(2, 4, "fast", tmp_path / "a", jobs=1)
    b = B.run_benchmark(2, 4, "fast", tmp_path / "b", jobs=2)
    for i in range(2):
        ra = json.loads((tmp_path / "a" / "scenarios" / f"{i}.json").read_text())
        rb = json.loads((tmp_path / "b" / "scenarios" / f"{i}.json").read_text())
        assert ra["manifest"] == rb["manifest"] and ra["truth"]["present"] == rb["truth"]["present"]
        assert ra["prediction"]["effects"] == rb["prediction"]["effects"]
        assert ra["truth"]["true_shrink"] == pytest.approx(rb["truth"]["true_shrink"], rel=1e-6, abs=1e-9)
        assert ra["prediction"]["shrink"] == pytest.approx(rb["prediction"]["shrink"], rel=1e-6, abs=1e-9)
    # resume: a finished case file is reused as it is (here: marked), never recomputed
    f = tmp_path / "a" / "scenarios" / "0.json"
    rec = json.loads(f.read_text())
    rec["marker"] = 1
    f.write_text(json.dumps(rec))
    B.run_benchmark(2, 4, "fast", tmp_path / "a", jobs=1)
    assert json.loads(f.read_text())["marker"] == 1
    assert a["n_cases"] == b["n_cases"] == 2
    # a resumed run with other parameters refuses to mix records
    with pytest.raises(ValueError, match="existing case record was made with"):
        B.run_benchmark(2, 5, "fast", tmp_path / "a", jobs=1)
