"""Loading a dataset for the diagnostic: prepared trials + trials.csv meta + rig (and the truth folder if any)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

__all__ = ["Case", "load_case", "prepare_fallback", "load_truth", "within_budget"]

PREPARED = ("t", "V", "q", "u_cmd", "relay", "dx_ref", "f_ref", "V_c", "V_s")


@dataclass
class Case:
    """One dataset in memory: ``trials`` (trial -> prepared DataFrame), ``meta`` (trials.csv indexed by trial),
    ``rig`` (``selfsense.io.Rig`` or rig.yaml mapping), optional ``truth`` (trial -> truth DataFrame)."""

    trials: dict
    meta: pd.DataFrame
    rig: Any
    name: str = "dataset"
    truth: dict | None = None
    truth_manifest: dict | None = field(default=None, repr=False)
    decimated: dict = field(default_factory=dict)  #: trial -> k for trials reduced to block means (sample budget)


def prepare_fallback(si: pd.DataFrame, R: float) -> pd.DataFrame:
    """Prepared trial from SI signals when ``selfsense.signals.prepare_trial`` is unavailable.

    V = V_c - V_s (thesis 000_18d138f03f1777c3.txt eq. 56); q = (1/R) integral V_s dt (eq. 57), reset to 0 while
    the relay shorts the leads.
    """
    t = si["t"].to_numpy(float)
    Vs = si["V_s"].to_numpy(float)
    relay = si["relay"].to_numpy(float) >= 0.5
    inc = np.concatenate([[0.0], 0.5 * (Vs[1:] + Vs[:-1]) * np.diff(t)]) / R
    q = np.zeros_like(t)
    acc = 0.0
    for i in range(len(t)):  # reset while shorted
        acc = 0.0 if relay[i] else acc + inc[i]
        q[i] = acc
    out = pd.DataFrame({"t": t, "V": si["V_c"].to_numpy(float) - Vs, "q": q, "u_cmd": si["u_cmd"].to_numpy(float),
                        "relay": si["relay"].to_numpy(float), "dx_ref": si["dx_ref"].to_numpy(float),
                        "f_ref": si["f_ref"].to_numpy(float), "V_c": si["V_c"].to_numpy(float), "V_s": Vs})
    return out


def _prepare(si: pd.DataFrame, rig) -> pd.DataFrame:
    try:
        from selfsense.signals import prepare_trial  # type: ignore
    except Exception:
        prepare_trial = None
    if prepare_trial is not None:
        try:
            df = prepare_trial(si, rig)
            if all(c in df for c in ("t", "V", "q", "relay")):
                for c in PREPARED:
                    if c not in df:
                        df[c] = si[c].to_numpy() if c in si else np.nan
                return df.reset_index(drop=True)
        except TypeError:
            pass
    return prepare_fallback(si, float(rig.shunt_resistance_ohm))


def load_truth(dataset_dir: Path) -> tuple[dict | None, dict | None]:
    """Truth folder BESIDE the dataset (``<dataset_dir>.truth``), docs/dev/CONTRACTS.md; (None, None) if absent."""
    tdir = Path(str(Path(dataset_dir)).rstrip("/") + ".truth")
    if not tdir.is_dir():
        return None, None
    import json

    man = json.loads((tdir / "manifest.json").read_text()) if (tdir / "manifest.json").exists() else {}
    truth = {p.stem: pd.read_parquet(p) for p in sorted(tdir.glob("*.parquet"))}
    return truth, man


def within_budget(df: pd.DataFrame, budget: int) -> tuple[pd.DataFrame, int]:
    """``df`` reduced to block means of k samples when it is longer than ``budget`` samples (the charge must have
    been integrated at the full rate before), and k (1 when it fits) (:mod:`selfsense.io.budget`)."""
    from selfsense.io.budget import block_mean, decimation_factor

    k = decimation_factor(len(df), budget)
    return (block_mean(df, k).reset_index(drop=True) if k > 1 else df), int(k)


def load_case(dataset_dir: str | Path, with_truth: bool = True, max_samples: int | None = None) -> Case:
    """Read and validate a raw dataset (docs/data_format.md) through ``selfsense.io`` and prepare every trial.

    Sample budget (:mod:`selfsense.io.budget`): a trial longer than ``max_samples`` (default
    ``GAP_MAX_SAMPLES``) is reduced to block means of k samples after the charge is integrated at the full rate
    (thesis eq. 57), and its truth frame with the same k; ``case.decimated`` maps such trials to k. Memory then
    grows with the budget, not with the trial length."""
    from selfsense.io import load_dataset, trial_signals
    from selfsense.io.budget import GAP_MAX_SAMPLES, block_mean

    budget = GAP_MAX_SAMPLES if max_samples is None else int(max_samples)
    d = Path(dataset_dir)
    ds = load_dataset(d)
    meta = ds.trials.set_index("trial")
    trials, decimated = {}, {}
    for t in meta.index:
        trials[t], k = within_budget(_prepare(trial_signals(d, t, ds.rig), ds.rig), budget)
        if k > 1:
            decimated[t] = k
    truth, man = load_truth(d) if with_truth else (None, None)
    if truth is not None:
        truth = {t: (block_mean(f, decimated[t]).reset_index(drop=True) if t in decimated else f)
                 for t, f in truth.items()}
    case = Case(trials=trials, meta=meta, rig=ds.rig, name=ds.name, truth=truth, truth_manifest=man)
    case.decimated = decimated
    return case
