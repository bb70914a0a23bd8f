"""Error tables in the style of thesis Table 3 / paper Table II.

Per trial (``000_18d138f03f1777c3.txt`` Table 3 convention): mean absolute error, and the same in % of that trial's
reference range, ``percent_of_range = mean|estimate - reference| / (max - min of the reference) * 100``.
Table 3 averages the validation trials of each measurement.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import pandas as pd

#: reference columns of paper Table II (001_972cacfaa08ad91a.txt): the thesis' own result and two other works.
REFERENCE_COLUMNS = {
    "displacement": {"thesis_percent": 12.0, "kurita_percent": 11.0, "badel_percent": 2.0},
    "force": {"thesis_percent": 12.0, "kurita_percent": 11.0, "badel_percent": 2.0},
}

MEASUREMENTS = {"displacement": ("dx_hat", "dx_ref", "m"), "force": ("f_hat", "f_ref", "N")}


def trial_errors(est: pd.DataFrame, measurement: str, active: np.ndarray | None = None) -> dict:
    """Mean absolute error and % of range of one trial for ``measurement`` ('displacement' or 'force')."""
    hat, ref, _ = MEASUREMENTS[measurement]
    e = est[hat].to_numpy(dtype=float)
    r = est[ref].to_numpy(dtype=float)
    ok = np.isfinite(r) & np.isfinite(e)
    if active is not None:
        ok &= active
    if ok.sum() < 2:
        raise ValueError(f"trial has no finite {ref} samples to score the {measurement} estimate")
    mae = float(np.mean(np.abs(e[ok] - r[ok])))
    rng = float(np.max(r[ok]) - np.min(r[ok]))
    pct = mae / rng * 100.0 if rng > 0 else float("nan")
    return {"mean_abs_error": mae, "percent_of_range": pct, "reference_range": rng, "n_samples": int(ok.sum())}


def per_trial_table(estimates: Mapping[str, pd.DataFrame], meta: pd.DataFrame) -> pd.DataFrame:
    """One row per trial and measured reference: ``trial, measurement, mean_abs_error, percent_of_range, role``, in
    the order of trials.csv (docs/data_format.md: the order of its rows sets the order of listings)."""
    meta = meta.set_index("trial") if "trial" in meta.columns else meta
    rows = []
    listed = [t for t in meta.index if t in estimates]
    for trial in listed + sorted(t for t in estimates if t not in set(listed)):
        m = meta.loc[trial]
        measurement = str(m["reference"])
        err = trial_errors(estimates[trial], measurement)
        rows.append({
            "trial": trial,
            "measurement": measurement,
            "mean_abs_error": err["mean_abs_error"],
            "percent_of_range": err["percent_of_range"],
            "role": str(m["role"]),
            "tip": str(m["tip"]),
            "signal": str(m["signal"]),
            "reference_range": err["reference_range"],
        })
    return pd.DataFrame(rows, columns=["trial", "measurement", "mean_abs_error", "percent_of_range", "role",
                                       "tip", "signal", "reference_range"])


def table3(per_trial: pd.DataFrame) -> pd.DataFrame:
    """Thesis Table 3: per measurement, the mean over *validation* trials, with paper Table II's reference columns."""
    val = per_trial[per_trial["role"] == "validation"]
    rows = []
    for measurement in ("displacement", "force"):
        sub = val[val["measurement"] == measurement]
        row = {
            "measurement": measurement,
            "mean_abs_error": float(sub["mean_abs_error"].mean()) if len(sub) else float("nan"),
            "percent_of_range": float(sub["percent_of_range"].mean()) if len(sub) else float("nan"),
            "n_trials": int(len(sub)),
            "unit": MEASUREMENTS[measurement][2],
        }
        row.update(REFERENCE_COLUMNS[measurement])
        rows.append(row)
    return pd.DataFrame(rows)


def _fmt(v, unit: str | None = None) -> str:
    if isinstance(v, (float, np.floating)):
        if not np.isfinite(v):
            return "n/a"
        if unit == "m":
            return f"{v * 1e3:.3f} mm"
        if unit == "N":
            return f"{v * 1e3:.2f} mN"
        return f"{v:.2f}"
    return str(v)


def table3_markdown(t3: pd.DataFrame, title: str = "Table 3") -> str:
    lines = [
        f"### {title}: performance of the self-sensing technique (validation trials)",
        "",
        "| Measurement | Mean error | % of range | trials | Thesis (Table 3) | Kurita et al. | Badel et al. |",
        "|---|---|---|---|---|---|---|",
    ]
    for _, r in t3.iterrows():
        lines.append(
            f"| {r['measurement']} | {_fmt(r['mean_abs_error'], r['unit'])} | {_fmt(r['percent_of_range'])} % | "
            f"{r['n_trials']} | {r['thesis_percent']:.0f} % | {r['kurita_percent']:.0f} % | {r['badel_percent']:.0f} % |"
        )
    return "\n".join(lines) + "\n"


def per_trial_markdown(pt: pd.DataFrame) -> str:
    lines = [
        "### Per-trial errors",
        "",
        "| trial | role | tip | signal | measurement | mean error | % of range |",
        "|---|---|---|---|---|---|---|",
    ]
    for _, r in pt.iterrows():
        unit = MEASUREMENTS[r["measurement"]][2]
        lines.append(
            f"| {r['trial']} | {r['role']} | {r['tip']} | {r['signal']} | {r['measurement']} | "
            f"{_fmt(r['mean_abs_error'], unit)} | {_fmt(r['percent_of_range'])} % |"
        )
    return "\n".join(lines) + "\n"


def selection_frame(fit_report: Mapping[str, Any]) -> pd.DataFrame:
    """The H(q) model-selection table (:func:`selfsense.stages.selection_table`) from a fit report (``fit_report`` of
    a model JSON): the report reads the selection of the final model (``sensing.json``), whose H(q) the sensing
    regression may have calibrated again (the offset drift beside the creep member, docs/method.md 6h)."""
    rep = fit_report.get("hysteresis", {})
    nan = float("nan")
    table = [{**r, "cv_rms_v": [nan if v is None else v for v in r["cv_rms_v"]],
              "cv_rms_mean_v": nan if r["cv_rms_mean_v"] is None else r["cv_rms_mean_v"]}
             for r in rep.get("selection") or []]
    lin = next((r["cv_rms_mean_v"] for r in table if r["kind"] == "linear"), float("nan"))
    rows = []
    for r in table:
        row = {"model": r["label"], "kind": r["kind"]}
        for i, v in enumerate(r["cv_rms_v"], 1):
            row[f"cv_rms_fold{i}_V"] = v
        row.update({"cv_rms_mean_V": r["cv_rms_mean_v"], "linear_baseline_rms_V": lin,
                    "beats_linear": bool(r["cv_rms_mean_v"] < lin) if r["kind"] != "linear" else "",
                    "selected": bool(r["selected"]), "status": r["status"]})
        rows.append(row)
    return pd.DataFrame(rows)
