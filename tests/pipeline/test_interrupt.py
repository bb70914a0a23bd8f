"""An interrupted `selfsense run` (Ctrl-C while rules run) resumes with a plain `selfsense run`: the stale locks are
cleared because no other selfsense run holds the folder, the incomplete outputs are made again, and the results
equal those of an uninterrupted run."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


def _workdir(tmp: Path) -> Path:
    (tmp / "data" / "raw").mkdir(parents=True)
    shutil.copytree(SAMPLE, tmp / "data" / "raw" / "sample")
    (tmp / "config.yaml").write_text("datasets: [sample]\n")
    return tmp


def _run(workdir: Path, **kw):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", "selfsense", "run", "--cores", "2", "--quiet"], cwd=workdir,
                          env=env, capture_output=True, text=True, timeout=900, **kw)


@pytest.mark.skipif(os.name != "posix", reason="process groups and SIGINT as a terminal sends them")
def test_interrupted_run_resumes_with_a_plain_run(tmp_path):
    wd = _workdir(tmp_path / "a")
    env = dict(os.environ, MPLBACKEND="Agg")
    # SIGINT at its default in the child, as under a terminal (a runner started in the background by a
    # non-interactive shell inherits SIGINT ignored, and Python then installs no KeyboardInterrupt handler)
    proc = subprocess.Popen([sys.executable, "-m", "selfsense", "run", "--cores", "2", "--quiet"], cwd=wd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    signals = wd / "results" / "sample" / "signals"
    deadline = time.time() + 300
    while time.time() < deadline and not (signals.exists() and any(signals.glob("*.parquet"))):
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    assert proc.poll() is None, "the run finished before it could be interrupted"
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal: the whole foreground process group
    out, err = proc.communicate(timeout=300)
    assert proc.returncode != 0
    assert not (wd / "results" / "sample" / "report.html").exists()
    # a kill can also leave Snakemake's lock files: the next run must clear them as well
    locks = wd / ".snakemake" / "locks"
    locks.mkdir(parents=True, exist_ok=True)
    (locks / "0.input.lock").write_text(str(wd / "data" / "raw" / "sample" / "trials.csv") + "\n")
    again = _run(wd)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "report: results/sample/report.html" in again.stdout
    assert (wd / "results" / "sample" / "report.html").exists()
    ref = _workdir(tmp_path / "b")
    fresh = _run(ref)
    assert fresh.returncode == 0, fresh.stderr[-3000:]
    for f in ("tables/table3.csv", "model/sensing.json", "model/hysteresis.json"):
        assert (wd / "results" / "sample" / f).read_bytes() == (ref / "results" / "sample" / f).read_bytes(), f
