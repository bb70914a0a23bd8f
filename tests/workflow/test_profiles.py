"""Cluster profiles and the checkpoint: no pipeline job may run in a group job.

The pipeline's DAG holds the checkpoint validate_dataset. In Snakemake 9 the DAG update after a checkpoint
re-forms the group jobs from cached GroupJob objects that earlier merges changed in place without redoing their
job order, so a group job can lose part of its jobs and the run stops with "KeyError: estimate" in
dag.update_ready, or not, depending on set order (it stopped the SLURM run of test_cluster once with the stage
groups prep/fit/post). The shipped profiles therefore group only gap_scenario (target gap_benchmark, no
checkpoint), and the workflow refuses any other cluster run that groups jobs while the checkpoint is pending.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml
from smk_workdir import ROOT, snakemake_cmd, workdir

PROFILES = sorted((ROOT / "workflow" / "profiles").glob("*/config.yaml"))
GROUPABLE = {"gap_scenario"}


def _snakemake(wd: Path, targets: list[str], args: list[str]) -> subprocess.CompletedProcess:
    cmd, env = snakemake_cmd(workdir(wd, gap={"benchmark": {"n": 2, "seed": 1, "tier": "fast"}}), targets, args)
    return subprocess.run(cmd, check=False, capture_output=True, text=True, env=env, cwd=wd, timeout=300)


def _groups(profile: Path) -> dict[str, str]:
    cfg = yaml.safe_load(profile.read_text()) or {}
    return dict(item.split("=", 1) for item in cfg.get("groups", []))


def test_profiles_exist():
    assert {p.parent.name for p in PROFILES} >= {"slurm", "slurm-local", "cluster-generic"}


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.parent.name)
def test_profiles_group_only_checkpoint_free_rules(profile):
    groups = _groups(profile)
    assert set(groups) <= GROUPABLE, f"{profile}: groups {sorted(set(groups) - GROUPABLE)} meet the checkpoint"
    cfg = yaml.safe_load(profile.read_text())
    components = dict(item.split("=", 1) for item in cfg.get("group-components", []))
    assert set(components) <= set(groups.values()), f"{profile}: group-components for a group no rule is in"


def test_rules_declare_no_group():
    """A rule's own `group:` would put pipeline jobs into group jobs on every cluster run."""
    for smk in [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]:
        for n, line in enumerate(smk.read_text().splitlines(), 1):
            assert not line.strip().startswith("group:"), f"{smk.name}:{n}: {line.strip()}"


def test_gap_benchmark_dag_holds_no_checkpoint(tmp_path):
    """The premise of grouping gap_scenario: its target's DAG never meets validate_dataset."""
    proc = _snakemake(tmp_path, ["gap_benchmark"], ["-n", "--cores", "1"])
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = proc.stdout + proc.stderr
    assert "gap_scenario" in out
    assert "validate_dataset" not in out and "checkpoint" not in out.lower(), out[-3000:]


def test_cluster_run_grouping_pipeline_rules_is_refused(tmp_path):
    """The old stage groups, given on the command line, stop the run before any job with a clear error."""
    pytest.importorskip("snakemake_executor_plugin_cluster_generic")
    proc = _snakemake(tmp_path, [], ["--profile", str(ROOT / "workflow/profiles/cluster-generic"),
                                 "--groups", "ingest=prep", "estimate=fit", "--group-components", "prep=1000"])
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out[-3000:]
    assert "ingest" in out and "checkpoint validate_dataset" in out and "docs/scale_out.md" in out, out[-3000:]
    assert not (tmp_path / "results" / "sample").exists(), "a job ran before the refusal"
    assert not list((tmp_path / ".fakecluster").glob("*.args")), "a job was submitted before the refusal"


def test_gap_benchmark_beside_the_pipeline_is_refused(tmp_path):
    """gap_scenario grouped by the shipped profile, but requested with a dataset target: the checkpoint is in."""
    pytest.importorskip("snakemake_executor_plugin_cluster_generic")
    proc = _snakemake(tmp_path, ["gap_benchmark", "all"], ["--profile", str(ROOT / "workflow/profiles/cluster-generic")])
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out[-3000:]
    assert "gap_scenario" in out and "invocation of its own" in out, out[-3000:]
    assert not (tmp_path / "results").exists(), "a job ran before the refusal"
