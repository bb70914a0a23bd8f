"""Writing the diagnostic's contract files (attribution.csv, budget.csv, verdict.json, shrink.csv/.md) and figures."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from selfsense.io import savefig_atomic

from .diagnose import Diagnosis

__all__ = ["write_diagnosis", "ATTRIBUTION_COLUMNS"]

ATTRIBUTION_COLUMNS = ["effect", "family", "selected", "selection_frequency", "cv_gain", "error_before",
                       "error_after", "shapley_share", "measurement"]


def _atomic_text(path: Path, text: str) -> None:
    try:
        from selfsense.io import atomic_write_text

        atomic_write_text(path, text)
    except ImportError:  # pragma: no cover
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(text)
        tmp.replace(path)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (set, frozenset, tuple)):
        return list(o)
    return str(o)


def _clean(o):
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, float) and not np.isfinite(o):
        return None
    if isinstance(o, np.floating):
        return _clean(float(o))
    return o


def shrink_markdown(shrink: pd.DataFrame) -> str:
    """Thesis Table 3 style: rows = measurement x trial, columns = model variant, 'err [lo, hi]' in % of range."""
    if shrink.empty:
        return "No held-out rows.\n"
    lines = ["# Held-out error before and after the confirmed effects (% of range, 90 % block-bootstrap interval)", ""]
    models = list(dict.fromkeys(shrink["model"]))
    lines.append("| measurement | trial | " + " | ".join(models) + " |")
    lines.append("|---|---|" + "---|" * len(models))
    for (m, tr), g in shrink.groupby(["measurement", "trial"], sort=False):
        cells = []
        for mod in models:
            r = g[g["model"] == mod]
            cells.append("" if r.empty else f"{r.error_pct.iloc[0]:.2f} [{r.ci_low.iloc[0]:.2f}, {r.ci_high.iloc[0]:.2f}]")
        lines.append(f"| {m} | {tr} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_diagnosis(d: Diagnosis, out_dir: str | Path, figures: bool = True) -> dict:
    """Write the contract files into ``out_dir``; returns {name: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, df in (("attribution", d.attribution[ATTRIBUTION_COLUMNS]), ("budget", d.budget), ("shrink", d.shrink)):
        p = out / f"{name}.csv"
        _atomic_text(p, df.to_csv(index=False, float_format="%.6g"))
        paths[name] = p
    _atomic_text(out / "shrink.md", shrink_markdown(d.shrink))
    paths["shrink_md"] = out / "shrink.md"
    _atomic_text(out / "verdict.json", json.dumps(_clean(d.verdict), indent=1, default=_json_default,
                                                  allow_nan=False) + "\n")
    paths["verdict"] = out / "verdict.json"
    if figures:
        paths.update(write_figures(d, out))
    return paths


def write_figures(d: Diagnosis, out: Path) -> dict:
    """Budget bar chart, shrink chart, residual vs V by branch (PNG, labelled axes with units)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    b = d.budget
    # 1. error budget by regime
    if not b.empty:
        reg = b[b["section"].str.startswith("regime:")]
        if not reg.empty:
            fig, axes = plt.subplots(1, 2, figsize=(11, 5), sharex=False)
            for ax, m in zip(axes, ["displacement", "force"]):
                g = reg[reg["measurement"] == m]
                lab = [f"{s.split(':', 1)[1]}: {i}" for s, i in zip(g["section"], g["item"])]
                ax.barh(lab, g["value"], color="tab:blue")
                tot = b[(b["section"] == "total") & (b["measurement"] == m)]["value"]
                if len(tot):
                    ax.axvline(float(tot.iloc[0]), color="k", ls="--", label="overall")
                fl = b[(b["section"] == "floor") & (b["measurement"] == m)]["value"]
                if len(fl):
                    ax.axvline(float(fl.iloc[0]), color="tab:red", ls=":", label="noise floor")
                ax.set_xlabel(f"{m} held-out mean |error| [% of range]")
                ax.set_title(f"{m}: error by operating regime")
                ax.tick_params(axis="y", labelsize=7)
                ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.12), ncol=2, frameon=False)
            fig.tight_layout()
            p = out / "budget_regimes.png"
            savefig_atomic(fig, p, dpi=110)
            plt.close(fig)
            paths["fig_budget"] = p
    # 2. shrink
    s = d.shrink[d.shrink["trial"] == "all"] if not d.shrink.empty else d.shrink
    if not s.empty:
        fig, ax = plt.subplots(figsize=(7, 4))
        models = list(dict.fromkeys(s["model"]))
        x = np.arange(len(models))
        for k, m in enumerate(dict.fromkeys(s["measurement"])):
            g = s[s["measurement"] == m].set_index("model").reindex(models)
            ax.bar(x + 0.38 * k, g["error_pct"], 0.36, yerr=[g["error_pct"] - g["ci_low"], g["ci_high"] - g["error_pct"]],
                   label=m, capsize=3)
        ax.set_xticks(x + 0.19, models, rotation=20, fontsize=8)
        ax.set_ylabel("held-out mean |error| [% of range]")
        ax.set_title("Shrink: refit on calibration, evaluated on validation", pad=22)
        ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False, fontsize=8)
        fig.tight_layout()
        p = out / "shrink.png"
        savefig_atomic(fig, p, dpi=110)
        plt.close(fig)
        paths["fig_shrink"] = p
    # 3. residual vs V by branch (validation trials, base model)
    fd = d.figures_data or {}
    ev, base = fd.get("ev"), fd.get("base")
    if ev is not None and base is not None:
        from .signals import branch

        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for ax, m in zip(axes, ["displacement", "force"]):
            rows = ev.rows.get(m, [])
            if not rows:
                continue
            Vs, Bs = [], []
            for tid, mask, _ in rows:
                V = ev.case.trials[tid]["V"].to_numpy(float)
                Vs.append(V[mask]); Bs.append(branch(V, 0.02 * (np.max(np.abs(V)) or 1))[mask])
            V, Bb, e = np.concatenate(Vs), np.concatenate(Bs), base.e[m]
            step = max(1, len(V) // 4000)
            for sgn, col, lab in ((1, "tab:red", "rising"), (-1, "tab:blue", "falling")):
                sel = (Bb == sgn)
                ax.plot(V[sel][::step], e[sel][::step], ".", ms=2, color=col, label=lab)
            ax.set_xlabel("actuator voltage V [V]")
            ax.set_ylabel(f"{m} error [% of range]")
            ax.set_title(f"{m} residual vs V by branch (nominal model)", pad=20)
            ax.legend(markerscale=4, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False, fontsize=8)
        fig.tight_layout()
        p = out / "residual_vs_voltage.png"
        savefig_atomic(fig, p, dpi=110)
        plt.close(fig)
        paths["fig_residual"] = p
    return paths
