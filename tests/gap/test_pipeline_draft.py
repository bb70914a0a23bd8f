"""The pipeline's gap rule in two (``gap_diagnose`` drafts the verdict beside the estimate jobs, ``gap_reconcile``
compares it with Table 3 and writes the folder): the folder it writes is byte for byte the one-call
:func:`selfsense.gap.pipeline.run_pipeline_diagnosis` writes from the same verdict."""
import copy
import json

import numpy as np
import pandas as pd

from selfsense.gap.pipeline import finish_from_draft, reconcile, write, write_draft
from selfsense.io import output_dir


def _verdict() -> dict:
    """A verdict of the shape :func:`selfsense.gap.pipeline.diagnose_pipeline` returns: one observed stage with an
    accepted member and a rejected one, a tip counterfactual, NumPy scalars and a NaN (kept by the draft as
    computed)."""
    acc = {"member": "slow.creep", "effect": "slow.creep", "gain": np.float64(0.61), "threshold": 0.2, "note": ""}
    stage = {"observed": True, "trials": ["a", "b"], "rms_nominal": np.float64(0.136), "rms_after": 0.0505,
             "rms_target": np.nan, "accepted": [acc], "generic_gain_after": 0.0026, "unexplained": False,
             "gains_alone": {"slow.creep": 0.61, "slow.leakage": 0.01, "generic": 0.63}, "notes": []}
    v = {"stages": {"mechanical": stage, "load": {"stage": "load", "observed": False}},
         "effects": [{"effect": "slow.creep", "family": "slow", "stage": "mechanical", "member": "slow.creep",
                      "gain": 0.61, "score": np.float64(3.05), "grid_value": 2.0, "unit": "s", "shrink_rms": 0.085}],
         "tip": {"before": {"displacement": 2.0495144259, "force": 3.6153578671, "mean": 2.8324361465},
                 "effects": {"slow.creep": {"after": {"displacement": 1.9, "force": 3.5}, "shrink": 0.12,
                                            "shrink_interval_90": [0.05, 0.2]}},
                 "after_all": {"displacement": 1.9, "force": 3.5}},
         "thresholds": {"slow.creep": 0.2, "slow.leakage": 0.05}}
    from selfsense.gap.pipeline import why_not

    v["candidates"] = why_not(v)
    return v


def test_draft_then_reconcile_writes_the_one_call_folder(tmp_path):
    ds = tmp_path / "dataset"
    ds.mkdir()
    t3 = tmp_path / "table3.csv"
    pd.DataFrame({"measurement": ["displacement", "force"], "percent_of_range": [2.04951, 3.61536]}).to_csv(t3,
                                                                                                          index=False)
    v = _verdict()
    one = tmp_path / "one" / "gap"
    one.parent.mkdir()
    with output_dir(one, [ds], force=True) as tmp:
        write(reconcile(copy.deepcopy(v), t3), tmp)
    write_draft(v, tmp_path / "verdict.pkl", tmp_path / "stage_gains.png")
    two = tmp_path / "two" / "gap"
    two.parent.mkdir()
    finish_from_draft(tmp_path / "verdict.pkl", tmp_path / "stage_gains.png", t3, two, ds)
    names = sorted(p.name for p in one.iterdir())
    assert names == sorted(p.name for p in two.iterdir())
    assert {"verdict.json", "stages.csv", "candidates.csv", "shrink.md", "stage_gains.png"} <= set(names)
    for n in names:
        assert (one / n).read_bytes() == (two / n).read_bytes(), n
    # the reconciliation is in the written verdict: the draft's "before" against Table 3 as the score rule wrote it
    rec = json.loads((two / "verdict.json").read_text())["reconciliation"]
    assert rec["displacement"] == 2.0495144259 - 2.04951 and rec["force"] == 3.6153578671 - 3.61536
