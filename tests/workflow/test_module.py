"""The workflow used as a Snakemake ``module`` from another workflow: a small outer Snakefile imports it with
renamed rules and runs the bundled sample dataset, gap diagnostic included (docs/scale_out.md)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"

OUTER = """\
configfile: "config.yaml"


module selfsense:
    snakefile:
        {snakefile!r}
    config:
        config


use rule * from selfsense as selfsense_*


rule outer_all:
    input:
        "results/sample/report.html",
    default_target: True
"""


@pytest.fixture(scope="module")
def outer_run(tmp_path_factory):
    if not SAMPLE.exists():
        pytest.fail("data/raw/sample is missing: the bundled sample dataset must be committed")
    work = tmp_path_factory.mktemp("outer")
    cfg = {"datasets": ["sample"], "raw_dir": str(ROOT / "data" / "raw"), "results_dir": "results",
           "report": {"compare_modes": False}, "gap": {"enabled": True}}
    (work / "config.yaml").write_text(yaml.safe_dump(cfg))
    (work / "Snakefile").write_text(OUTER.format(snakefile=str(ROOT / "Snakefile")))
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", "--force-use-threads"], cwd=work,
                          capture_output=True, text=True, env=dict(os.environ, MPLBACKEND="Agg"), timeout=900)
    assert proc.returncode == 0, f"outer workflow failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return work / "results" / "sample", proc.stdout + proc.stderr


def test_module_runs_the_whole_pipeline_with_renamed_rules(outer_run, sample_table3_pins):
    res, out = outer_run
    for rule in ("validate_dataset", "ingest", "calibrate_hysteresis", "estimate", "score", "figures", "report"):
        assert f"selfsense_{rule}" in out, f"rule {rule} did not run under its module name"
    t3 = pd.read_csv(res / "tables" / "table3.csv").set_index("measurement")
    assert list(t3.index) == ["displacement", "force"]
    # the workflow as a module gives the pipeline's own accuracy (pins and tolerance: tests/conftest.py)
    for m, (pct, tol) in sample_table3_pins.items():
        assert t3.loc[m, "percent_of_range"] == pytest.approx(pct, abs=tol), (m, t3.loc[m, "percent_of_range"])


def test_module_includes_the_gap_diagnostic(outer_run):
    """The gap rules are part of the module (they used to vanish when imported from elsewhere)."""
    res, out = outer_run
    assert "selfsense_gap_diagnose" in out
    verdict = json.loads((res / "gap" / "verdict.json").read_text())
    assert {"effects", "families", "unexplained", "message", "stages", "tip"} <= set(verdict)
    assert "gap diagnostic" in (res / "report.html").read_text()
