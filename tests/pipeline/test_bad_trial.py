"""Fault behaviour of the real Snakefile: a bad validation trial either stops the run with a clear message
(on_bad_trial: fail, the default) or fails alone and is listed in the report (on_bad_trial: skip)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


@pytest.fixture(scope="module")
def bad_dataset(tmp_path_factory):
    raw = tmp_path_factory.mktemp("raw")
    d = raw / "sample"
    shutil.copytree(SAMPLE, d)
    meta = pd.read_csv(d / "trials.csv")
    victim = meta[meta["role"] == "validation"].iloc[0]
    log = pd.read_parquet(d / victim["file"])
    log.loc[log.index[1234], "v_shunt"] = float("nan")
    log.to_parquet(d / victim["file"], index=False)
    return raw, str(victim["trial"]), str(victim["file"])


def _run(workdir: Path, raw: Path, on_bad_trial: str):
    workdir.mkdir(parents=True, exist_ok=True)
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    cfg.update(datasets=["sample"], raw_dir=str(raw), results_dir="results", on_bad_trial=on_bad_trial)
    cfg["gap"] = {"enabled": False}
    cfg["report"] = {"compare_modes": False}
    (workdir / "config.yaml").write_text(yaml.safe_dump(cfg))
    return subprocess.run(
        [sys.executable, "-m", "snakemake", "--cores", "2", "--snakefile", str(ROOT / "Snakefile"),
         "--directory", str(workdir), "--configfile", str(workdir / "config.yaml"), "--keep-going"],
        capture_output=True, text=True, env=dict(os.environ, MPLBACKEND="Agg"), timeout=900,
    )


def test_default_stops_with_a_message_naming_file_column_and_row(bad_dataset, tmp_path):
    raw, trial, file = bad_dataset
    proc = _run(tmp_path / "w", raw, "fail")
    assert proc.returncode != 0
    log = (tmp_path / "w" / "results" / "sample" / "logs" / "validate.log").read_text()
    assert file in log and "'v_shunt'" in log and "row 1235" in log, log[-2000:]
    assert not (tmp_path / "w" / "results" / "sample" / "validation.json").exists(), "half-written output"


def test_skip_fails_the_trial_alone_and_the_report_lists_it(bad_dataset, tmp_path):
    raw, trial, file = bad_dataset
    proc = _run(tmp_path / "w", raw, "skip")
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = tmp_path / "w" / "results" / "sample"
    v = json.loads((res / "validation.json").read_text())
    assert trial in v["failed"] and trial not in v["trials"]
    assert any("'v_shunt'" in m for m in v["failed"][trial])
    # the DAG is fixed before validation runs (no checkpoint): the skipped trial's per-trial files are placeholders
    from selfsense.stages import skipped_reason

    for kind in ("signals", "estimates", "internals"):
        why = skipped_reason(res / kind / f"{trial}.parquet")
        assert why is not None and "failed validation" in why, (kind, why)
    assert pd.read_parquet(res / "estimates" / f"{trial}.parquet").empty
    pt = pd.read_csv(res / "tables" / "per_trial.csv")
    assert trial not in set(pt["trial"]) and len(pt) == len(v["trials"])
    html = (res / "report.html").read_text()
    assert "Failed trials" in html and trial in html
