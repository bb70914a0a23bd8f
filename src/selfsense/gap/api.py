"""One-call entry points used by the CLI and the Snakemake scripts."""
from __future__ import annotations

import json
from pathlib import Path

__all__ = ["run_diagnose", "run_scenario_to_json", "aggregate_scenarios"]


def run_diagnose(dataset_dir, out_dir, estimator: str = "sensing", seed: int = 0, n_boot: int = 30,
                 figures: bool = True, progress: bool | None = False, force: bool = False):
    """Load a raw dataset (and its truth folder if present), diagnose, write the contract files; returns the
    :class:`~selfsense.gap.diagnose.Diagnosis`.

    ``estimator="sensing"`` (default) diagnoses the project's ``SelfSensingEstimator`` (limiting / DC offset off);
    if it cannot be calibrated on this dataset the fast stand-in is used and the verdict says so
    (``estimator_fallback``).

    ``out_dir`` is written all-or-nothing (:func:`selfsense.io.output_dir`): it must not overlap the dataset, and an
    existing non-empty folder is replaced only if selfsense wrote it or ``force``. The dataset is validated
    (contract and plausibility, :func:`selfsense.io.load_dataset`) before anything else."""
    from selfsense.io import check_output_dir, output_dir

    from .data import load_case
    from .diagnose import diagnose
    from .report import write_diagnosis

    if estimator not in ("sensing", "sensing_ri", "fast"):  # no silent fallback on a typo
        raise ValueError(f"gap diagnose: estimator: expected 'sensing', 'sensing_ri' or 'fast', found {estimator!r}")
    check_output_dir(out_dir, [dataset_dir], force=force)  # fail before the long computation
    case = load_case(dataset_dir, with_truth=True)
    try:
        d = diagnose(case, estimator=estimator, seed=seed, n_boot=n_boot, progress=progress)
    except Exception as exc:  # noqa: BLE001 - report and fall back, never a silent fix
        if estimator == "fast":
            raise
        d = diagnose(case, estimator="fast", seed=seed, n_boot=n_boot)
        d.verdict["estimator_fallback"] = f"{estimator!r} failed ({type(exc).__name__}: {exc}); used 'fast'"
    if case.decimated:  # say what was done (sample budget, selfsense.io.budget)
        d.verdict["decimated"] = {t: int(k) for t, k in sorted(case.decimated.items())}
        d.verdict["decimation_note"] = ("trials longer than the sample budget were diagnosed on block means of k "
                                        "samples (k per trial in 'decimated'); the charge was integrated first")
    with output_dir(out_dir, [dataset_dir], force=force) as tmp:
        write_diagnosis(d, tmp, figures=figures)
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
