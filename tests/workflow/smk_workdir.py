"""A Snakemake working directory on the bundled sample dataset, and the command that runs the workflow there
(shared by test_cluster.py and test_profiles.py; a unique module name, imported directly)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
RAW = Path(os.environ.get("SELFSENSE_TEST_RAW_DIR", ROOT / "data" / "raw"))
DATASET = "sample"


def workdir(path: Path, gap: dict | None = None) -> Path:
    """``path`` with a config.yaml for the sample dataset (``gap`` merged into its ``gap:`` block) and a ``cluster``
    symlink (the cluster-generic profile names its fake-scheduler scripts relatively)."""
    path.mkdir(parents=True, exist_ok=True)
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    cfg.update(datasets=[DATASET], raw_dir=str(RAW), results_dir="results")
    cfg["gap"] = {**(cfg.get("gap") or {}), "enabled": False, **(gap or {})}
    (path / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    if not (path / "cluster").exists():
        (path / "cluster").symlink_to(ROOT / "cluster")
    return path


def snakemake_cmd(wd: Path, targets: list[str], extra: list[str]) -> tuple[list[str], dict]:
    """(argv, env) of ``python -m snakemake targets`` on the repository's Snakefile in ``wd`` (targets first:
    ``--configfile`` takes several values)."""
    env = dict(os.environ, MPLBACKEND="Agg")
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    cmd = [sys.executable, "-m", "snakemake", *targets, "--snakefile", str(ROOT / "Snakefile"),
           "--directory", str(wd), "--configfile", str(wd / "config.yaml"), *extra]
    return cmd, env
