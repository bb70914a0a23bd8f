"""The papers' figures, regenerated from pipeline artefacts.

Each function writes ``<name>.png`` and ``<name>.pdf`` (deterministic: fixed PDF metadata) and returns the caption.
Figure numbers refer to ``000_18d138f03f1777c3.txt`` (thesis, "Fig.") and ``001_972cacfaa08ad91a.txt`` (paper).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from selfsense.io import savefig_atomic  # noqa: E402

STYLE = {
    "figure.dpi": 100,
    "savefig.dpi": 110,
    "font.size": 9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "pdf.fonttype": 42,
    "svg.hashsalt": "selfsense",
    "path.simplify": True,
}

#: figure file stem -> (thesis figure, paper figure, title)
FIGURES = {
    "fig17_voltage_charge": ("Fig. 17", "Fig. 8", "Hysteresis between actuator voltage and charge, with minor loops"),
    "fig21_h_calibration": ("Fig. 21", "Fig. 12", "Hysteresis operator H(q) calibration on the free-tip trial"),
    "fig24_limiting_dc_offset": ("Fig. 24", "Fig. 13", "Effect of limiting and sliding DC offset"),
    "fig25-30_displacement_trials": ("Figs. 25-30", "Fig. 14", "Self-sensed vs reference tip displacement"),
    "fig31-36_force_trials": ("Figs. 31-36", "Fig. 15", "Self-sensed vs reference tip force"),
    "fig37_force_displacement": ("Fig. 37", "-", "Force and displacement self-sensed on one time axis"),
    "fig39_mismatch_subtraction": ("Fig. 39", "Fig. 17", "Effect of hysteresis model mismatch (free-case subtraction)"),
}


def _save(fig, out_dir: Path, stem: str) -> list[str]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for ext, kw in (("png", {"metadata": {"Software": None}}), ("pdf", {"metadata": {"CreationDate": None, "Producer": None, "Creator": None}})):
        p = out_dir / f"{stem}.{ext}"
        savefig_atomic(fig, p, format=ext, **kw)  # unique temp file, 0644 (umask), atomic rename
        paths.append(str(p))
    plt.close(fig)
    return paths


def caption(stem: str, extra: str = "") -> str:
    thesis, paper, title = FIGURES[stem]
    ref = f"regenerates thesis {thesis}" + (f" / paper {paper}" if paper != "-" else "")
    return f"{title} ({ref}). {extra}".strip()


def fig_voltage_charge(sig: pd.DataFrame, out_dir: Path, trial: str) -> str:
    m = sig["relay"].to_numpy() < 0.5
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(5.5, 4))
        ax.plot(sig["V"].to_numpy()[m], sig["q"].to_numpy()[m] * 1e6, lw=0.7)
        ax.set_xlabel("actuator voltage V [V]")
        ax.set_ylabel("charge q [µC]")
        ax.set_title(f"Voltage-charge hysteresis, trial {trial}")
        _save(fig, out_dir, "fig17_voltage_charge")
    return caption("fig17_voltage_charge", f"Free-tip calibration trial {trial}; loops traversed counter-clockwise.")


def fig_h_calibration(sig: pd.DataFrame, H_target: np.ndarray, H_fit: np.ndarray, out_dir: Path, trial: str,
                      rms_pct: float, max_pct: float) -> str:
    m = sig["relay"].to_numpy() < 0.5
    q = sig["q"].to_numpy()[m] * 1e6
    with plt.rc_context(STYLE):
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.8))
        a1.plot(q, H_target[m], lw=0.8, label="measured V - q/C (target)")
        a1.plot(q, H_fit[m], lw=0.8, ls="--", label="fitted H(q)")
        a1.set_xlabel("charge q [µC]")
        a1.set_ylabel("H(q) [V]")
        a1.legend(loc="best")
        a2.plot(sig["t"].to_numpy()[m], H_fit[m] - H_target[m], lw=0.6)
        a2.set_xlabel("time t [s]")
        a2.set_ylabel("H(q) fit error [V]")
        a2.set_title(f"RMS {rms_pct:.2f} %, max {max_pct:.2f} % of range")
        _save(fig, out_dir, "fig21_h_calibration")
    return caption("fig21_h_calibration", f"Trial {trial}; error in % of the output range (thesis: 0.58 % mean, 2.4 % max).")


def fig_limiting(est: pd.DataFrame, out_dir: Path, trial: str) -> str:
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(7, 3.5))
        t = est["t"].to_numpy()
        ax.plot(t, est["dx_raw"].to_numpy() * 1e3, lw=0.7, label="raw estimate")
        ax.plot(t, est["dx_hat"].to_numpy() * 1e3, lw=0.9, label="limited + sliding DC offset")
        if np.isfinite(est["dx_ref"]).any():
            ax.plot(t, est["dx_ref"].to_numpy() * 1e3, lw=0.7, color="k", alpha=0.6, label="reference (laser)")
        ax.set_xlabel("time t [s]")
        ax.set_ylabel("tip displacement Δx_tip [mm]")
        ax.legend(loc="best")
        _save(fig, out_dir, "fig24_limiting_dc_offset")
    return caption("fig24_limiting_dc_offset", f"Trial {trial}.")


def fig_trials(estimates: Mapping[str, pd.DataFrame], meta: pd.DataFrame, measurement: str, out_dir: Path,
               per_trial: pd.DataFrame) -> str:
    stem = "fig25-30_displacement_trials" if measurement == "displacement" else "fig31-36_force_trials"
    hat, ref, scale, unit = ("dx_hat", "dx_ref", 1e3, "mm") if measurement == "displacement" else ("f_hat", "f_ref", 1e3, "mN")
    meta = meta.set_index("trial") if "trial" in meta.columns else meta
    trials = [t for t in sorted(estimates) if meta.loc[t, "reference"] == measurement]
    n = max(len(trials), 1)
    ncol = 2
    nrow = int(np.ceil(n / ncol))
    pt = per_trial.set_index("trial")
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(nrow, ncol, figsize=(10, 2.4 * nrow), squeeze=False)
        for ax, trial in zip(axes.ravel(), trials):
            e = estimates[trial]
            ax.plot(e["t"], e[ref] * scale, color="k", lw=0.8, alpha=0.7, label="reference")
            ax.plot(e["t"], e[hat] * scale, lw=0.8, label="self-sensed")
            m = meta.loc[trial]
            obj = f" {m['object_mm']} mm" if str(m["tip"]) == "object" else ""
            ax.set_title(f"{trial} ({m['role']}, {m['tip']}{obj}, {m['signal']}): "
                         f"{pt.loc[trial, 'percent_of_range']:.1f} % of range", fontsize=8)
            ax.set_xlabel("time t [s]")
            ax.set_ylabel(f"{'Δx_tip' if measurement == 'displacement' else 'f_tip'} [{unit}]")
        for ax in axes.ravel()[len(trials):]:
            ax.axis("off")
        if trials:
            axes[0, 0].legend(loc="best", fontsize=7)
        fig.tight_layout()
        _save(fig, out_dir, stem)
    return caption(stem, f"All {measurement}-reference trials; the title gives the mean error in % of range.")


def fig_force_displacement(est: pd.DataFrame, out_dir: Path, trial: str) -> str:
    with plt.rc_context(STYLE):
        fig, a1 = plt.subplots(figsize=(7, 3.5))
        a1.plot(est["t"], est["dx_hat"] * 1e3, lw=0.8, color="C0", label="Δx_tip (self-sensed)")
        a1.set_xlabel("time t [s]")
        a1.set_ylabel("tip displacement Δx_tip [mm]", color="C0")
        a2 = a1.twinx()
        a2.plot(est["t"], est["f_hat"] * 1e3, lw=0.8, color="C3", label="f_tip (self-sensed)")
        a2.set_ylabel("tip force f_tip [mN]", color="C3")
        a2.grid(False)
        _save(fig, out_dir, "fig37_force_displacement")
    return caption("fig37_force_displacement",
                   f"Trial {trial}: force stays near zero until the tips touch the object, then rises with the voltage.")


def fig_mismatch(est: pd.DataFrame, free_est: pd.DataFrame, out_dir: Path, trial: str, free_trial: str) -> str:
    n = min(len(est), len(free_est))
    t = est["t"].to_numpy()[:n]
    f = est["f_raw"].to_numpy()[:n]
    f0 = free_est["f_raw"].to_numpy()[:n]
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(7, 3.5))
        if np.isfinite(est["f_ref"]).any():
            ax.plot(t, est["f_ref"].to_numpy()[:n] * 1e3, color="k", lw=0.8, alpha=0.7, label="reference")
        ax.plot(t, f * 1e3, lw=0.8, label="self-sensed (raw)")
        ax.plot(t, (f - f0) * 1e3, lw=0.8, label=f"minus free-tip estimate ({free_trial})")
        ax.set_xlabel("time t [s]")
        ax.set_ylabel("tip force f_tip [mN]")
        ax.legend(loc="best")
        _save(fig, out_dir, "fig39_mismatch_subtraction")
    return caption("fig39_mismatch_subtraction",
                   f"Trial {trial}: subtracting the force the model reports on a free tip under the same input "
                   f"history ({free_trial}) removes the hysteresis-mismatch part of the error.")
