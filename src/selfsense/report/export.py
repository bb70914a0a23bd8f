"""Export of one trial's results for MATLAB and spreadsheets: ``.mat`` and ``.csv`` with units.

Both files hold, per sample: ``t, u_cmd, relay, V, q, V_H, V_p, dx_raw, f_raw, dx_hat, f_hat, dx_ref, f_ref`` (SI
units listed in :data:`selfsense.report.units.SIGNALS`: the measured actuator voltage and charge of thesis
``000_18d138f03f1777c3.txt`` eqs. (56)-(57), the raw estimates of eq. (52) and the post-processed ones of sec. 5.2),
and per file: the sample rate, the trial's row of ``trials.csv``, the sensing coefficients with their units, the
H(q) fit report, the estimator configuration and the package version.

* ``.mat`` (MAT v5, deterministic bytes): struct ``data`` (one column vector per signal), struct ``units``
  (signal -> unit string), struct ``meta``, struct ``coef`` and ``coef_units``, and ``config_json`` (the estimator
  configuration and H(q) fit report as JSON text). MATLAB: ``s = load('x.mat'); plot(s.data.t, s.data.f_hat)``.
* ``.csv``: ``#`` comment lines (sample rate, trial, coefficients with units, configuration as JSON), then a header
  ``name [unit]`` and one row per sample. pandas: ``pd.read_csv(path, comment='#')``.
"""
from __future__ import annotations

import io as _io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .units import SIGNALS, coef_unit

__all__ = ["EXPORT_COLUMNS", "export_trial", "trial_frame"]

EXPORT_COLUMNS = ("t", "u_cmd", "relay", "V", "q", "V_H", "V_p", "dx_raw", "f_raw", "dx_hat", "f_hat", "dx_ref",
                  "f_ref")


def trial_frame(signals: pd.DataFrame, internals: pd.DataFrame) -> pd.DataFrame:
    """The per-sample export table from the ``signals/`` and ``internals/`` Parquet frames of one trial."""
    if len(signals) != len(internals):
        raise ValueError(f"signals ({len(signals)} samples) and internals ({len(internals)}) differ in length")
    cols = {}
    for c in EXPORT_COLUMNS:
        src = internals if c in internals.columns else signals
        if c not in src.columns:
            raise ValueError(f"export: column {c!r} is in neither the signals nor the internals frame")
        cols[c] = src[c].to_numpy(dtype=np.float64)
    return pd.DataFrame(cols)


def _flat_coef(model: dict) -> dict[str, float]:
    out = {}
    for k, v in (model.get("coef") or {}).items():
        if isinstance(v, dict):
            for kk, vv in v.items():
                out[f"{k}_{kk}"] = float(vv)
        else:
            out[k] = float(v)
    if "h_slope" in model:
        out["h_slope"] = float(model["h_slope"])
    return out


def _matlab_name(s: str) -> str:
    import re

    s = re.sub(r"[^A-Za-z0-9_]", "_", s)
    return (s if s[:1].isalpha() else "x_" + s)[:63]


def export_trial(dataset_dir: str | Path, trial: str, signals_parquet: str | Path, internals_parquet: str | Path,
                 model_json: str | Path, out_mat: str | Path | None = None, out_csv: str | Path | None = None
                 ) -> list[Path]:
    """Write ``out_mat`` and/or ``out_csv`` for one trial (atomically); returns the paths written."""
    import scipy.io

    from selfsense import io as sio
    from selfsense import version
    from selfsense.io.formats import MAT_HEADER

    rig = sio.load_rig(dataset_dir)
    meta_row = sio.load_trials(dataset_dir).set_index("trial").loc[trial]
    meta_row = meta_row[[c for c in sio.TRIAL_COLUMNS if c in meta_row.index]]
    model = json.loads(Path(model_json).read_text())
    df = trial_frame(pd.read_parquet(signals_parquet), pd.read_parquet(internals_parquet))
    coef = _flat_coef(model)
    meta: dict[str, Any] = {
        "dataset": rig.dataset, "trial": trial, "sample_rate_hz": float(rig.sample_rate_hz),
        "n_samples": int(len(df)), "selfsense_version": version(),
        **{k: ("" if pd.isna(v) else str(v)) for k, v in meta_row.items()},
        "h_model": str(model.get("config", {}).get("h_model", "")),
        "h_mode": str(model.get("config", {}).get("h_mode", "")),
        "calibration_trials": ", ".join(map(str, model.get("calibration_trials", []))),
    }
    config = {"estimator_config": model.get("config", {}), "fit_report": model.get("fit_report", {}),
              "ranges": model.get("ranges", {})}
    written = []
    if out_mat is not None:
        payload = {
            "data": {c: df[c].to_numpy().reshape(-1, 1) for c in df.columns},
            "units": {c: SIGNALS[c][0] for c in df.columns},
            "description": {c: SIGNALS[c][1] for c in df.columns},
            "meta": {_matlab_name(k): v for k, v in meta.items()},
            "coef": {_matlab_name(k): v for k, v in coef.items()},
            "coef_units": {_matlab_name(k): coef_unit(k) for k in coef},
            "config_json": json.dumps(config, sort_keys=True, default=str),
        }
        buf = _io.BytesIO()
        scipy.io.savemat(buf, payload, format="5", do_compression=True, oned_as="column")
        raw = bytearray(buf.getvalue())
        raw[:116] = MAT_HEADER.ljust(116, b" ")  # fixed header text: same input, same bytes
        sio.write_bytes_atomic(bytes(raw), out_mat)
        written.append(Path(out_mat))
    if out_csv is not None:
        lines = [f"# selfsense {meta['selfsense_version']} export: dataset {rig.dataset}, trial {trial}",
                 f"# sample_rate_hz: {rig.sample_rate_hz:g}",
                 "# trial: " + ", ".join(f"{k}={meta_row[k] if not pd.isna(meta_row[k]) else ''}"
                                         for k in meta_row.index),
                 f"# H(q): {meta['h_model']} ({meta['h_mode']} mode), calibration trials: {meta['calibration_trials']}",
                 "# coefficients (thesis eq. 52): " + ", ".join(f"{k} = {v:.9g} {coef_unit(k)}"
                                                                for k, v in coef.items()),
                 "# config: " + json.dumps(config, sort_keys=True, default=str)]
        body = _io.StringIO()
        df.rename(columns={c: f"{c} [{SIGNALS[c][0]}]" for c in df.columns}).to_csv(
            body, index=False, float_format="%.9g", lineterminator="\n")
        sio.write_text_atomic("\n".join(lines) + "\n" + body.getvalue(), out_csv)
        written.append(Path(out_csv))
    return written
