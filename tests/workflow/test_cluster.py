"""Scale-out: the smoke pipeline on data/raw/sample through a real single-node SLURM cluster gives the same
results as a local run (tables, fitted models, estimates: byte-identical).

The cluster is started by ``cluster/start_local_slurm.sh`` (Debian slurmctld + slurmd + munge; needs root and
apt; only with ``SELFSENSE_TEST_SLURM=1``, because it installs packages and starts daemons) and always stopped afterwards by ``cluster/stop_local_slurm.sh`` (by PID), unless it was already running
before the test. Where SLURM cannot be started (not root, no apt, daemons fail), the same run goes through the
cluster-generic executor with the fake scheduler of ``cluster/submit.sh`` instead, and the test says so in a
warning and on stderr: the scale-out path is still exercised, never silently skipped.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from smk_workdir import DATASET, RAW, ROOT, snakemake_cmd, workdir

START = ROOT / "cluster" / "start_local_slurm.sh"
STOP = ROOT / "cluster" / "stop_local_slurm.sh"
STATE = Path(os.environ.get("SELFSENSE_SLURM_STATE", "/tmp/selfsense-slurm"))
#: artefacts that must be identical between the local and the cluster run
COMPARED = ("tables/*.csv", "model/*.json", "estimates/*.parquet", "gap/*.csv")
#: fit-report keys that hold wall-clock durations (not results; see test_cluster_results_byte_identical_to_local)
WALL_CLOCK_KEYS = ("seconds",)

pytestmark = pytest.mark.slow

# the executor plugins are the optional extra [slurm] (requirements.lock and .ci/run install it)
for _plugin in ("snakemake_executor_plugin_slurm", "snakemake_executor_plugin_cluster_generic"):
    pytest.importorskip(_plugin, reason="the extra [slurm] is not installed: pip install -e '.[slurm]'")


def _say(msg: str) -> None:
    print(f"[test_cluster] {msg}", file=sys.stderr, flush=True)


def _pid_alive(f: Path) -> bool:
    try:
        os.kill(int(f.read_text().strip()), 0)
        return True
    except (OSError, ValueError):
        return False


@pytest.fixture(scope="module")
def engine(request):
    """``{"kind": "slurm"|"cluster-generic", "profile": Path, "reason": str}``; stops what it started."""
    reason = None
    started = False
    if os.environ.get("SELFSENSE_TEST_SLURM", "") != "1":
        # system-level side effects are opt-in: start_local_slurm.sh installs Debian packages and starts munged,
        # slurmctld and slurmd as root (CI sets the variable; .ci/run)
        reason = ("SELFSENSE_TEST_SLURM=1 is not set (the local SLURM cluster installs packages with apt and starts "
                  "daemons as root, so it is opt-in)")
    elif os.environ.get("SELFSENSE_TEST_NO_SLURM"):
        reason = "SELFSENSE_TEST_NO_SLURM is set"
    elif os.geteuid() != 0:
        reason = "not running as root (start_local_slurm.sh installs packages and starts munged/slurmd)"
    elif not (shutil.which("sinfo") or shutil.which("apt-get")):
        reason = "neither SLURM nor apt-get is available on this machine"
    else:
        already = _pid_alive(STATE / "slurmctld.pid") and _pid_alive(STATE / "slurmd.pid")
        try:
            proc = subprocess.run(["bash", str(START)], capture_output=True, text=True, timeout=300)
            rc, err = proc.returncode, proc.stderr
        except subprocess.TimeoutExpired as e:
            rc, err = -1, f"timed out after {e.timeout} s"
        if rc == 0:
            started = not already
            if started:
                request.addfinalizer(lambda: subprocess.run(["bash", str(STOP)], timeout=120))
            _say("local SLURM cluster is up" + (" (was already running; left running)" if already else ""))
        else:
            reason = f"cluster/start_local_slurm.sh failed (exit {rc}): " + " | ".join(err.strip().splitlines()[-5:])
            if not already:  # stop whatever part of the cluster did come up
                request.addfinalizer(lambda: subprocess.run(["bash", str(STOP)], timeout=120))
    if reason is None:
        return {"kind": "slurm", "profile": ROOT / "workflow/profiles/slurm-local", "reason": "", "started": started}
    msg = f"SLURM NOT USED: {reason}. Running through the cluster-generic executor (fake scheduler) instead."
    _say(msg)
    warnings.warn(msg, UserWarning, stacklevel=1)
    return {"kind": "cluster-generic", "profile": ROOT / "workflow/profiles/cluster-generic", "reason": reason,
            "started": False}


def _snakemake(workdir: Path, targets: list[str], extra: list[str]) -> subprocess.Popen:
    cmd, env = snakemake_cmd(workdir, targets, extra)
    _say(" ".join(cmd))
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            cwd=workdir)


def _finish(proc: subprocess.Popen, what: str, timeout: float = 600) -> str:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.terminate()
        out, _ = proc.communicate(timeout=60)
        pytest.fail(f"{what} timed out after {timeout} s:\n{out[-4000:]}")
    assert proc.returncode == 0, f"{what} failed (exit {proc.returncode}):\n{out[-6000:]}"
    return out


def _hashes(results: Path) -> dict[str, str]:
    out = {}
    for pat in COMPARED:
        for p in sorted(results.glob(pat)):
            out[str(p.relative_to(results))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def runs(engine, tmp_path_factory, request):
    if not (RAW / DATASET / "trials.csv").exists():
        pytest.fail(f"{RAW / DATASET} is missing: the bundled sample dataset must be committed")
    # the whole pipeline, gap diagnostic included (its rule runs as a cluster job of its own)
    local = workdir(tmp_path_factory.mktemp("local"), gap={"enabled": True})
    remote = workdir(tmp_path_factory.mktemp(engine["kind"]), gap={"enabled": True})
    # all at once: the cluster runs spend most of their time in job start-up and status polling
    p_remote = _snakemake(remote, ["all"], ["--profile", str(engine["profile"])])
    p_local = _snakemake(local, ["all"], ["--cores", "1"])
    out_local = _finish(p_local, "local run")
    out_remote = _finish(p_remote, f"{engine['kind']} run")
    return {"local": local / "results" / DATASET, "remote": remote / "results" / DATASET,
            "remote_dir": remote, "out_remote": out_remote, "out_local": out_local}


def test_cluster_run_went_through_the_engine(engine, runs):
    out = runs["out_remote"]
    if engine["kind"] == "slurm":
        ids = re.findall(r"submitted with SLURM jobid (\d+)", out)
        assert ids, f"no SLURM submission in the log:\n{out[-3000:]}"
        # MinJobAge=600 keeps finished jobs visible to scontrol: every submitted job completed
        for jid in ids:
            info = subprocess.run(["scontrol", "show", "job", jid], capture_output=True, text=True).stdout
            assert "JobState=COMPLETED" in info, f"SLURM job {jid} did not complete:\n{info}"
        # the per-trial jobs ran in group jobs (profile groups trials_in / trials_out): fewer cluster jobs than
        # pipeline jobs, and the outputs are byte-identical to the local run (test below)
        assert re.search(r"Group job trials_in", out) and re.search(r"Group job trials_out", out), out[-3000:]
        n_jobs = len(re.findall(r"Finished jobid: \d+ \(Rule: (?!all\))", out))
        assert n_jobs and len(ids) < n_jobs, f"{len(ids)} SLURM submissions for {n_jobs} finished jobs: no grouping"
    else:
        args = sorted((runs["remote_dir"] / ".fakecluster").glob("*.args"))
        assert args, "the cluster-generic run submitted no job to cluster/submit.sh"
        first = args[0].read_text()
        assert re.search(r"--mem=\d+ --time=\d+ --cpus=\d+ --name=smk-", first), first
        rcs = [p.with_suffix(".rc").read_text().strip() for p in args]
        assert set(rcs) == {"0"}, rcs
        assert re.search(r"Group job trials_in", out) and re.search(r"Group job trials_out", out), out[-3000:]
        n_jobs = len(re.findall(r"Finished jobid: \d+ \(Rule: (?!all\))", out))
        assert n_jobs and len(args) < n_jobs, f"{len(args)} submissions for {n_jobs} finished jobs: no grouping"
        _say(f"cluster-generic run used instead of SLURM because: {engine['reason']}")


def _json_diff(a, b, path=""):
    """Dotted paths of the leaves where two JSON documents differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}.{k}".lstrip(".") for k in sorted(set(a) ^ set(b))]
        for k in sorted(set(a) & set(b)):
            out += _json_diff(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _json_diff(x, y, f"{path}[{i}]")]
    return [] if a == b else [path.lstrip(".")]


def _strip(doc, keys=WALL_CLOCK_KEYS):
    if isinstance(doc, dict):
        return {k: _strip(v, keys) for k, v in doc.items() if k not in keys}
    if isinstance(doc, list):
        return [_strip(v, keys) for v in doc]
    return doc


def test_cluster_science_identical_to_local(runs):
    """Every table, estimate and fitted number is the same (wall-clock timing fields of the fit reports aside)."""
    a, b = _hashes(runs["local"]), _hashes(runs["remote"])
    assert any(k.startswith("estimates/") for k in a), f"no estimates in the local run: {sorted(a)}"
    assert any(k.startswith("model/") for k in a) and any(k.startswith("tables/") for k in a)
    assert a.keys() == b.keys(), f"different artefacts: {sorted(set(a) ^ set(b))}"
    for k in a:
        if k.endswith(".json"):
            ja = json.loads((runs["local"] / k).read_text())
            jb = json.loads((runs["remote"] / k).read_text())
            assert _strip(ja) == _strip(jb), f"{k}: cluster and local models differ at {_json_diff(ja, jb)}"
        else:
            assert a[k] == b[k], f"{k}: cluster and local results differ"
    assert (runs["remote"] / "report.html").stat().st_size > 0


def test_cluster_results_byte_identical_to_local(runs):
    """Same bytes (determinism rule: no wall-clock in results). Fails while a model JSON records fit durations."""
    a, b = _hashes(runs["local"]), _hashes(runs["remote"])
    diff = [k for k in a if a[k] != b.get(k)]
    detail = []
    for k in diff:
        if k.endswith(".json"):
            ja = json.loads((runs["local"] / k).read_text())
            jb = json.loads((runs["remote"] / k).read_text())
            detail.append(f"{k} differs at {_json_diff(ja, jb)}")
        else:
            detail.append(f"{k} differs")
    assert not diff, "cluster and local results are not byte-identical: " + "; ".join(detail)
