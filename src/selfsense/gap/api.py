"""One-call entry points used by the CLI and the Snakemake scripts."""
from __future__ import annotations

import json
from pathlib import Path

__all__ = ["run_diagnose", "run_scenario_to_json", "aggregate_scenarios"]


def run_diagnose(dataset_dir, out_dir, estimator: str = "sensing", seed: int = 0, n_boot: int = 30,
                 figures: bool = True, progress: bool | None = False):
    """Load a raw dataset (and its truth folder if present), diagnose, write the contract files; returns the
    :class:`~selfsense.gap.diagnose.Diagnosis`.

    ``estimator="sensing"`` (default) diagnoses the project's ``SelfSensingEstimator`` (limiting / DC offset off);
    if it cannot be calibrated on this dataset the fast stand-in is used and the verdict says so."""
    from .data import load_case
    from .diagnose import diagnose
    from .report import write_diagnosis

    case = load_case(dataset_dir, with_truth=True)
    try:
        d = diagnose(case, estimator=estimator, seed=seed, n_boot=n_boot, progress=progress)
    except Exception as exc:  # noqa: BLE001 - report and fall back, never a silent fix
        if estimator == "fast":
            raise
        d = diagnose(case, estimator="fast", seed=seed, n_boot=n_boot)
        d.verdict["estimator_fallback"] = f"{estimator!r} failed ({type(exc).__name__}: {exc}); used 'fast'"
    write_diagnosis(d, out_dir, figures=figures)
    return d


def run_scenario_to_json(i: int, seed: int, tier: str, out_path, sim_kind: str = "device",
                         estimator: str = "sensing_ri") -> dict:
    from .benchmark import run_scenario

    rec = run_scenario(i, seed, tier, sim_kind=sim_kind, estimator=estimator)
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    Path(out_path).write_text(json.dumps(rec, indent=1, default=float))
    return rec


def aggregate_scenarios(files, out_dir) -> dict:
    from .benchmark import score, write_scores

    recs = [json.loads(Path(p).read_text()) for p in files]
    sc = score(recs)
    write_scores(sc, Path(out_dir), f"snakemake gap_benchmark ({len(recs)} cases)")
    return sc
