"""Peak memory of every pipeline job on one long trial: 10 minutes at 10 kHz (6,000,000 samples).

    python benchmarks/memory_pipeline.py [--minutes 10] [--rate 10000] [--out benchmarks/MEMORY.md]

Simulates a dataset with the virtual tweezer (``selfsense simulate``): three short calibration / validation
trials and one long validation trial of ``--minutes`` at ``--rate``; runs the whole Snakefile on it (gap
diagnostic and mode comparison included, ``--cores 2``) in a temporary folder, and records the true peak resident
set size of every job: a ``sitecustomize`` hook on the jobs' ``PYTHONPATH`` writes ``VmHWM`` of
``/proc/self/status`` (the kernel's high-water mark of the process; ``ru_maxrss`` would carry the parent's RSS
across fork and exec) with the job's rule and wildcards when the job's Python exits.
(Snakemake's own ``benchmark:`` ``max_rss`` only samples every 1-30 s and can miss a short peak; it is shown
beside it.) Writes a table with the declared ``mem_mb`` of each rule. Target: every job below 2 GB. Not a test:
it takes several minutes.
"""
from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
TARGET_MB = 2000.0
#: imported by every Python job of the run (PYTHONPATH): appends "rule<TAB>wildcards<TAB>peak kB" at exit
HOOK = """
import atexit, os, resource, sys


def _selfsense_peak():
    # VmHWM: this process's own high-water mark (ru_maxrss would carry the parent's RSS across fork + exec)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        with open("/proc/self/status") as st:
            peak = next(int(l.split()[1]) for l in st if l.startswith("VmHWM:"))
    except (OSError, StopIteration):
        pass
    prog = sys.argv[0] if sys.argv else ""
    if "/.snakemake/scripts/" in prog:  # a script: job, a process of its own
        sm = getattr(sys.modules.get("__main__"), "snakemake", None)
        try:
            items = list(sm.wildcards.items())
        except Exception:
            items = []
        wc = ",".join(f"{k}={v}" for k, v in items)
        line = f"{getattr(sm, 'rule', prog)}\\t{wc}\\t{peak}\\n"
    elif prog.endswith(("snakemake/__main__.py", "/snakemake")):
        line = f"snakemake process (hosts the run: jobs)\\t\\t{peak}\\n"
    else:
        return
    with open(os.environ["SELFSENSE_PEAK_LOG"], "a") as fh:
        fh.write(line)


if os.environ.get("SELFSENSE_PEAK_LOG"):
    atexit.register(_selfsense_peak)
"""


def scenario(minutes: float, rate: float) -> dict:
    short = dict(duration=10, freq=0.6)
    return {"name": "long", "seed": 16, "sample_rate_hz": float(rate), "substeps": 1, "effects_defaults": True,
            "effects": {},
            "trials": [
                dict(trial="cal_free", role="calibration", tip="free", reference="displacement", signal="sine", **short),
                dict(trial="cal_blocked", role="calibration", tip="blocked", reference="force", signal="sine", **short),
                dict(trial="val_force", role="validation", tip="object", object_mm=2.0, reference="force",
                     signal="sine", **short),
                dict(trial="val_long", role="validation", tip="object", object_mm=4.0, reference="displacement",
                     signal="mixed", duration=float(minutes) * 60.0, freq=0.6),
            ]}


def declared_mem_mb() -> dict[str, int]:
    """benchmark file stem (``validate``, ``ingest``, ...) -> resources.mem_mb of its rule, from the rule files."""
    out: dict[str, int] = {}
    for smk in sorted((ROOT / "workflow" / "rules").glob("*.smk")):
        bench, mem = None, None
        for line in smk.read_text().splitlines() + ["rule end:"]:
            if re.match(r"^(?:rule|checkpoint)\s+\w+:", line):
                if bench and mem:
                    out[bench] = mem
                bench, mem = None, None
            m = re.search(r'/benchmarks/([\w.-]+?)(?:/|\.tsv)', line) or \
                re.search(r'"benchmarks",\s*"([\w.-]+?)(?:\.tsv)?"', line)
            if m:
                bench = m.group(1)
            m = re.match(r"^\s+mem_mb=(\d+)", line)
            if m:
                mem = int(m.group(1))
    return out


def timed(cmd: list[str], **kw) -> tuple[int, float, float, str]:
    """(return code, wall s, peak RSS of the child [MB], output tail)."""
    code = ("import resource, subprocess, sys, time; t0 = time.perf_counter(); "
            "p = subprocess.run(sys.argv[1:], capture_output=True, text=True); dt = time.perf_counter() - t0; "
            "sys.stderr.write((p.stdout + p.stderr)[-3000:]); "
            "print(p.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, dt)")
    p = subprocess.run([sys.executable, "-c", code, *cmd], capture_output=True, text=True, **kw)
    rc, rss_kb, dt = p.stdout.split()[-3:]
    return int(rc), float(dt), int(rss_kb) / 1024.0, p.stderr


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=10000.0)
    ap.add_argument("--out", default=str(HERE / "MEMORY.md"))
    ap.add_argument("--h-model", default=None, choices=["modified_pi", "ri"],
                    help="config calibration.h_model of the run (default: the repository's config.yaml)")
    ap.add_argument("--keep", default=None, help="keep the work folder here (default: a temporary one, removed)")
    a = ap.parse_args(argv)
    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="selfsense_mem_"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        sc = work / "scenario.yaml"
        sc.write_text(yaml.safe_dump(scenario(a.minutes, a.rate), sort_keys=False))
        raw = work / "raw"
        rc, t_sim, rss_sim, tail = timed([sys.executable, "-m", "selfsense", "simulate", "--scenario", str(sc),
                                          "--out", str(raw / "long"), "--no-contributions", "--force"])
        if rc != 0:
            print(tail, file=sys.stderr)
            return rc
        cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
        cfg.update(datasets=["long"], raw_dir=str(raw), results_dir=str(work / "results"))
        if a.h_model:
            cfg["calibration"] = dict(cfg.get("calibration") or {}, h_model=a.h_model)
        (work / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        hook = work / "hook"
        hook.mkdir(exist_ok=True)
        (hook / "sitecustomize.py").write_text(HOOK)
        peaks_log = work / "peaks.tsv"
        peaks_log.unlink(missing_ok=True)
        env = dict(os.environ, MPLBACKEND="Agg", SELFSENSE_PEAK_LOG=str(peaks_log),
                   PYTHONPATH=os.pathsep.join([str(hook)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "snakemake", "all", "--cores", "2", "--snakefile",
                            str(ROOT / "Snakefile"), "--directory", str(work), "--configfile",
                            str(work / "config.yaml")], capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
        sampled = {}
        bdir = work / "results" / "long" / "benchmarks"
        for tsv in sorted(bdir.rglob("*.tsv")):
            rel = tsv.relative_to(bdir)
            lines = tsv.read_text().splitlines()
            d = dict(zip(lines[0].split("\t"), lines[1].split("\t")))
            sampled[str(rel.with_suffix(""))] = (float(d["s"]), d["max_rss"])
        bench_of = {"validate_dataset": "validate"}  # rule -> benchmark file stem, where they differ
        rows = []
        for line in peaks_log.read_text().splitlines() if peaks_log.exists() else []:
            rule, wc, kb = line.split("\t")
            stem = bench_of.get(rule, rule)
            trial = dict(kv.split("=", 1) for kv in wc.split(",") if kv).get("trial")
            job = f"{stem}/{trial}" if trial else stem
            if rule.startswith("snakemake process"):
                job, stem = rule, ""
            s_wall, smp = sampled.get(job, (float("nan"), "NA"))
            rows.append((job, stem, s_wall, int(kb) / 1024.0, smp))
        # `run:` rules execute in threads of the Snakemake process when run locally (one process per job on a
        # cluster): re-run each such stage of the long trial in a process of its own, as a cluster job would
        res = work / "results" / "long"
        scratch = work / "rerun"
        scratch.mkdir(exist_ok=True)
        ds = raw / "long"
        cal = {t: str(res / "signals" / f"{t}.parquet") for t in ("cal_free", "cal_blocked")}
        allest = {t: str(res / "estimates" / f"{t}.parquet") for t in ("cal_free", "cal_blocked", "val_force", "val_long")}
        sens = {k: cfg.get(k, {}) for k in ("calibration", "estimation")}
        reruns = {
            "validate": f"stages.validate({str(ds)!r}, {str(scratch / 'v.json')!r})",
            "ingest/val_long": f"stages.ingest({str(ds)!r}, 'val_long', {str(scratch / 's.parquet')!r})",
            "calibrate_hysteresis": f"stages.calibrate({str(ds)!r}, {cal!r}, {sens!r}, {str(scratch / 'h.json')!r})",
            "regress_coefficients": f"stages.regress({str(ds)!r}, {cal!r}, {str(res / 'model' / 'hysteresis.json')!r}, "
                                    f"{str(scratch / 'm.json')!r})",
            "estimate/val_long": f"stages.estimate({str(ds)!r}, {str(res / 'signals' / 'val_long.parquet')!r}, "
                                 f"{str(res / 'model' / 'sensing.json')!r}, {str(scratch / 'e.parquet')!r}, "
                                 f"{str(scratch / 'i.parquet')!r})",
            "score": f"stages.score({str(ds)!r}, {allest!r}, {str(scratch / 'tables')!r})",
        }
        renv = dict(env)
        renv.pop("SELFSENSE_PEAK_LOG", None)
        renv["ARROW_DEFAULT_MEMORY_POOL"] = "system"  # as in the workflow's jobs (workflow/rules/common.smk)
        for job, call in reruns.items():
            if p.returncode != 0:
                break
            rc, t_job, rss_job, tail = timed([sys.executable, "-c", f"from selfsense import stages; {call}"], env=renv)
            stem = job.split("/")[0]
            s_wall, smp = sampled.get(job, (float("nan"), "NA"))
            rows = [r for r in rows if r[0] != job]
            rows.append((job + ("" if rc == 0 else f" (exit {rc})"), stem, t_job, rss_job, smp))
        mem = declared_mem_mb()
        n_long = int(a.minutes * 60 * a.rate)
        peak = max((r[3] for r in rows), default=float("inf"))
        ok = p.returncode == 0 and peak < TARGET_MB
        lines = [
            "# Peak memory per pipeline job on one long trial",
            "",
            f"`python benchmarks/memory_pipeline.py --minutes {a.minutes:g} --rate {a.rate:g}"
            + (f" --h-model {a.h_model}" if a.h_model else "") + "` on "
            f"{platform.node() and 'this project'}'s {os.cpu_count()}-core machine, Python {platform.python_version()}.",
            f"Dataset: `selfsense simulate` (virtual tweezer), three 10 s trials and `val_long`, {a.minutes:g} min at "
            f"{a.rate:g} Hz = {n_long:,} samples; whole Snakefile with `--cores 2` (gap diagnostic and mode "
            f"comparison included). Snakemake exit code {p.returncode}, {wall:.0f} s wall.",
            f"Peak RSS of each job (`VmHWM` of the job's Python at exit, through a `sitecustomize` hook; re-runs: "
            "`ru_maxrss` of the child of a small wrapper) against "
            f"the target of {TARGET_MB:.0f} MB per job: **{'met' if ok else 'NOT met'}** (largest {peak:.0f} MB). "
            "Snakemake's sampled `max_rss` (every 1-30 s) is shown for comparison. The workflow's light rules use "
            "`run:` and execute in threads of the Snakemake process when run locally (a process per job on a "
            "cluster): those stages of the long trial were re-run each in a process of their own on the same "
            "inputs, and the Snakemake process's own peak is listed too (it hosts up to `--cores` such jobs at once).",
            "",
            "| job | wall [s] | peak RSS [MB] | Snakemake max_rss (sampled) [MB] | declared mem_mb |",
            "|---|---|---|---|---|",
        ]
        for job, rule, s, rss, smp in sorted(rows, key=lambda r: -r[3]):
            lines.append(f"| {job} | {s:.1f} | {rss:.0f} | {smp} | {mem.get(rule, '')} |")
        lines += ["", f"Simulating the dataset (not a pipeline job): {t_sim:.0f} s, peak RSS {rss_sim:.0f} MB.", ""]
        if p.returncode != 0:
            lines += ["Snakemake output (tail):", "```", (p.stdout + p.stderr)[-3000:], "```", ""]
        Path(a.out).write_text("\n".join(lines))
        print("\n".join(lines))
        return 0 if ok else 1
    finally:
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
