"""Cluster profiles: the pipeline's per-trial jobs run in group jobs, which needs a DAG that is fixed before any job
runs. The pipeline holds no checkpoint (a trial that fails validation with on_bad_trial=skip keeps its per-trial
files as skip placeholders): in Snakemake 9 the DAG update after a checkpoint re-forms group jobs from cached
GroupJob objects and can lose jobs ("KeyError: estimate" in dag.update_ready), which is why the profiles could not
group pipeline rules while validate_dataset was a checkpoint."""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml
from smk_workdir import ROOT, snakemake_cmd, workdir

PROFILES = sorted((ROOT / "workflow" / "profiles").glob("*/config.yaml"))
#: rules the shipped profiles group (the per-trial jobs)
GROUPED = {"ingest", "estimate"}


def _snakemake(wd: Path, targets: list[str], args: list[str]) -> subprocess.CompletedProcess:
    cmd, env = snakemake_cmd(workdir(wd), targets, args)
    return subprocess.run(cmd, check=False, capture_output=True, text=True, env=env, cwd=wd, timeout=300)


def _groups(profile: Path) -> dict[str, str]:
    cfg = yaml.safe_load(profile.read_text()) or {}
    return dict(item.split("=", 1) for item in cfg.get("groups", []))


def test_profiles_exist():
    assert {p.parent.name for p in PROFILES} >= {"slurm", "slurm-local", "cluster-generic"}


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.parent.name)
def test_profiles_group_the_per_trial_jobs(profile):
    groups = _groups(profile)
    assert set(groups) == GROUPED, f"{profile}: groups {sorted(groups)}"
    assert groups["ingest"] != groups["estimate"], "ingest and estimate in one group would chain them per trial"
    cfg = yaml.safe_load(profile.read_text())
    components = dict(item.split("=", 1) for item in cfg.get("group-components", []))
    assert set(components) == set(groups.values()), f"{profile}: group-components {components} vs groups {groups}"
    assert all(int(v) > 1 for v in components.values()), components


def test_rules_declare_no_group():
    """A rule's own `group:` would put pipeline jobs into group jobs on every cluster run."""
    for smk in [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]:
        for n, line in enumerate(smk.read_text().splitlines(), 1):
            assert not line.strip().startswith("group:"), f"{smk.name}:{n}: {line.strip()}"


def test_pipeline_dag_holds_no_checkpoint_and_the_profile_forms_group_jobs(tmp_path):
    """A dry run with a cluster profile plans every trial's ingest and estimate before validation has run, in group
    jobs of the profile's groups, and meets no checkpoint."""
    pytest.importorskip("snakemake_executor_plugin_cluster_generic")
    proc = _snakemake(tmp_path, [], ["-n", "--profile", str(ROOT / "workflow/profiles/cluster-generic")])
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "checkpoint" not in out.lower(), out[-3000:]
    assert "Group job trials_in" in out and "Group job trials_out" in out, out[-3000:]
    n_trials = len((ROOT / "data" / "raw" / "sample" / "trials.csv").read_text().strip().splitlines()) - 1
    for rule in ("ingest", "estimate"):
        row = [ln for ln in out.splitlines() if ln.split()[:1] == [rule]]
        assert row and int(row[-1].split()[-1]) == n_trials, (rule, row)
