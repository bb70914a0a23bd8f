"""selfsense.gap: the sim-to-real gap diagnostic (docs/gap.md; docs/gap.md).

Public API (imported lazily)::

    diagnose(case, estimator="fast"|"sensing", thresholds=None, n_boot=30, seed=0, ...) -> Diagnosis
    load_case(dataset_dir, with_truth=True) -> Case
    run_diagnose(dataset_dir, out_dir, estimator="sensing", seed=0) -> Diagnosis   (writes the contract files)
    write_diagnosis(diagnosis, out_dir)
    run_scenario(i, seed, tier="fast", effects=None, sim_kind="device", estimator="fast") -> dict
    score(records) -> dict ; run_benchmark(n, seed, tier, out) ; calibrate_thresholds(n, seed, tier)
    LIBRARY, FAMILIES, effect(name)        the candidate-effect library
    shapley_exact, shapley_interactions, block_bootstrap_indices, contiguous_blocks, GramCV   (stats)
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "diagnose": "diagnose", "Diagnosis": "diagnose", "Evaluator": "diagnose", "load_thresholds": "diagnose",
    "load_case": "data", "Case": "data",
    "run_diagnose": "api", "run_scenario_to_json": "api", "aggregate_scenarios": "api",
    "write_diagnosis": "report",
    "run_scenario": "benchmark", "score": "benchmark", "run_benchmark": "benchmark",
    "calibrate_thresholds": "benchmark", "write_scores": "benchmark",
    "LIBRARY": "library", "FAMILIES": "library", "effect": "library",
    "shapley_exact": "stats", "shapley_interactions": "stats", "block_bootstrap_indices": "stats",
    "contiguous_blocks": "stats", "GramCV": "stats",
    "FastSensingEstimator": "model",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
