"""The gap diagnostic inside the pipeline: reads the pipeline's signals and fitted model, diagnoses the configured
estimator, and reconciles with Table 3 (docs/gap.md, "In the pipeline").

* Where / which: :func:`selfsense.gap.stages.diagnose_stages` on the pipeline's prepared signals
  (``results/<dataset>/signals``), thresholds from :mod:`selfsense.gap.blind` (null cases over the device
  families).
* How far: :func:`selfsense.gap.counterfactual.counterfactual` with the *configured* estimator: "before" is the
  pipeline's fitted model (``model/sensing.json``) scored exactly as Table 3 (so the numbers are Table 3's), each
  "after" a recalibration of the same configuration on the corrected calibration trials.
* The excitation check and the protocol proposal of :mod:`selfsense.gap.protocol`.

Outputs (all-or-nothing into ``out_dir``): ``verdict.json``, ``stages.csv``, ``effects.csv``, ``candidates.csv``,
``shrink.csv`` / ``shrink.md`` (thesis Table 3 style) and ``stage_gains.png``.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

__all__ = ["run_pipeline_diagnosis", "diagnose_pipeline", "reconcile", "write_draft", "finish_from_draft", "reconcile_job",
           "diagnose_dataset", "why_not"]


def why_not(verdict: dict) -> list[dict]:
    """One row per library member: accepted or, if not, why (from the verdict's numbers)."""
    rows = []
    thr = verdict.get("thresholds", {})
    for st, d in verdict["stages"].items():
        if not d.get("observed"):
            continue
        acc = {a["member"]: a for a in d["accepted"]}
        for m, g in d["gains_alone"].items():
            if m == "generic":
                continue
            t = float(d.get("thresholds", {}).get(m, thr.get(m, np.nan)))
            if m in acc:
                a = acc[m]
                why = (f"accepted: the chain's anchors change by {a['gain']:.2g} over the campaign >= threshold "
                       f"{a['threshold']:.2g}" if st == "anchors" else
                       f"accepted: held-out gain {a['gain']:.3f} > threshold {a['threshold']:.3f}")
                if a.get("note"):
                    why += f"; named {a['effect']}: {a['note']}"
            elif any(n.startswith(m + ":") for n in d.get("notes", [])):
                why = next(n for n in d["notes"] if n.startswith(m + ":")).split(": ", 1)[1]
            elif g > t:
                why = (f"gain {g:.3f} alone is above its threshold {t:.3f}, but once the accepted members were in "
                       "the stage model it no longer was (they explain the same residual)")
            elif st == "anchors":
                why = f"the chain's anchors change by {g:.2g} over the campaign, below the member's threshold {t:.2g}"
            else:
                why = f"held-out gain {g:.3f} is below its null threshold {t:.3f}"
            rows.append({"stage": st, "member": m, "gain_alone": float(g), "threshold": t, "accepted": m in acc,
                         "why": why})
    return rows


def diagnose_dataset(trials: dict, meta: pd.DataFrame, rig, make_estimator, fitted=None, thresholds=None,
                     seed: int = 0, n_boot: int = 200, refit_outputs: bool = True, workers: int = 1) -> dict:
    """Stage verdict + tip counterfactual of one dataset in memory (JSON-able dict). ``workers``: recalibrations of
    the counterfactual and of the chain's member contributions fitted at a time (the same bits for any count)."""
    from .blind import load_stage_thresholds
    from .counterfactual import chain_contributions, contribution_sets, counterfactual
    from .protocol import excitation_check, proposal

    from .stages import diagnose_stages

    thr = load_stage_thresholds() if thresholds is None else thresholds
    v = diagnose_stages(trials, meta, rig, thr, fitted=fitted)
    chain = fitted is not None and hasattr(fitted, "members")
    cf = counterfactual(trials, meta, rig, v, make_estimator, n_boot=n_boot, seed=seed, fitted=fitted,
                        refit_outputs=refit_outputs, workers=workers,
                        also_members=contribution_sets(fitted) if chain else ())
    v = {k: x for k, x in v.items() if not k.startswith("_")}
    v["thresholds"] = thr
    tables = cf.pop("_tables", None)
    v["tip"] = cf
    if chain:
        # the estimator's own chain members: Table 3 with and without each (the same chain the counterfactual forces)
        v["chain"] = chain_contributions(trials, meta, rig, make_estimator, fitted, tables=tables)
    v["candidates"] = why_not(v)
    try:
        ex = excitation_check(trials, meta)
        v["excitation"] = ex
        v["protocol_proposal"] = proposal(ex)
    except Exception as exc:  # noqa: BLE001 - the check is advice; say why it is missing
        v["excitation"] = {"error": f"{type(exc).__name__}: {exc}"}
    v["families"] = sorted({e["family"] for e in v["effects"]})
    v["message"] = message(v)
    return v


def message(v: dict) -> str:
    """The verdict in one paragraph: the stage that carries the gap, the effect, the shrink."""
    parts = []
    if v["effects"]:
        e = v["effects"][0]
        te = v["tip"]["effects"].get(e["effect"], {})
        parts.append(f"The largest gap is in the {e['stage']} stage: {e['effect']} (held-out gain {e['gain']:.3f}, "
                     f"{e['score']:.1f}x its null threshold"
                     + (f", {e['grid_value']} {e['unit']}" if e.get("grid_value") is not None else "") + ").")
        if te and te.get("how"):
            lo, hi = te["shrink_interval_90"]
            parts.append(f"It is a member of the estimator's stage chain; {te['how']}: the tip error changes by "
                         f"{te['shrink']:+.2f} points of range (90 % interval {lo:+.2f} to {hi:+.2f}; positive = "
                         "smaller error).")
        elif te:
            lo, hi = te["shrink_interval_90"]
            parts.append(f"Corrected with its stage-fitted coefficients fixed, the tip error changes by "
                         f"{te['shrink']:+.2f} points of range (90 % interval {lo:+.2f} to {hi:+.2f}; positive = "
                         "smaller error).")
            if abs(te["shrink"]) < 0.1:
                parts.append("The effect is plain in its stage but costs the configured estimator's tip error less "
                             "than 0.1 points of range (the estimator already absorbs or compensates it).")
        if len(v["effects"]) > 1:
            parts.append("Also confirmed: " + ", ".join(f"{x['effect']} ({x['stage']})" for x in v["effects"][1:])
                         + ".")
            tip = v["tip"]
            if "shrink_all" in tip:
                lo, hi = tip["shrink_all_interval_90"]
                parts.append(f"All together ({', '.join(tip.get('joint_effects', [])) or 'none'}), from the chain "
                             f"without its carried confirmed members, the tip error changes by {tip['shrink_all']:+.2f} "
                             f"points of range (90 % interval {lo:+.2f} to {hi:+.2f}).")
            for n, why in (tip.get("joint_left_out") or {}).items():
                parts.append(f"{n} is left out of all together: {why}.")
    else:
        parts.append("No library effect beat its null threshold in any stage.")
    ch = v.get("chain") or {}
    for m, r in (ch.get("members") or {}).items():
        if r.get("adopted"):
            parts.append(f"The estimate carries the chain member {m.replace('_', ' ')} (from the {r['source']}): "
                         f"without it Table 3's mean would change by {r['contribution']:+.2f} points.")
    if v["unexplained"]:
        parts.append("Unexplained structure remains in the " + ", ".join(v["unexplained"])
                     + " stage(s): the generic model-error model gains beyond every library member there (an effect "
                       "outside the library, e.g. backlash, a dead band, another mode).")
    return " ".join(parts)


def _tables(v: dict) -> dict[str, pd.DataFrame]:
    st_rows = []
    for st, d in v["stages"].items():
        st_rows.append({"stage": st, "observed": bool(d.get("observed")), "trials": ";".join(d.get("trials", [])),
                        "rms_nominal": d.get("rms_nominal", np.nan), "rms_after": d.get("rms_after", np.nan),
                        "rms_target": d.get("rms_target", np.nan),
                        "relative_gap_closed": (1 - d["rms_after"] / d["rms_nominal"]) if d.get("observed") else np.nan,
                        "accepted": ";".join(a["member"] for a in d.get("accepted", [])),
                        "generic_gain_after": d.get("generic_gain_after", np.nan),
                        "unexplained": bool(d.get("unexplained", False))})
    tip = v["tip"]
    ef_rows = []
    for e in v["effects"]:
        te = tip["effects"].get(e["effect"], {})
        ef_rows.append({"effect": e["effect"], "family": e["family"], "stage": e["stage"], "member": e["member"],
                        "gain": e["gain"], "score_over_threshold": e["score"], "grid_value": e.get("grid_value"),
                        "unit": e.get("unit", ""), "stage_shrink_rms": e["shrink_rms"],
                        "tip_shrink_points": te.get("shrink", np.nan),
                        "tip_shrink_lo90": (te.get("shrink_interval_90") or [np.nan])[0],
                        "tip_shrink_hi90": (te.get("shrink_interval_90") or [np.nan, np.nan])[1],
                        "tip_shrink_lo90_blocks": (te.get("shrink_interval_90_blocks") or [np.nan])[0],
                        "tip_shrink_hi90_blocks": (te.get("shrink_interval_90_blocks") or [np.nan, np.nan])[1],
                        "shapley_points": (tip.get("shapley") or {}).get(e["effect"], np.nan),
                        "in_all_together": e["effect"] in tip.get("joint_effects", [])})
    sh_rows = []
    for meas in ("displacement", "force"):
        if meas not in tip["before"]:
            continue
        row = {"measurement": meas, "before": tip["before"][meas]}
        for n, te in tip["effects"].items():
            row[f"after {n}"] = te["after"].get(meas, np.nan)
        row["after all"] = tip["after_all"].get(meas, np.nan)
        sh_rows.append(row)
    ch_rows = []
    ch = v.get("chain") or {}
    for m, r in (ch.get("members") or {}).items():
        row = {"member": m, "adopted": bool(r["adopted"]), "source": r.get("source", "")}
        for meas in ("displacement", "force", "mean"):
            row[f"table3_{meas}"] = ch["table3"].get(meas, np.nan)
            row[f"without_{meas}"] = (r.get("without") or {}).get(meas, np.nan)
        row["contribution_points"] = r.get("contribution", np.nan)
        ch_rows.append(row)
    if ch.get("without_all"):
        row = {"member": "all carried", "adopted": True, "source": ""}
        for meas in ("displacement", "force", "mean"):
            row[f"table3_{meas}"] = ch["table3"].get(meas, np.nan)
            row[f"without_{meas}"] = ch["without_all"].get(meas, np.nan)
        row["contribution_points"] = ch.get("contribution_all", np.nan)
        ch_rows.append(row)
    return {"stages": pd.DataFrame(st_rows), "effects": pd.DataFrame(ef_rows), "shrink": pd.DataFrame(sh_rows),
            "candidates": pd.DataFrame(v["candidates"]),
            "chain": pd.DataFrame(ch_rows, columns=["member", "adopted", "source", "table3_displacement",
                                                    "without_displacement", "table3_force", "without_force",
                                                    "table3_mean", "without_mean", "contribution_points"])}


def _figure(v: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from selfsense.io import savefig_atomic

    rows = [r for r in v["candidates"] if np.isfinite(r["threshold"])]
    fig, ax = plt.subplots(figsize=(8, 0.28 * len(rows) + 1.4))
    y = np.arange(len(rows))
    ratio = [r["gain_alone"] / r["threshold"] for r in rows]
    ax.barh(y, ratio, color=["tab:red" if r["accepted"] else "tab:gray" for r in rows])
    ax.axvline(1.0, color="k", lw=1)
    ax.set_yticks(y)
    ax.set_yticklabels([f"{r['stage']}: {r['member']}" for r in rows], fontsize=7)
    ax.set_xlabel("held-out gain of the member alone / its null threshold [-]\n(anchors: the chain's campaign "
                  "change / its adoption threshold; accepted in red)", fontsize=8)
    ax.set_title("Stage-wise gap diagnostic: which effect, where\n(cf. thesis Fig. 39 for the free-case budget)",
                 fontsize=9)
    ax.set_xscale("symlog", linthresh=1.0)
    fig.tight_layout()
    savefig_atomic(fig, path)
    plt.close(fig)


def _json_default(o):
    """JSON for the verdict's NumPy scalars and arrays, sets and tuples; anything else as its string."""
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (set, frozenset, tuple)):
        return list(o)
    return str(o)


def write(v: dict, out: Path, figures: bool = True, drawn: str | Path | None = None) -> None:
    """The verdict's files into ``out``; ``drawn``: ``stage_gains.png`` as :func:`write_draft` drew it, copied instead
    of drawn again (the same figure: it reads the member candidates only, not the reconciliation with Table 3)."""
    import shutil

    from selfsense.io import atomic_write_text

    out.mkdir(parents=True, exist_ok=True)
    T = _tables(v)
    for name, df in T.items():
        atomic_write_text(out / f"{name}.csv", df.to_csv(index=False, float_format="%.6g"))
    sh = T["shrink"]
    md = ["| measurement | " + " | ".join(sh.columns[1:]) + " |", "|---" * len(sh.columns) + "|"]
    for _, r in sh.iterrows():
        md.append(f"| {r['measurement']} | " + " | ".join(f"{r[c]:.2f} %" for c in sh.columns[1:]) + " |")
    atomic_write_text(out / "shrink.md", "Held-out error of the configured estimator (thesis Table 3: mean "
                      "|error| in % of each validation trial's reference range), before and after each confirmed "
                      "effect's correction with its stage-fitted coefficients fixed (recalibrated on the corrected "
                      "calibration trials).\n\n" + "\n".join(md) + "\n")
    atomic_write_text(out / "verdict.json", json.dumps(v, indent=1, sort_keys=True, default=_json_default) + "\n")
    if drawn is not None:
        shutil.copyfile(drawn, out / "stage_gains.png")
    elif figures:
        _figure(v, out / "stage_gains.png")


def _configured(config: Mapping[str, Any]):
    """(SensingConfig of the ``calibration`` / ``estimation`` sections, a factory rig -> unfitted estimator)."""
    from selfsense.sensing.estimator import SelfSensingEstimator
    from selfsense.stages import sensing_config

    cfg = sensing_config(config)
    return cfg, lambda rig_: SelfSensingEstimator(config=cfg, rig=rig_)


def _config_record(cfg) -> dict:
    return {k: (list(x) if isinstance(x, tuple) else x) for k, x in vars(cfg).items()}


def diagnose_pipeline(dataset_dir: str | Path, signal_paths: Mapping[str, str | Path], model_json: str | Path,
                      config: Mapping[str, Any], seed: int = 0, workers: int = 1) -> dict:
    """The pipeline's gap diagnosis in memory: pipeline signals + fitted model -> the verdict, without its
    reconciliation with Table 3 (:func:`reconcile`). Its "before" is computed here, as Table 3 is, so nothing of it
    waits for the score rule; ``workers``: recalibrations fitted at a time."""
    from selfsense import io as sio
    from selfsense.stages import load_estimator

    from selfsense.io.budget import GAP_MAX_SAMPLES

    from .data import within_budget

    rig = sio.load_rig(dataset_dir)
    meta = sio.load_trials(dataset_dir).set_index("trial")
    # memory bound (selfsense.io.budget): a trial longer than the diagnostic's sample budget is reduced to block
    # means of k samples (the charge was integrated at the full rate by the pipeline's ingest)
    trials, decimated = {}, {}
    for t, p in signal_paths.items():
        trials[t], k = within_budget(pd.read_parquet(p), GAP_MAX_SAMPLES)
        if k > 1:
            decimated[t] = k
    meta = meta.loc[[t for t in meta.index if t in trials]]
    fitted = load_estimator(dataset_dir, model_json)
    cfg, make = _configured(config)
    v = diagnose_dataset(trials, meta, rig, make, fitted=fitted, seed=seed, refit_outputs=False, workers=workers)
    v["counterfactual_note"] = ("charge and voltage corrections: the configured estimator recalibrated on the "
                                "corrected calibration trials; output corrections (charge-free motion, load stage): "
                                "the pipeline's fitted model with the correction added to its estimate")
    v["estimator"] = {"config": _config_record(cfg), "model": str(model_json)}
    if decimated:
        v["decimated"] = decimated
        v["decimation_note"] = ("trials longer than the diagnostic's sample budget were diagnosed on block means of k "
                                "samples; their 'before' then differs from Table 3 by that averaging")
    return v


def reconcile(v: dict, table3_csv: str | Path | None) -> dict:
    """``v`` with Table 3 as the score rule wrote it (``table3``) and the difference of the diagnosis' "before" from
    it (``reconciliation``: CSV rounding, or the decimation of long trials); unchanged without the file."""
    if table3_csv is not None and Path(table3_csv).exists():
        t3 = pd.read_csv(table3_csv).set_index("measurement")["percent_of_range"]
        v["table3"] = {m: float(t3.get(m, np.nan)) for m in ("displacement", "force")}
        v["reconciliation"] = {m: float(v["tip"]["before"].get(m, np.nan) - v["table3"][m])
                               for m in ("displacement", "force")}
    return v


def write_draft(v: dict, verdict_pkl: str | Path, figure_png: str | Path) -> None:
    """The pipeline rule ``gap_diagnose``'s outputs: the verdict of :func:`diagnose_pipeline` as a pickle (every
    value as computed, for :func:`finish_from_draft`) and ``stage_gains.png``, drawn here, in the rule's own process,
    so that the rule that finishes the folder runs in the Snakemake process without matplotlib."""
    import pickle

    from selfsense.io import atomic_write_bytes

    atomic_write_bytes(verdict_pkl, pickle.dumps(v, protocol=pickle.HIGHEST_PROTOCOL))
    _figure(v, Path(figure_png))


def finish_from_draft(verdict_pkl: str | Path, figure_png: str | Path, table3_csv: str | Path | None,
                      out_dir: str | Path, dataset_dir: str | Path) -> dict:
    """The pipeline rule ``gap_reconcile``: the draft of :func:`write_draft` reconciled with Table 3 and written
    all-or-nothing into ``out_dir``, the files :func:`run_pipeline_diagnosis` writes, byte for byte."""
    import pickle

    from selfsense.io import output_dir

    v = reconcile(pickle.loads(Path(verdict_pkl).read_bytes()), table3_csv)
    with output_dir(out_dir, [dataset_dir], force=True) as tmp:
        write(v, Path(tmp), drawn=figure_png)
    return v


def run_pipeline_diagnosis(dataset_dir: str | Path, signal_paths: Mapping[str, str | Path], model_json: str | Path,
                           config: Mapping[str, Any], out_dir: str | Path, table3_csv: str | Path | None = None,
                           seed: int = 0, figures: bool = True, force: bool = True, workers: int = 1) -> dict:
    """Pipeline signals + fitted model -> verdict files in ``out_dir`` in one call (:func:`diagnose_pipeline`,
    :func:`reconcile`, :func:`write`); the pipeline runs the same as two rules, ``gap_diagnose`` and
    ``gap_reconcile``. ``workers``: recalibrations fitted at a time."""
    from selfsense.io import output_dir

    v = reconcile(diagnose_pipeline(dataset_dir, signal_paths, model_json, config, seed=seed, workers=workers),
                  table3_csv)
    with output_dir(out_dir, [dataset_dir], force=force) as tmp:
        write(v, Path(tmp), figures=figures)
    return v


def run_stage_diagnose(dataset_dir: str | Path, out_dir: str | Path, config: Mapping[str, Any] | None = None,
                       seed: int = 0, figures: bool = True, force: bool = False, workers: int = 1) -> dict:
    """``selfsense gap diagnose``: the same diagnosis on a raw dataset outside the pipeline. The dataset is
    validated and prepared as the pipeline's ingest does (thesis eqs. 56-57), the configured estimator (``config``:
    the ``calibration`` / ``estimation`` sections, default: the pipeline's defaults) is calibrated on its
    calibration trials, then diagnosed (``workers``: recalibrations fitted at a time, the same result for any
    count); ``out_dir`` is written all-or-nothing."""
    from selfsense.io import check_output_dir, output_dir

    from .data import load_case

    check_output_dir(out_dir, [dataset_dir], force=force)
    case = load_case(dataset_dir, with_truth=False)
    cfg, make = _configured(config or {})
    fitted = make(case.rig).fit(case.trials, case.meta)
    v = diagnose_dataset(case.trials, case.meta, case.rig, make, fitted=fitted, seed=seed, refit_outputs=False,
                         workers=workers)
    v["estimator"] = {"config": _config_record(cfg)}
    if case.decimated:
        v["decimated"] = {t: int(k) for t, k in sorted(case.decimated.items())}
    with output_dir(out_dir, [dataset_dir], force=force) as tmp:
        write(v, Path(tmp), figures=figures)
    return v


def reconcile_job(input, output, params, log) -> None:
    """Body of the workflow's ``gap_reconcile`` rule (a ``run:`` rule, inside the Snakemake process):
    :func:`finish_from_draft` inside the rule's log."""
    from selfsense import stages

    with stages.logged(log[0], exit_on_bad_input=False):
        finish_from_draft(input.verdict, input.figure, input.table3, output.gap, params.dataset_dir)
