"""``selfsense run``: run the Snakemake pipeline of this checkout and print the path of every report.

Usage: ``selfsense run [--cores N] [--configfile FILE] [extra snakemake arguments...]``

It must be started from the project root (where ``Snakefile`` and ``config.yaml`` live). The last lines printed
are the paths of the HTML reports of the datasets listed in the config.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import yaml


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="selfsense run", description=__doc__.splitlines()[0])
    ap.add_argument("--cores", default="2")
    ap.add_argument("--configfile", default=None)
    ap.add_argument("--directory", default=".")
    args, extra = ap.parse_known_args(argv)
    root = Path(args.directory).resolve()
    snakefile = root / "Snakefile"
    if not snakefile.exists():
        print(f"selfsense run: no Snakefile in {root}; run it from the project root", file=sys.stderr)
        return 2
    cmd = [sys.executable, "-m", "snakemake", "--cores", str(args.cores), "--snakefile", str(snakefile),
           "--directory", str(root)]
    if args.configfile:
        cmd += ["--configfile", args.configfile]
    cmd += extra
    rc = subprocess.call(cmd, cwd=root)
    if rc != 0:
        return rc
    cfg_path = Path(args.configfile) if args.configfile else root / "config.yaml"
    cfg = yaml.safe_load(cfg_path.read_text())
    results = root / cfg.get("results_dir", "results")
    for d in cfg["datasets"]:
        report = results / d / "report.html"
        if report.exists():
            print(f"report: {report.relative_to(root) if report.is_relative_to(root) else report}")
    return 0
