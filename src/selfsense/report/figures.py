"""The papers' figures, regenerated from pipeline artefacts.

Each function writes ``<name>.png`` and ``<name>.pdf`` (deterministic: fixed PDF metadata) and returns the caption.
Figure numbers refer to ``000_18d138f03f1777c3.txt`` (thesis, "Fig.") and ``001_972cacfaa08ad91a.txt`` (paper).
"""
from __future__ import annotations

import contextlib
import threading
from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from selfsense.io import savefig_atomic  # noqa: E402

from .figure_list import FIGURES  # noqa: E402

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

#: samples drawn per trace against time at most: longer traces are drawn from their min-max envelope
#: (:func:`_envelope`), twice as many points as the widest panel has pixels at ``savefig.dpi`` times four
FIGURE_TRACE_POINTS = 4000


def _envelope(x, y, n_points: int = FIGURE_TRACE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` thinned for drawing: the samples are cut into ``n_points / 2`` consecutive bins and each bin keeps
    its smallest and its largest ``y`` (in time order), so every peak and every spike stays drawn, at a cost that does
    not grow with the record. A bin without a finite ``y`` keeps one NaN sample (a gap stays a gap). Traces of at most
    ``n_points`` samples are returned as they are."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = y.size
    if n <= n_points:
        return x, y
    nb = max(n_points // 2, 1)
    w = -(-n // nb)
    nb = -(-n // w)
    Y = np.full(nb * w, np.nan)
    Y[:n] = y
    Y = Y.reshape(nb, w)
    bad = np.isnan(Y)
    lo = np.where(bad, np.inf, Y).argmin(axis=1)
    hi = np.where(bad, -np.inf, Y).argmax(axis=1)
    first = np.where(bad.all(axis=1), 0, np.minimum(lo, hi))
    second = np.where(bad.all(axis=1), 0, np.maximum(lo, hi))
    base = np.arange(nb) * w
    idx = np.unique(np.concatenate([base + first, base + second]))
    idx = idx[idx < n]
    return x[idx], y[idx]


def _trace(ax, x, y, **kw):
    """``ax.plot`` of a trace against time, drawn from its envelope (:func:`_envelope`)."""
    xe, ye = _envelope(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    return ax.plot(xe, ye, **kw)




#: OpenType tables that a PDF viewer never reads from an embedded TrueType font (glyph substitution and positioning,
#: the math table, the old kerning table): the text's glyphs and their positions are already written in the page
LAYOUT_TABLES = ("GSUB", "GPOS", "GDEF", "BASE", "JSTF", "MATH", "kern")
_SUBSET_LOCK = threading.Lock()


@contextlib.contextmanager
def _pdf_fonts_without_layout_tables():
    """While a PDF is written: the TrueType fonts it embeds (``pdf.fonttype`` 42, subset by fontTools) are subset
    without their :data:`LAYOUT_TABLES`. Matplotlib keeps them in the subset, and fontTools parses and subsets them
    each time, about three quarters of the subsetting's time (DejaVu Sans has large GSUB, GPOS and MATH tables); the
    embedded glyph outlines, metrics and hinting tables are the same, and so is every page as drawn. Where
    matplotlib or fontTools load the font some other way, nothing changes."""
    from fontTools import subset

    with _SUBSET_LOCK:   # one PDF at a time: the load function is the module's, shared by every thread
        load = subset.load_font

        def load_without_layout(*args, **kwargs):
            font = load(*args, **kwargs)
            for tag in LAYOUT_TABLES:
                if tag in font:
                    del font[tag]
            return font

        subset.load_font = load_without_layout
        try:
            yield
        finally:
            subset.load_font = load


def _save(fig, out_dir: Path, stem: str) -> list[str]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for ext, kw in (("png", {"metadata": {"Software": None}}), ("pdf", {"metadata": {"CreationDate": None, "Producer": None, "Creator": None}})):
        p = out_dir / f"{stem}.{ext}"
        with _pdf_fonts_without_layout_tables() if ext == "pdf" else contextlib.nullcontext():
            savefig_atomic(fig, p, format=ext, **kw)  # unique temp file, 0644 (umask), atomic rename
        paths.append(str(p))
    plt.close(fig)
    return paths


def caption(stem: str, extra: str = "") -> str:
    thesis, paper, title = FIGURES[stem]
    if thesis == "-":
        return f"{title} (no counterpart in the thesis: the fits have seen these trials). {extra}".strip()
    ref = f"regenerates thesis {thesis}" + (f" / paper {paper}" if paper != "-" else "")
    return f"{title} ({ref}). {extra}".strip()


def _legend_above(ax, ncol: int = 3, **kw) -> None:
    """Legend above the axes, outside the data."""
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=ncol, frameon=False, fontsize=8,
              borderaxespad=0.0, **kw)


def _arrows(ax, x: np.ndarray, y: np.ndarray, colors, n: int = 14) -> None:
    """Direction arrows along a path (x, y), coloured like the path at that point."""
    L = len(x)
    if L < 3:
        return
    idx = np.linspace(L * 0.03, L * 0.97, n).astype(int)
    span = max(L // 200, 1)
    for i in idx:
        j = min(i + span, L - 1)
        if x[j] == x[i] and y[j] == y[i]:
            continue
        ax.annotate("", xy=(x[j], y[j]), xytext=(x[i], y[i]),
                    arrowprops=dict(arrowstyle="-|>", color=colors[i], lw=1.0, mutation_scale=11))


def _colour_runs(norm, t: np.ndarray, n_colours: int) -> np.ndarray:
    """Indices where a run of consecutive values of ``t`` that map to one entry of an ``n_colours`` lookup table
    (matplotlib's ``Colormap.__call__``: ``int(norm(t) N)``, the top value in the last entry) begins."""
    k = np.clip((np.asarray(norm(t), dtype=float) * n_colours), -1, n_colours)
    k[k == n_colours] = n_colours - 1
    k = np.floor(k).astype(int)
    return np.flatnonzero(np.r_[True, np.diff(k) != 0])


def fig_voltage_charge(sig: pd.DataFrame, out_dir: Path, trial: str) -> str:
    """Thesis Fig. 17: V-q loops coloured by time (colour bar) with direction arrows, so the minor loops and their
    order can be told apart."""
    from matplotlib.collections import LineCollection

    m = sig["relay"].to_numpy() < 0.5
    V = sig["V"].to_numpy()[m]
    q = sig["q"].to_numpy()[m] * 1e6
    t = sig["t"].to_numpy()[m]
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(6.2, 4.2))
        pts = np.column_stack([V, q])
        norm = plt.Normalize(float(t.min()), float(t.max())) if len(t) else None
        # one polyline per colour of the map: the segments whose start time falls on the same entry of the
        # colormap's lookup table are drawn as one path (the same colours as one segment per sample, at a cost
        # bounded by the table's size, not by the record's length)
        starts = _colour_runs(norm, t[:-1], plt.get_cmap("viridis").N) if len(t) > 1 else np.zeros(0, int)
        ends = np.append(starts[1:], len(t) - 1)
        segs = [pts[a:b + 1] for a, b in zip(starts, ends)]
        lc = LineCollection(segs, cmap="viridis", norm=norm, linewidths=0.9)
        lc.set_array(t[starts])
        ax.add_collection(lc)
        ax.autoscale()
        cmap = plt.get_cmap("viridis")
        _arrows(ax, V, q, cmap(norm(t)) if len(t) else [])
        cb = fig.colorbar(lc, ax=ax)
        cb.set_label("time t [s]")
        ax.set_xlabel("actuator voltage V [V]")
        ax.set_ylabel("charge q [µC]")
        ax.set_title(f"Voltage-charge hysteresis, trial {trial}")
        _save(fig, out_dir, "fig17_voltage_charge")
    return caption("fig17_voltage_charge", f"Free-tip calibration trial {trial}; colour = time (dark = start, "
                                           "yellow = end), arrows give the direction of travel, so each minor loop "
                                           "and the order of the loops can be followed.")


def fig_input(sig: pd.DataFrame, out_dir: Path, trial: str, stem: str) -> str:
    """Thesis Figs. 22-23: the driving voltage of a trial (amplifier output V_c and actuator voltage V) vs time."""
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(7, 3.2))
        _trace(ax, sig["t"], sig["V_c"], lw=0.9, label="amplifier output V_c")
        _trace(ax, sig["t"], sig["V"], lw=0.7, ls="--", label="actuator voltage V = V_c - V_s")
        ax.set_xlabel("time t [s]")
        ax.set_ylabel("voltage [V]")
        _legend_above(ax, ncol=2)
        fig.tight_layout()
        _save(fig, out_dir, stem)
    return caption(stem, f"Trial {trial}; the relay shorts the actuator leads during the first segment (0 V).")


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
        _legend_above(a1, ncol=1)
        _trace(a2, sig["t"].to_numpy()[m], H_fit[m] - H_target[m], lw=0.6)
        a2.set_xlabel("time t [s]")
        a2.set_ylabel("H(q) fit error [V]")
        a2.set_title(f"RMS {rms_pct:.2f} %, max {max_pct:.2f} % of range")
        fig.tight_layout()
        _save(fig, out_dir, "fig21_h_calibration")
    return caption("fig21_h_calibration", f"Trial {trial}; error in % of the output range (thesis: 0.58 % mean, 2.4 % max).")


def fig_limiting(est: pd.DataFrame, out_dir: Path, trial: str, limit: bool = True, dc_offset: bool = True) -> str:
    """Thesis Fig. 24: the raw estimate and the estimate after the post-processing the configuration applies
    (``limit``: clipped to the calibration range; ``dc_offset``: the sliding DC offset), each named only where
    applied."""
    done = [w for w, on in (("limited to the calibration range", limit), ("sliding DC offset", dc_offset)) if on]
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(7, 3.5))
        t = est["t"].to_numpy()
        _trace(ax, t, est["dx_raw"].to_numpy() * 1e3, lw=0.7, label="raw estimate")
        _trace(ax, t, est["dx_hat"].to_numpy() * 1e3, lw=0.9,
               label="estimate, " + " + ".join(done) if done else "estimate (no post-processing configured)")
        if np.isfinite(est["dx_ref"]).any():
            _trace(ax, t, est["dx_ref"].to_numpy() * 1e3, lw=0.7, color="k", alpha=0.6, label="reference (laser)")
        ax.set_xlabel("time t [s]")
        ax.set_ylabel("tip displacement Δx_tip [mm]")
        _legend_above(ax)
        fig.tight_layout()
        _save(fig, out_dir, "fig24_limiting_dc_offset")
    return caption("fig24_limiting_dc_offset", f"Trial {trial}.")


_TIP_RANK = {"free": 0, "blocked": 0, "object": 1}


def _thesis_order(meta: pd.DataFrame, trials: list[str], measurement: str) -> list[str]:
    """Thesis order of Figs. 25-36: free (or blocked) tip first, then objects (small to large for displacement,
    large to small for force), the sine before the mixed drive."""
    def key(t):
        m = meta.loc[t]
        size = float(m["object_mm"]) if str(m["tip"]) == "object" and pd.notna(m["object_mm"]) else 0.0
        return (_TIP_RANK.get(str(m["tip"]), 2), size if measurement == "displacement" else -size,
                0 if str(m["signal"]) == "sine" else 1, t)
    return sorted(trials, key=key)


def fig_trials(estimates: Mapping[str, pd.DataFrame], meta: pd.DataFrame, measurement: str, out_dir: Path,
               per_trial: pd.DataFrame, role: str = "validation") -> str | None:
    """Thesis Figs. 25-30 (displacement) / 31-36 (force): one panel per ``role`` trial of that reference, in the
    thesis' order; the calibration trials go to a figure of their own. Returns None when there is no such trial."""
    if role == "validation":
        stem = "fig25-30_displacement_trials" if measurement == "displacement" else "fig31-36_force_trials"
    else:
        stem = "cal_displacement_trials" if measurement == "displacement" else "cal_force_trials"
    hat, ref, scale, unit = ("dx_hat", "dx_ref", 1e3, "mm") if measurement == "displacement" else ("f_hat", "f_ref", 1e3, "mN")
    meta = meta.set_index("trial") if "trial" in meta.columns else meta
    trials = [t for t in estimates if meta.loc[t, "reference"] == measurement and meta.loc[t, "role"] == role]
    if not trials:
        return None
    trials = _thesis_order(meta, trials, measurement)
    n = len(trials)
    ncol = 2 if n > 1 else 1
    nrow = int(np.ceil(n / ncol))
    pt = per_trial.set_index("trial")
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(nrow, ncol, figsize=(10 if ncol == 2 else 6, 2.5 * nrow + 0.5), squeeze=False)
        for k, (ax, trial) in enumerate(zip(axes.ravel(), trials), start=1):
            e = estimates[trial]
            _trace(ax, e["t"], e[ref] * scale, color="k", lw=0.8, alpha=0.7, label="reference")
            _trace(ax, e["t"], e[hat] * scale, lw=0.8, color="C0", label="self-sensed")
            m = meta.loc[trial]
            obj = f" {m['object_mm']} mm" if str(m["tip"]) == "object" else ""
            err = pt.loc[trial, "percent_of_range"] if trial in pt.index else float("nan")
            ax.set_title(f"{'Trial ' + str(k) + ': ' if role == 'validation' else ''}{trial} ({m['tip']}{obj}, "
                         f"{m['signal']}): {err:.1f} % of range", fontsize=8)
            ax.set_xlabel("time t [s]")
            ax.set_ylabel(f"{'Δx_tip' if measurement == 'displacement' else 'f_tip'} [{unit}]")
        for ax in axes.ravel()[n:]:
            ax.axis("off")
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="upper center", ncol=2, frameon=False, fontsize=8)
        fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / (2.5 * nrow + 0.5)))
        _save(fig, out_dir, stem)
    which = ("validation trials (never seen by a fit), in the thesis' order" if role == "validation" else
             "calibration trials (used to fit H(q) and the coefficients; shown apart from the validation panels)")
    return caption(stem, f"{n} {measurement}-reference {which.replace('trials', 'trial', 1) if n == 1 else which}; "
                         "each title gives the trial's mean error in % of its reference range.")


def fig_force_displacement(est: pd.DataFrame, out_dir: Path, trial: str,
                           partner: pd.DataFrame | None = None, partner_trial: str | None = None) -> str:
    """Thesis Fig. 37: self-sensed force and displacement on one time axis, each with its reference trace. A trial
    has one reference sensor; the other reference comes from ``partner``, the trial with the same object and drive
    that recorded the other sensor (when there is one)."""
    refs = {"dx_ref": (est, trial), "f_ref": (est, trial)}
    if partner is not None:
        for c in ("dx_ref", "f_ref"):
            if not np.isfinite(est[c]).any() and np.isfinite(partner[c]).any():
                refs[c] = (partner, partner_trial)
    with plt.rc_context(STYLE):
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
        for ax, hat, ref, scale, lab, unit, col in ((a1, "dx_hat", "dx_ref", 1e3, "tip displacement Δx_tip", "mm", "C0"),
                                                     (a2, "f_hat", "f_ref", 1e3, "tip force f_tip", "mN", "C3")):
            src, who = refs[ref]
            if np.isfinite(src[ref]).any():
                rlab = "reference" + (f" (paired trial {who}, same object and drive)" if who != trial else "")
                _trace(ax, src["t"], src[ref] * scale, color="k", lw=0.8, alpha=0.6, label=rlab)
                _trace(ax, est["t"], est[hat] * scale, lw=0.9, color=col, label="self-sensed")
            else:
                _trace(ax, est["t"], est[hat] * scale, lw=0.9, color=col,
                        label=f"self-sensed (no {'laser' if ref == 'dx_ref' else 'load-cell'} reference in this trial)")
            ax.set_ylabel(f"{lab} [{unit}]")
            _legend_above(ax, ncol=2)
        a2.set_xlabel("time t [s]")
        fig.tight_layout()
        _save(fig, out_dir, "fig37_force_displacement")
    have = [c for c in ("dx_ref", "f_ref") if np.isfinite(refs[c][0][c]).any()]
    note = ("References: " + ", ".join({"dx_ref": "laser (displacement)", "f_ref": "load cell (force)"}[c]
                                       + (f" from trial {refs[c][1]}" if refs[c][1] != trial else "") for c in have)
            + "." if have else "No reference recorded for this trial.")
    return caption("fig37_force_displacement",
                   f"Trial {trial}: force stays near zero until the tips touch the object, then rises with the "
                   f"voltage. {note}")


def fig_mismatch(est: pd.DataFrame, free_est: pd.DataFrame, out_dir: Path, trial: str, free_trial: str) -> str:
    n = min(len(est), len(free_est))
    t = est["t"].to_numpy()[:n]
    f = est["f_raw"].to_numpy()[:n]
    f0 = free_est["f_raw"].to_numpy()[:n]
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(7, 3.5))
        if np.isfinite(est["f_ref"]).any():
            _trace(ax, t, est["f_ref"].to_numpy()[:n] * 1e3, color="k", lw=0.8, alpha=0.7, label="reference")
        _trace(ax, t, f * 1e3, lw=0.8, label="self-sensed (raw)")
        _trace(ax, t, (f - f0) * 1e3, lw=0.8, label=f"minus free-tip estimate ({free_trial})")
        ax.set_xlabel("time t [s]")
        ax.set_ylabel("tip force f_tip [mN]")
        _legend_above(ax)
        fig.tight_layout()
        _save(fig, out_dir, "fig39_mismatch_subtraction")
    return caption("fig39_mismatch_subtraction",
                   f"Trial {trial}: subtracting the force the model reports on a free tip under the same input "
                   f"history ({free_trial}) removes the hysteresis-mismatch part of the error.")
