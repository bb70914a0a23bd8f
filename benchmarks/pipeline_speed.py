"""Cold pipeline time and where it goes: start-up against compute, per rule, in one run.

    python benchmarks/pipeline_speed.py                       # tweezer_sim, --cores 2, cold results
    python benchmarks/pipeline_speed.py --numba-cold          # also an empty numba cache
    python benchmarks/pipeline_speed.py --out speed.md          # also write the table to a file

Runs ``snakemake all --cores N`` of the repository's Snakefile (with its workflow profile ``profiles/default``) on
one bundled dataset in a fresh temporary working directory, so every result is computed again. Snakemake is started
as ``selfsense run`` starts it (:func:`selfsense.cli.run.snakemake_command`: a local run without the SLURM executor
plugins' start-up probe). Reports

* the pipeline time by Snakemake's own clock (its closing line ``Elapsed time: ...``) and by this script's;
* per rule: the number of jobs, the jobs' wall time summed from Snakemake's ``benchmark:`` files, and the split
  of each job into *start-up* and *compute* from the ``timing:`` line that ``selfsense.stages.logged`` appends to
  the job's log. Start-up = age of the job's process when its code starts (interpreter, imports, Snakemake's
  script preamble); 0 for ``run:`` rules, which execute in threads of the Snakemake process. Compute = time
  inside the job (lazy imports and numba cache loads included). ``other`` = benchmark wall - start-up - compute
  (spawning the script, Snakemake's bookkeeping around the job);
* the load average before and after the run: on a shared machine the times scale with it.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
TIMING = re.compile(r"^timing: startup_s=([0-9.naninf]+) compute_s=([0-9.naninf]+)$", re.M)
ELAPSED = re.compile(r"Elapsed time: (\d+):(\d+):(\d+(?:\.\d+)?)")


def _rule_of(bench: Path, bench_root: Path) -> str:
    rel = bench.relative_to(bench_root)
    name = rel.parts[0] if len(rel.parts) > 1 else rel.stem
    return {"validate": "validate_dataset"}.get(name, name)


def _log_of(bench: Path, bench_root: Path) -> Path:
    logs = bench_root.parent / "logs"
    rel = bench.relative_to(bench_root).with_suffix(".log")
    return logs / rel


def slurm_probe_s() -> float | None:
    """Seconds that ``scontrol show config`` takes here, or None without SLURM's client. Snakemake's SLURM executor
    plugin (in the lock for the cluster profiles) runs it at every Snakemake start when ``sinfo`` is on PATH: a
    machine with SLURM's client installed but its controller down (after the scale-out test, say) waits for its
    time-out at every start; one without SLURM, or with its controller up, does not."""
    import shutil

    if shutil.which("sinfo") is None or shutil.which("scontrol") is None:
        return None
    t0 = time.perf_counter()
    try:
        subprocess.run(["scontrol", "show", "config"], capture_output=True, timeout=60)
    except subprocess.TimeoutExpired:
        pass
    return time.perf_counter() - t0


def run(dataset: str, cores: int, numba_cold: bool, keep: Path | None) -> dict:
    work = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="selfsense-speed-"))
    work.mkdir(parents=True, exist_ok=True)
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    cfg.update(datasets=[dataset], raw_dir=str(ROOT / "data" / "raw"), results_dir="results")
    (work / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    env = dict(os.environ, MPLBACKEND="Agg")
    if numba_cold:
        env["NUMBA_CACHE_DIR"] = str(work / "numba-cache")
    from selfsense.cli.run import snakemake_command

    cmd = snakemake_command(["all", "--snakefile", str(ROOT / "Snakefile"), "--directory", str(work), "--configfile",
                             str(work / "config.yaml"), "--cores", str(cores)], env)
    local = cmd[2] != "snakemake"
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=work)
    wall = time.perf_counter() - t0
    load1 = os.getloadavg()
    out = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise SystemExit(f"snakemake failed (exit {proc.returncode}):\n{out[-4000:]}")
    m = ELAPSED.findall(out)
    sm_clock = float(m[-1][0]) * 3600 + float(m[-1][1]) * 60 + float(m[-1][2]) if m else float("nan")
    bench_root = work / "results" / dataset / "benchmarks"
    rules: dict[str, dict] = defaultdict(lambda: {"jobs": 0, "wall": 0.0, "startup": 0.0, "compute": 0.0})
    for b in sorted(bench_root.rglob("*.tsv")):
        r = rules[_rule_of(b, bench_root)]
        r["jobs"] += 1
        r["wall"] += float(b.read_text().splitlines()[-1].split("\t")[0])
        log = _log_of(b, bench_root)
        t = TIMING.findall(log.read_text()) if log.exists() else []
        if t:
            r["startup"] += float(t[-1][0])
            r["compute"] += float(t[-1][1])
    return {"dataset": dataset, "cores": cores, "numba_cold": numba_cold, "snakemake_s": sm_clock, "wall_s": wall,
            "load": (load0, load1), "rules": dict(rules), "workdir": str(work), "slurm_probe_s": slurm_probe_s(),
            "probe_skipped": local}


def markdown(res: dict) -> str:
    rows = sorted(res["rules"].items(), key=lambda kv: -kv[1]["wall"])
    tot = {k: sum(r[k] for _, r in rows) for k in ("jobs", "wall", "startup", "compute")}
    lines = [
        f"Cold pipeline on `{res['dataset']}`, `--cores {res['cores']}`"
        f"{', empty numba cache' if res['numba_cold'] else ''}: **{res['snakemake_s']:.1f} s** by Snakemake's clock "
        f"({res['wall_s']:.1f} s wall for the whole `snakemake` process); load average "
        f"{res['load'][0][0]:.2f} before, {res['load'][1][0]:.2f} after (machine with {os.cpu_count()} cores).",
        "",
        *([f"On this machine SLURM's client is installed and `scontrol show config` takes {res['slurm_probe_s']:.1f} s: "
           "Snakemake's SLURM executor plugin runs it at every start (its controller is down here). "
           + ("A local `selfsense run` starts Snakemake without that plugin (`selfsense.cli._local_snakemake`), so "
              "the wall time above does not include the wait; `python -m snakemake` started by hand still waits."
              if res.get("probe_skipped") else "That wait is part of the wall time above."), ""]
          if res.get("slurm_probe_s") is not None and res["slurm_probe_s"] > 1.0 else []),
        "| rule | jobs | job wall, s (sum) | start-up, s | compute, s | other, s | start-up / (start-up + compute) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in rows + [("**all jobs**", tot)]:
        sc = r["startup"] + r["compute"]
        ratio = f"{r['startup'] / sc:.2f}" if sc > 0 else "n/a"
        other = r["wall"] - sc
        lines.append(f"| {name} | {r['jobs']} | {r['wall']:.2f} | {r['startup']:.2f} | {r['compute']:.2f} | "
                     f"{other:.2f} | {ratio} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="tweezer_sim")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--numba-cold", action="store_true", help="run with an empty NUMBA_CACHE_DIR")
    ap.add_argument("--keep", type=Path, default=None, help="working directory to use and keep")
    ap.add_argument("--out", type=Path, default=None, help="also write the Markdown table here")
    a = ap.parse_args(argv)
    md = markdown(run(a.dataset, a.cores, a.numba_cold, a.keep))
    print(md, end="")
    if a.out:
        a.out.write_text(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
