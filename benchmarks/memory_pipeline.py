"""Peak memory of every pipeline job on one long trial (issue 16): 10 minutes at 10 kHz (6,000,000 samples).

    python benchmarks/memory_pipeline.py [--minutes 10] [--rate 10000] [--out benchmarks/MEMORY.md]

Simulates a dataset with the virtual tweezer (``selfsense simulate``): three short calibration / validation
trials and one long validation trial of ``--minutes`` at ``--rate``; runs the whole Snakefile on it (gap
diagnostic and mode comparison included, ``--cores 2``) in a temporary folder; reads the peak resident set size
of every job from Snakemake's ``benchmark:`` files (``max_rss``) and writes a table with the declared
``mem_mb`` of each rule beside it. Target: every job below 2 GB. Not a test: it takes several minutes.
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
    """rule -> resources.mem_mb, read from the rule files."""
    out: dict[str, int] = {}
    for smk in sorted((ROOT / "workflow" / "rules").glob("*.smk")):
        rule = None
        for line in smk.read_text().splitlines():
            m = re.match(r"^(?:rule|checkpoint)\s+(\w+):", line)
            if m:
                rule = m.group(1)
            m = re.match(r"^\s+mem_mb=(\d+)", line)
            if m and rule:
                out[rule] = int(m.group(1))
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
        (work / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        env = dict(os.environ, MPLBACKEND="Agg")
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "snakemake", "all", "--cores", "2", "--snakefile",
                            str(ROOT / "Snakefile"), "--directory", str(work), "--configfile",
                            str(work / "config.yaml")], capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
        rows = []
        bdir = work / "results" / "long" / "benchmarks"
        for tsv in sorted(bdir.rglob("*.tsv")):
            rel = tsv.relative_to(bdir)
            rule = rel.parts[0] if len(rel.parts) > 1 else rel.stem
            job = str(rel.with_suffix(""))
            lines = tsv.read_text().splitlines()
            d = dict(zip(lines[0].split("\t"), lines[1].split("\t")))
            rows.append((job, rule, float(d["s"]), float(d["max_rss"])))
        mem = declared_mem_mb()
        n_long = int(a.minutes * 60 * a.rate)
        peak = max((r[3] for r in rows), default=float("nan"))
        ok = p.returncode == 0 and peak < TARGET_MB
        lines = [
            "# Peak memory per pipeline job on one long trial",
            "",
            f"`python benchmarks/memory_pipeline.py --minutes {a.minutes:g} --rate {a.rate:g}` on "
            f"{platform.node() and 'this project'}'s {os.cpu_count()}-core machine, Python {platform.python_version()}.",
            f"Dataset: `selfsense simulate` (virtual tweezer), three 10 s trials and `val_long`, {a.minutes:g} min at "
            f"{a.rate:g} Hz = {n_long:,} samples; whole Snakefile with `--cores 2` (gap diagnostic and mode "
            f"comparison included). Snakemake exit code {p.returncode}, {wall:.0f} s wall.",
            f"Peak RSS (`max_rss` of each job's `benchmark:` file) against the target of {TARGET_MB:.0f} MB per job: "
            f"**{'met' if ok else 'NOT met'}** (largest {peak:.0f} MB).",
            "",
            "| job | rule | wall [s] | peak RSS [MB] | declared mem_mb |",
            "|---|---|---|---|---|",
        ]
        for job, rule, s, rss in sorted(rows, key=lambda r: -r[3]):
            lines.append(f"| {job} | {rule} | {s:.1f} | {rss:.0f} | {mem.get(rule, '')} |")
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
