"""Same input and config -> the same bits, whatever the BLAS thread settings and whichever thread runs the job.

The pipeline's ``run:`` jobs share the Snakemake process and run in its worker threads. ``threadpoolctl`` applies an
OpenBLAS limit only from the Python thread that first set one, and SciPy loads its own OpenBLAS after the first job
has set its limit, so before ``selfsense.determinism.single_thread_blas`` the H(q) calibration ran on one or two
BLAS threads depending on which worker picked the job, and ``model/hysteresis.json`` / ``model/sensing.json``
differed in the last bits between two identical Snakemake runs. Here the calibration stage runs in two processes:
one on one BLAS thread in its main thread, one with ``OPENBLAS_NUM_THREADS=2`` in a second worker thread while the
first worker (which set the limit) is still alive, as in the Snakemake process, and with the rule's ``threads: 2``
(the H(q) selection cross-validates two candidates at a time, in threads there); and in a process of its own with two
forked workers, as the ``calibrate_hysteresis`` script runs. All must write identical files.
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"

_JOB = r"""
import json, sys, threading
from types import SimpleNamespace as NS
from selfsense import stages

sig, cfg, out, mode = sys.argv[1], json.loads(sys.argv[2]), sys.argv[3], sys.argv[4]
ds, threads = sys.argv[5], int(sys.argv[6])
class Files(list):
    def __init__(self, items, **named):
        super().__init__(items)
        self.__dict__.update(named)
signals = [f"{sig}/cal_free.parquet", f"{sig}/cal_blocked.parquet"]

def calibrate():
    # as the calibrate_hysteresis script runs it: the rule's threads are the candidates cross-validated at a time
    from selfsense.hysteresis.models.select import cv_workers
    with stages.logged(f"{out}/calibrate.log"), cv_workers(threads):
        stages.calibrate(ds, stages.by_trial(signals), cfg, f"{out}/hysteresis.json")
    stages.run_job("regress_coefficients", Files(signals, signals=signals, hysteresis=f"{out}/hysteresis.json"),
                   Files([f"{out}/sensing.json"]), NS(dataset_dir=ds), NS(), [f"{out}/regress.log"])

if mode == "main":
    from selfsense.parallel import can_fork
    print(f"can fork: {can_fork()}", flush=True)
    calibrate()
else:  # a first worker sets the limit and stays alive while a second worker runs the calibration
    first_done, calibrated = threading.Event(), threading.Event()
    def first():
        with stages.logged(f"{out}/first.log"):
            pass
        first_done.set()
        calibrated.wait()
    t1 = threading.Thread(target=first)
    t1.start()
    first_done.wait()
    t2 = threading.Thread(target=calibrate)
    t2.start()
    t2.join()
    calibrated.set()
    t1.join()
"""


def _digest(folder: Path) -> dict[str, str]:
    return {n: hashlib.sha256((folder / n).read_bytes()).hexdigest()
            for n in ("hysteresis.json", "h_selection.csv", "sensing.json")}


def test_calibration_is_bit_identical_across_blas_thread_settings_and_worker_threads(tmp_path):
    from selfsense import stages

    sig = tmp_path / "signals"
    for trial in ("cal_free", "cal_blocked"):
        stages.ingest(SAMPLE, trial, sig / f"{trial}.parquet")
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    cfg = {k: cfg.get(k, {}) for k in ("calibration", "estimation")}
    script = tmp_path / "job.py"
    script.write_text(_JOB)
    runs = {"main_1thread": ("main", "1", "1"), "worker_2threads": ("worker", "2", "2"),
            "main_2forks": ("main", "1", "2")}
    procs = {}
    for name, (mode, n, cv_threads) in runs.items():
        (tmp_path / name).mkdir()
        env = dict(os.environ, OPENBLAS_NUM_THREADS=n, OMP_NUM_THREADS=n, MKL_NUM_THREADS=n,
                   PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
        procs[name] = subprocess.Popen(
            [sys.executable, str(script), str(sig), json.dumps(cfg), str(tmp_path / name), mode, str(SAMPLE),
             cv_threads],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    outs = {}
    for name, p in procs.items():
        outs[name], _ = p.communicate(timeout=600)
        assert p.returncode == 0, f"{name}:\n{outs[name][-3000:]}"
    a, b, c = (_digest(tmp_path / name) for name in runs)
    assert a == b, [n for n in a if a[n] != b[n]]
    # a job in a process of its own (the calibrate_hysteresis script) cross-validates in forked workers: same bits
    assert "can fork: True" in outs["main_2forks"]
    assert a == c, [n for n in a if a[n] != c[n]]
    # the duhem candidates, where one-vs-two-thread rounding showed first, were scored in both runs
    rep = json.loads((tmp_path / "main_1thread" / "hysteresis.json").read_text())["fit_report"]["hysteresis"]
    kinds = [r["kind"] for r in rep["selection"]]
    assert "duhem" in kinds
    # and so was the leakage search, whose searches (all rows, each leave-one-block-out) and error without leakage
    # run in the forked workers too: its numbers are in the files compared above
    search = rep["drift"]["search"]
    assert search["g_cal"] is not None and len(search["g_folds"]) == 3 and not search["reused"]


def test_single_thread_blas_reaches_libraries_loaded_later_and_other_threads():
    """The limit holds for a BLAS library loaded after it was set, and is applied even when another live thread
    controls OpenBLAS limits (where threadpoolctl alone silently does nothing)."""
    code = r"""
import threading, numpy
from threadpoolctl import threadpool_limits, threadpool_info
from selfsense.determinism import single_thread_blas
hold, done = threading.Event(), threading.Event()
def owner():  # takes threadpoolctl's control of OpenBLAS limits and keeps its thread alive
    threadpool_limits(limits=2)
    hold.set()
    done.wait()
t = threading.Thread(target=owner); t.start(); hold.wait()
single_thread_blas()
import scipy.linalg  # SciPy's own OpenBLAS, loaded after the limit
print(sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}))
done.set(); t.join()
"""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="2",
               PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[1]"
