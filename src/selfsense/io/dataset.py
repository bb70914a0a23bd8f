"""A whole raw dataset: validation and SI conversion of one trial (docs/data_format.md, thesis eqs. 56-57)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from .errors import ContractError, Problem
from .logs import check_log
from .plausibility import check_plausibility
from .rig import RIG_FILE, Rig, check_rig
from .trials import check_trials, pipeline_problems

__all__ = ["Dataset", "check_dataset", "validate_dataset", "load_dataset", "trial_signals", "to_si", "SI_COLUMNS"]

#: columns of :func:`trial_signals`
SI_COLUMNS: tuple[str, ...] = ("t", "u_cmd", "V_c", "V_s", "relay", "dx_ref", "f_ref")


@dataclass(frozen=True)
class Dataset:
    path: Path
    rig: Rig
    trials: pd.DataFrame  #: as returned by :func:`selfsense.io.load_trials`

    @property
    def name(self) -> str:
        return self.rig.dataset


def _log_problems(dataset_dir: Path, rig: Rig | None, rec: Mapping[str, Any], max_rows: int | None = None
                  ) -> tuple[pd.DataFrame | None, list[Problem]]:
    """Contract checks of one trial log, then (when it passed them and the rig is valid) the physical
    plausibility checks of :mod:`selfsense.io.plausibility` (errors and warnings)."""
    df, lp = check_log(dataset_dir / rec["file"], rig, rec["reference"], name=rec["file"], max_rows=max_rows)
    if df is not None and not lp and rig is not None:
        lp = check_plausibility(df, rig, rec, rec["file"])
    return df, lp


def _logs_readable_without_rig(dataset_dir: Path) -> bool:
    """Whether the logs can be checked without a valid rig: rig.yaml parses as a mapping and sets neither a
    ``channel_map`` nor a ``format`` (then the logs use the canonical names and are read by their extension)."""
    from .yamlsafe import load_yaml_file

    try:
        data = load_yaml_file(dataset_dir / RIG_FILE)
    except Exception:  # noqa: BLE001 - any reading problem is rig.yaml's own, already reported
        return not (dataset_dir / RIG_FILE).exists()
    return isinstance(data, dict) and "channel_map" not in data and "format" not in data


def _dataset_problems(dataset_dir: Path, warnings: list[Problem] | None = None, pipeline: bool = False,
                      max_trial_samples: int | None = None
                      ) -> tuple[Rig | None, pd.DataFrame | None, list[Problem], int]:
    """(rig, trials, errors, number of samples); warnings are appended to ``warnings`` when given; with
    ``pipeline`` also what the pipeline needs beyond the contract (:func:`selfsense.io.trials.pipeline_problems`)."""
    if not dataset_dir.is_dir():
        return None, None, [Problem(str(dataset_dir), None, None, "a dataset folder", "no such directory")], 0
    rig, probs = check_rig(dataset_dir)
    trials, tprobs = check_trials(dataset_dir)
    probs = probs + tprobs
    if pipeline and trials is not None:
        probs += pipeline_problems(trials)
    n_samples = 0
    if trials is not None and rig is None and not _logs_readable_without_rig(dataset_dir):
        # rig.yaml says how the logs are read (channel names, scales, format) but is broken: checking them against
        # the canonical names would bury its one real problem under a false one per column of every log
        probs.append(Problem(RIG_FILE, None, None, "a valid rig.yaml before the trial logs are checked (its "
                             "channel_map or format says how to read them)", "the logs were not checked"))
    elif trials is not None:
        for rec in trials.to_dict("records"):
            df, lp = _log_problems(dataset_dir, rig, rec, max_trial_samples)
            probs += [p for p in lp if not p.is_warning]
            if warnings is not None:
                warnings += [p for p in lp if p.is_warning]
            if df is not None:
                n_samples += len(df)
    return rig, trials, probs, n_samples


def check_dataset(dataset_dir: str | Path, pipeline: bool = False, max_trial_samples: int | None = None
                  ) -> tuple[list[Problem], list[Problem]]:
    """``(errors, warnings)`` of a dataset folder: contract problems and physical plausibility findings (and with
    ``pipeline`` what the pipeline needs: :func:`selfsense.io.trials.pipeline_problems`).

    Warnings do not make a dataset invalid; ``selfsense validate`` prints them and the pipeline writes them to
    ``validation.json``, which the report shows.
    """
    warnings: list[Problem] = []
    errors = _dataset_problems(Path(dataset_dir), warnings, pipeline, max_trial_samples)[2]
    return errors, warnings


def validate_dataset(dataset_dir: str | Path) -> list[Problem]:
    """Check a raw dataset folder against the contract; return every problem found (empty list = valid).

    ``rig.yaml``, ``trials.csv`` and every log named by ``trials.csv`` are checked independently, so one
    broken file does not hide the problems of the others. Never raises on bad data.
    """
    return _dataset_problems(Path(dataset_dir))[2]


def load_dataset(dataset_dir: str | Path) -> Dataset:
    """Validate the whole dataset and return :class:`Dataset`; raise :class:`ContractError` on any problem."""
    d = Path(dataset_dir)
    rig, trials, probs, _ = _dataset_problems(d)
    if probs or rig is None or trials is None:
        raise ContractError(probs, str(d))
    return Dataset(d, rig, trials)


def to_si(df: pd.DataFrame, rig: Rig, reference: str | None) -> pd.DataFrame:
    """Canonical raw log -> SI signals (docs/data_format.md; thesis 000_18d138f03f1777c3.txt eqs. 56-57).

    ``V_c = amplifier_gain * u_cmd`` [V], ``V_s = v_shunt / inamp_gain`` [V],
    ``dx_ref = 2 * laser_m_per_v * laser`` [m] (both arms, NaN unless reference = 'displacement'),
    ``f_ref = load_cell_n_per_v * load_cell`` [N] (NaN unless reference = 'force').
    """
    n = len(df)
    nan = np.full(n, np.nan)
    u = df["u_cmd"].to_numpy(np.float64)
    out = pd.DataFrame({
        "t": df["t"].to_numpy(np.float64),
        "u_cmd": u,
        "V_c": rig.amplifier_gain * u,
        "V_s": df["v_shunt"].to_numpy(np.float64) / rig.inamp_gain,
        "relay": df["relay"].to_numpy(np.float64),
        "dx_ref": 2.0 * rig.reference.laser_m_per_v * df["laser"].to_numpy(np.float64)
        if reference == "displacement" else nan,
        "f_ref": rig.reference.load_cell_n_per_v * df["load_cell"].to_numpy(np.float64)
        if reference == "force" else nan.copy(),
    })
    return out


def trial_signals(dataset_dir: str | Path, trial: str, rig: Rig | None = None) -> pd.DataFrame:
    """SI signals of one trial: columns ``t, u_cmd, V_c, V_s, relay, dx_ref, f_ref`` (see :func:`to_si`).

    Checks ``rig.yaml`` (unless ``rig`` is given), ``trials.csv`` and this trial's log; raises
    :class:`ContractError` on any problem (a trial id not in ``trials.csv`` included).
    """
    d = Path(dataset_dir)
    probs: list[Problem] = []
    if rig is None:
        rig, probs = check_rig(d)
    trials, tprobs = check_trials(d)
    probs = probs + tprobs
    if probs or rig is None or trials is None:
        raise ContractError(probs, str(d))
    sel = trials[trials["trial"] == trial]
    if sel.empty:
        raise ContractError([Problem("trials.csv", "trial", None, "a trial id listed in trials.csv", trial)], str(d))
    rec = sel.iloc[0]
    df, lp = _log_problems(d, rig, rec.to_dict())
    errs = [p for p in lp if not p.is_warning]
    if errs or df is None:
        raise ContractError(errs, str(d))
    out = to_si(df, rig, rec["reference"])
    out.attrs.update({"dataset": rig.dataset, "trial": trial, "reference": rec["reference"],
                      "tip": rec["tip"], "role": rec["role"]})
    return out
