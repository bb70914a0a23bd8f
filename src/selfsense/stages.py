"""The pipeline's stages as plain functions: each Snakemake rule's script calls exactly one of them.

They read their inputs from disk, call the science in ``selfsense.*`` and write their outputs atomically, so they
can also be used from a notebook or the ``selfsense`` command without Snakemake. The flow::

    data/raw/<d>/  -> validate -> signals/<trial>.parquet -> model/hysteresis.json -> model/sensing.json
                   -> estimates/<trial>.parquet -> tables/*.csv|md -> figures/*.png|pdf -> report.html
"""
from __future__ import annotations

import contextvars
import io
import json
import logging
import sys
import threading
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from selfsense import io as sio
from selfsense.sensing import SelfSensingEstimator, SensingConfig
from selfsense.signals import prepare_trial

#: the columns of a signals file that SelfSensingEstimator.estimate and the scoring read
_ESTIMATE_INPUTS = ["t", "V", "q", "u_cmd", "relay", "dx_ref", "f_ref"]
SIGNAL_COLUMNS = ["t", "V", "q", "u_cmd", "relay", "dx_ref", "f_ref", "V_c", "V_s"]
ESTIMATE_COLUMNS = ["t", "dx_hat", "f_hat", "dx_ref", "f_ref"]


def _meta(dataset_dir: str | Path) -> pd.DataFrame:
    return sio.load_trials(dataset_dir).set_index("trial")


def sensing_config(config: Mapping[str, Any]) -> SensingConfig:
    """Build the estimator configuration from the ``calibration`` and ``estimation`` sections of config.yaml."""
    merged = dict(config.get("calibration", {}) or {})
    merged.update(config.get("estimation", {}) or {})
    return SensingConfig.from_mapping(merged)


#: the pipeline's sample budget per trial (config max_trial_samples): 10 min at 10 kHz, measured below 2 GB per job
#: by benchmarks/memory_pipeline.py (benchmarks/MEMORY.md)
MAX_TRIAL_SAMPLES = 6_000_000
#: compare_modes evaluates six estimators per trial (three H(q) identifications x two calibration modes), two of
#: them RI models (about 270 B more per sample than the modified PI, benchmarks/MEMORY.md): longer validation
#: trials are left out of that secondary table, with a note in it
COMPARE_MAX_SAMPLES = 2_000_000


def validate(dataset_dir: str | Path, out_json: str | Path, on_bad_trial: str = "fail",
             max_trial_samples: int | None = MAX_TRIAL_SAMPLES) -> dict:
    """Check the whole dataset against docs/data_format.md.

    Problems of ``rig.yaml`` / ``trials.csv`` or of a calibration trial's log always raise ``ContractError`` listing
    every problem. Problems confined to one validation trial's log raise too with ``on_bad_trial="fail"`` (default);
    with ``"skip"`` that trial is recorded as failed (with its problems) in ``out_json`` and left out of the run,
    and the report lists it.
    """
    if on_bad_trial not in ("fail", "skip"):
        raise ValueError(f"on_bad_trial: expected 'fail' or 'skip', found {on_bad_trial!r}")
    problems, warnings = sio.check_dataset(dataset_dir, pipeline=True, max_trial_samples=max_trial_samples)
    try:
        meta = _meta(dataset_dir)
    except sio.ContractError:
        raise sio.ContractError(problems) from None
    file_to_trial = {str(Path(str(f))): t for t, f in meta["file"].items()}
    per_trial: dict[str, list[str]] = {}
    fatal = []
    for p in problems:
        trial = file_to_trial.get(str(Path(str(p.file))))
        if trial is None or on_bad_trial == "fail" or meta.loc[trial, "role"] == "calibration":
            fatal.append(p)
        else:
            per_trial.setdefault(trial, []).append(str(p))
    if fatal:
        raise sio.ContractError(problems)
    valid = [t for t in meta.index if t not in per_trial]   # trials.csv order (the order of listings)
    summary = {"dataset": Path(dataset_dir).name, "valid": not per_trial, "n_trials": int(len(meta)),
               "trials": valid, "failed": {t: per_trial[t] for t in meta.index if t in per_trial},
               "warnings": [str(w) for w in warnings]}
    for w in warnings:
        print(f"warning: {w}")
    for t, msgs in summary["failed"].items():
        print(f"trial {t!r} failed validation and is left out (on_bad_trial=skip):", *msgs, sep="\n  ")
    sio.write_json_atomic(summary, out_json)
    return summary


#: Parquet schema metadata key of a skip placeholder: a trial that failed validation with ``on_bad_trial: skip``
#: still has its per-trial files (the DAG is fixed before any job runs: no checkpoint), each an empty table whose
#: metadata holds the reason; :func:`by_trial` leaves such files out of every dataset-level stage
SKIPPED_KEY = b"selfsense_skipped"


def write_skipped(path: str | Path, trial: str, reason: str) -> Path:
    """A skip placeholder for ``trial`` at ``path`` (empty Parquet table, the reason in its schema metadata)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({"t": pa.array([], pa.float64())}).replace_schema_metadata(
        {SKIPPED_KEY: f"trial {trial!r} {reason}".encode()})
    with sio.atomic_write(path, "wb") as fh:
        pq.write_table(table, fh)
    return Path(path)


def skipped_reason(path: str | Path) -> str | None:
    """The reason if ``path`` is a skip placeholder (:func:`write_skipped`), else None (reads the footer only)."""
    import pyarrow.parquet as pq

    p = Path(path)
    if p.suffix != ".parquet" or not p.exists():
        return None
    meta = pq.read_schema(p).metadata or {}
    r = meta.get(SKIPPED_KEY)
    return r.decode() if r is not None else None


def failed_trials(validation_json: str | Path) -> dict[str, list]:
    """Trials that failed validation and are left out (``on_bad_trial: skip``), from ``validation.json``."""
    import json

    return dict(json.loads(Path(validation_json).read_text()).get("failed", {})) if validation_json else {}


def ingest(dataset_dir: str | Path, trial: str, out_parquet: str | Path,
           validation_json: str | Path | None = None) -> pd.DataFrame | None:
    """Raw DAQ log -> SI signals with actuator voltage and charge (thesis eqs. 56-57). A trial that
    ``validation_json`` lists as failed (``on_bad_trial: skip``) gets a skip placeholder instead."""
    if validation_json is not None and trial in failed_trials(validation_json):
        write_skipped(out_parquet, trial, "failed validation and is left out (on_bad_trial: skip)")
        return None
    rig = sio.load_rig(dataset_dir)
    df = prepare_trial(sio.trial_signals(dataset_dir, trial, rig=rig), rig)  # a fresh frame, RangeIndex
    sio.write_parquet_atomic(df, out_parquet, columns=SIGNAL_COLUMNS)  # no copy of the frame (sample budget)
    return df[SIGNAL_COLUMNS]


def _load_signals(paths: Mapping[str, str | Path]) -> dict[str, pd.DataFrame]:
    return {t: pd.read_parquet(p) for t, p in paths.items()}


def calibrate(dataset_dir: str | Path, signal_paths: Mapping[str, str | Path], config: Mapping[str, Any],
              out_json: str | Path) -> SelfSensingEstimator:
    """Calibrate H(q) on the free-tip calibration trial (thesis eq. 55 or paper eq. 23) with Kuhnen's QP."""
    rig = sio.load_rig(dataset_dir)
    est = SelfSensingEstimator(config=sensing_config(config), rig=rig)
    est.fit_hysteresis(_load_signals(signal_paths), _meta(dataset_dir))
    sio.write_json_atomic(est.to_dict(), out_json)
    sio.write_text_atomic(selection_table(est).to_csv(index=False, float_format="%.6g"),
                          Path(out_json).parent / "h_selection.csv")
    return est


def selection_table(est: SelfSensingEstimator) -> pd.DataFrame:
    """The H(q) model-selection table of a fitted estimator: one row per candidate (blocked-CV RMS per fold and mean
    [V], the straight line's mean for comparison, selected flag); empty for the thesis identification."""
    from selfsense.report.tables import selection_frame

    return selection_frame(est.fit_report_)


def regress(dataset_dir: str | Path, signal_paths: Mapping[str, str | Path], hysteresis_json: str | Path,
            out_json: str | Path) -> SelfSensingEstimator:
    """Regress the sensing coefficients A1-A3 (thesis eq. 52) on the calibration trials. Where the creep member is
    carried beside an offset-drift member, H(q) may be calibrated again here without the drift
    (:meth:`SelfSensingEstimator.fit_coefficients`): ``sensing.json`` is then the model to read, not
    ``hysteresis.json``."""
    rig = sio.load_rig(dataset_dir)
    est = SelfSensingEstimator.from_dict(json.loads(Path(hysteresis_json).read_text()), rig)
    est.fit_coefficients(_load_signals(signal_paths), _meta(dataset_dir))
    sio.write_json_atomic(est.to_dict(), out_json)
    return est


def load_estimator(dataset_dir: str | Path, model_json: str | Path) -> SelfSensingEstimator:
    return SelfSensingEstimator.from_dict(json.loads(Path(model_json).read_text()), sio.load_rig(dataset_dir))


def estimate(dataset_dir: str | Path, signal_path: str | Path, model_json: str | Path,
             out_parquet: str | Path, full_out: str | Path | None = None) -> pd.DataFrame:
    """Estimate tip displacement and force of one trial; writes the contract columns ``t, dx_hat, f_hat, dx_ref, f_ref``.
    A skipped trial's signals (a placeholder) give placeholders."""
    why = skipped_reason(signal_path)
    if why is not None:
        for p in (out_parquet, full_out):
            if p is not None:
                write_skipped(p, Path(signal_path).stem, why.split(" ", 2)[-1])
        return None
    est = load_estimator(dataset_dir, model_json)
    sig = pd.read_parquet(signal_path, columns=_ESTIMATE_INPUTS)
    out = est.estimate(sig, trial=Path(signal_path).stem)
    out["dx_ref"] = sig["dx_ref"].to_numpy()
    out["f_ref"] = sig["f_ref"].to_numpy()
    del sig  # memory: the trial is held once at a time (sample budget, benchmarks/MEMORY.md)
    out = out.reset_index(drop=True) if not isinstance(out.index, pd.RangeIndex) else out
    sio.write_parquet_atomic(out, out_parquet, columns=ESTIMATE_COLUMNS)  # no copy of the frame (sample budget)
    if full_out is not None:
        sio.write_parquet_atomic(out, full_out)
    return out


def score(dataset_dir: str | Path, estimate_paths: Mapping[str, str | Path], out_dir: str | Path) -> pd.DataFrame:
    """Thesis Table 3 and per-trial errors (CSV + Markdown)."""
    from selfsense.report import tables

    out_dir = Path(out_dir)
    meta = _meta(dataset_dir).reset_index()
    ests = {t: pd.read_parquet(p) for t, p in estimate_paths.items()}
    pt = tables.per_trial_table(ests, meta)
    t3 = tables.table3(pt)
    sio.write_text_atomic(pt.to_csv(index=False, float_format="%.6g"), out_dir / "per_trial.csv")
    sio.write_text_atomic(t3.to_csv(index=False, float_format="%.6g"), out_dir / "table3.csv")
    sio.write_text_atomic(tables.per_trial_markdown(pt), out_dir / "per_trial.md")
    sio.write_text_atomic(tables.table3_markdown(t3), out_dir / "table3.md")
    return t3


def coverage(dataset_dir: str | Path, signal_paths: Mapping[str, str | Path], per_trial_csv: str | Path | None,
             out_dir: str | Path, model_json: str | Path | None = None) -> pd.DataFrame:
    """The drive coverage of the calibration (:mod:`selfsense.report.coverage`): ``coverage.csv`` and ``coverage.md``
    in ``out_dir``; with the score rule's ``per_trial.csv``, the validation errors with and without each feature the
    calibration lacks; with the fitted model (``sensing.json``), which lacking holds its hold rows fitted."""
    import json

    from selfsense.report.coverage import coverage_markdown, coverage_table

    out_dir = Path(out_dir)
    cov = coverage_table(dict(signal_paths), _meta(dataset_dir).reset_index())
    pt = pd.read_csv(per_trial_csv) if per_trial_csv is not None else None
    hold_rows = None
    if model_json is not None:
        hold_rows = json.loads(Path(model_json).read_text()).get("fit_report", {}).get("hysteresis", {}).get(
            "hold_rows")
    sio.write_text_atomic(cov.to_csv(index=False, float_format="%.6g"), out_dir / "coverage.csv")
    sio.write_text_atomic(coverage_markdown(cov, pt, hold_rows), out_dir / "coverage.md")
    return cov


#: compare_modes runs a full garbage collection after trials of at least this many samples (memory of long trials)
GC_MIN_SAMPLES = 1_000_000


def compare_modes(dataset_dir: str | Path, signal_paths: Mapping[str, str | Path], config: Mapping[str, Any],
                  out_csv: str | Path, out_md: str | Path, model_json: str | Path | None = None,
                  estimate_paths: Mapping[str, str | Path] | None = None) -> pd.DataFrame:
    """Table 3 for both calibration modes of the seeds (thesis eq. 55 vs paper eq. 23) and three ways to identify H(q),
    same data and other settings: the H model selected by blocked CV, identified jointly on every free-tip and
    force-reference calibration trial (the default); Kuhnen's modified PI with creep (thesis eqs. 36-43) on the
    free-tip trial only, as the thesis does; the RI model of the third seed + creep bank on the free-tip trials.

    ``model_json``: the pipeline's fitted model. A combination whose configuration is the pipeline model's is not
    fitted again: its row is scored on that model's estimates (the same numbers, without refitting the model
    selection), read from ``estimate_paths`` (the pipeline's estimates) where given, else estimated here -- the
    pipeline's rule does not wait for the estimate jobs, it runs beside them. The selected model's other calibration mode
    refits the H form the pipeline's blocked CV selected in that mode's gauge, instead of repeating the whole
    selection: the gauges differ by a term linear in Q, which every linear-in-parameter candidate absorbs in its
    unpenalised linear column. For the same reason the form is held without the blocked CV against the straight line
    (``h_selection_cv``: the model the CV gives wherever the form beats the line, as it did in the pipeline's gauge)
    and the pipeline's leakage search is taken over (``leakage_search_any_gauge``: the search's reference model
    absorbs the gauge term the same way; a fresh search in the other gauge found the same conductance to a relative
    2e-12 on tweezer_sim, and modes.csv / modes.md came out byte-identical)."""
    from selfsense.report import tables

    rig = sio.load_rig(dataset_dir)
    meta = _meta(dataset_dir)
    # memory bounded by the longest trial, not the dataset: calibration trials stay loaded (the fits need them),
    # the six estimators are fitted first, then every other trial is read once, estimated by each and scored,
    # keeping only its error rows; Arrow's buffers come from the system allocator so that a freed trial is
    # returned to the OS instead of being cached (benchmarks/MEMORY.md)
    import gc

    import pyarrow as pa

    pool = pa.default_memory_pool()
    pa.set_memory_pool(pa.system_memory_pool())
    try:
        cal = {t: p for t, p in signal_paths.items() if t in meta.index and meta.loc[t, "role"] == "calibration"}
        sigs = _load_signals(cal)
        # the default (model selected by blocked CV, joint identification, drift compensation) and the thesis'
        # identification of the modified PI and of the RI model, each in both calibration modes
        combos = tuple((h, ident, mode) for h, ident in (("auto", "joint"), ("modified_pi", "thesis"), ("ri", "thesis"))
                       for mode in ("thesis", "onsite"))
        ests = {}
        reused = None   # the combination the pipeline already fitted
        pipeline = load_estimator(dataset_dir, model_json) if model_json is not None else None
        for h_model, ident, mode in combos:
            cfg = dict(config)
            extra = {} if ident == "joint" else {"drift": "off"}
            cfg["calibration"] = dict(config.get("calibration", {}) or {}, h_mode=mode, h_model=h_model,
                                      h_identification=ident, **extra)
            sc = sensing_config(cfg)
            if pipeline is not None and reused is None and sc == pipeline.config:
                ests[(h_model, ident, mode)] = pipeline
                reused = (h_model, ident, mode)
                continue
            # the other calibration mode of the selected model: the H form the pipeline's blocked CV selected,
            # refitted in this mode's gauge with the pipeline's leakage search -- not a second selection or search
            cands = pipeline.selected_form() if pipeline is not None and h_model == "auto" else ()
            held = {"h_candidates": cands, "h_selection_cv": False, "leakage_search_any_gauge": True,
                    "leakage_search_reuse": (pipeline.fit_report_.get("hysteresis", {}).get("drift") or {}).get(
                        "search")} if cands else {}
            ests[(h_model, ident, mode)] = SelfSensingEstimator(config=sc, rig=rig, **held).fit(sigs, meta)
        pts: dict = {c: [] for c in combos}
        left_out = {}
        for t in sorted(signal_paths):
            if t not in sigs:
                import pyarrow.parquet as pq

                n = pq.ParquetFile(str(signal_paths[t])).metadata.num_rows
                if n > COMPARE_MAX_SAMPLES:  # sample budget: the RI evaluation needs ~270 B more per sample
                    left_out[t] = n
                    continue
            s = sigs[t] if t in sigs else pd.read_parquet(signal_paths[t], columns=_ESTIMATE_INPUTS)
            for c in combos:
                if c == reused and t in (estimate_paths or {}):
                    e = pd.read_parquet(estimate_paths[t], columns=["dx_hat", "f_hat"])
                else:
                    e = ests[c].estimate(s, trial=t)
                e = pd.DataFrame({"dx_hat": e["dx_hat"].to_numpy(), "f_hat": e["f_hat"].to_numpy(),
                                  "dx_ref": s["dx_ref"].to_numpy(), "f_ref": s["f_ref"].to_numpy()})
                pts[c].append(tables.per_trial_table({t: e}, meta.reset_index()))
                del e
            # the frames are freed by reference counting; a full collection (0.1 s each with the fitted models
            # alive) only after a long trial, where cyclic garbage would matter for the sample budget
            long = len(s) >= GC_MIN_SAMPLES
            del s
            if long:
                gc.collect()
    finally:
        pa.set_memory_pool(pool)
    rows = []
    for (h_model, ident, mode) in combos:
        est = ests[(h_model, ident, mode)]
        t3 = tables.table3(pd.concat(pts[(h_model, ident, mode)], ignore_index=True))
        for _, r in t3.iterrows():
            rows.append({"h_model": h_model, "h_identification": ident, "h_mode": mode,
                         "h_selected": est.fit_report_["hysteresis"].get("selected", h_model),
                         "measurement": r["measurement"],
                         "mean_abs_error": r["mean_abs_error"],
                         "percent_of_range": r["percent_of_range"], "n_trials": r["n_trials"],
                         "h_fit_rms_pct": est.fit_report_["hysteresis"].get("rms_pct", float("nan"))})
    df = pd.DataFrame(rows)
    sio.write_text_atomic(df.to_csv(index=False, float_format="%.6g"), out_csv)
    lines = ["### Table 3 for both H(q) calibration modes and three H(q) identifications", "",
             "| H(q) model | identified on | H(q) calibration | displacement, % of range | force, % of range | "
             "H fit RMS, % |", "|---|---|---|---|---|---|"]
    label = {"thesis": "thesis eq. (55)", "onsite": "on-site, paper eq. (23)"}
    mlabel = {"auto": "selected by blocked CV", "modified_pi": "modified PI + creep (thesis eqs. 36-43)",
              "ri": "RI (third seed) + creep bank"}
    ilabel = {"joint": "all free-tip and force-reference calibration trials, drift compensation",
              "thesis": "the free-tip trial(s) only (thesis)"}
    for (h_model, ident, mode), g in df.groupby(["h_model", "h_identification", "h_mode"], sort=False):
        g = g.set_index("measurement")
        name = mlabel[h_model] + (f": {g['h_selected'].iloc[0]}" if h_model == "auto" else "")
        lines.append(f"| {name} | {ilabel[ident]} | {label[mode]} | {g.loc['displacement', 'percent_of_range']:.2f} | "
                     f"{g.loc['force', 'percent_of_range']:.2f} | {g['h_fit_rms_pct'].iloc[0]:.3f} |")
    if left_out:
        lines += ["", "Left out of this comparison (sample budget of " + f"{COMPARE_MAX_SAMPLES:,} samples per trial; "
                  "Table 3 includes them): " + ", ".join(f"{t} ({n:,} samples)" for t, n in sorted(left_out.items()))]
    sio.write_text_atomic("\n".join(lines) + "\n", out_md)
    return df


def figures(dataset_dir: str | Path, signal_paths: Mapping[str, str | Path], model_json: str | Path,
            internals_paths: Mapping[str, str | Path], per_trial_csv: str | Path, out_dir: str | Path) -> dict:
    """Regenerate the papers' figures; returns {figure stem: caption} (also written to captions.json).

    ``internals_paths`` are the full estimate frames written by :func:`estimate` (``full_out``: raw and
    post-processed estimates, V_p, V_H, q and the references)."""
    from selfsense.report import figures as F
    from selfsense.sensing.estimator import _eval_h, h_target

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    meta = _meta(dataset_dir)
    est = load_estimator(dataset_dir, model_json)
    free_trial = est.fit_report_["hysteresis"]["trial"]
    sig_free = pd.read_parquet(signal_paths[free_trial])
    caps = {}
    caps["fig17_voltage_charge"] = F.fig_voltage_charge(sig_free, out_dir, free_trial)
    Ht = h_target(sig_free["V"].to_numpy(), sig_free["q"].to_numpy(), est.h_slope_)
    Hf = _eval_h(est.hysteresis_, sig_free["q"].to_numpy())
    rep = est.fit_report_["hysteresis"]
    caps["fig21_h_calibration"] = F.fig_h_calibration(sig_free, Ht, Hf, out_dir, free_trial,
                                                      rep.get("rms_pct", np.nan), rep.get("max_pct", np.nan))
    # sample budget (selfsense.io.budget): a long trial is drawn from every k-th row, read batch by batch
    full, dec = {}, {}
    for t, p in internals_paths.items():
        full[t], k = sio.read_parquet_decimated(p, sio.FIGURE_MAX_ROWS)
        if k > 1:
            dec[t] = k
    listed = [t for t in meta.index if t in full]   # trials.csv order
    disp = [t for t in listed if meta.loc[t, "reference"] == "displacement" and meta.loc[t, "role"] == "validation"]
    disp = disp or [t for t in listed if meta.loc[t, "reference"] == "displacement"]
    if disp:
        pick = next((t for t in disp if meta.loc[t, "tip"] == "object"), disp[0])
        caps["fig24_limiting_dc_offset"] = F.fig_limiting(full[pick], out_dir, pick, limit=bool(est.config.limit),
                                                          dc_offset=bool(est.config.dc_offset))
    # Figs. 22-23: the sine and the mixed drive (the sine of the H(q) calibration trial when it is one)
    sig_all = {t: sio.read_parquet_decimated(p, sio.FIGURE_MAX_ROWS, columns=["t", "V_c", "V", "u_cmd"])[0]
               for t, p in signal_paths.items()}
    for stem, kinds in (("fig22_input_sine", ("sine",)), ("fig23_input_mixed", ("mixed", "steps", "other"))):
        cands = [t for kind in kinds for t in sorted(sig_all) if meta.loc[t, "signal"] == kind]
        if kinds == ("sine",) and free_trial in cands:
            cands.insert(0, free_trial)
        if cands:
            caps[stem] = F.fig_input(sig_all[cands[0]], out_dir, cands[0], stem)
    pt = pd.read_csv(per_trial_csv)
    for measurement in ("displacement", "force"):
        for role in ("validation", "calibration"):
            cap = F.fig_trials(full, meta.reset_index(), measurement, out_dir, pt, role=role)
            if cap is not None:
                stem = (("fig25-30_displacement_trials" if measurement == "displacement" else "fig31-36_force_trials")
                        if role == "validation" else f"cal_{measurement}_trials")
                caps[stem] = cap
    obj = [t for t in sorted(full) if meta.loc[t, "tip"] == "object"]
    if obj:
        # prefer a displacement-reference object trial whose twin (same object, drive and length) has the load cell
        def twin(t):
            m = meta.loc[t]
            for o in obj:
                mo = meta.loc[o]
                if (o != t and mo["reference"] != m["reference"] and mo["signal"] == m["signal"]
                        and str(mo["object_mm"]) == str(m["object_mm"]) and len(full[o]) == len(full[t])
                        and np.allclose(sig_all[o]["u_cmd"].to_numpy(), sig_all[t]["u_cmd"].to_numpy(), atol=1e-6)):
                    return o
            return None
        pick = next((t for t in obj if twin(t) is not None), obj[0])
        tw = twin(pick)
        caps["fig37_force_displacement"] = F.fig_force_displacement(full[pick], out_dir, pick,
                                                                    full[tw] if tw else None, tw)
    # Fig. 39: a force trial minus the free-tip estimate under the same input history (same signal family)
    forces = sorted((t for t in full if meta.loc[t, "reference"] == "force" and meta.loc[t, "tip"] != "free"),
                    key=lambda t: (meta.loc[t, "role"] != "validation", t))  # a validation trial when there is one
    frees = [t for t in sorted(full) if meta.loc[t, "tip"] == "free"]
    for ft in forces:
        same = [t for t in frees if meta.loc[t, "signal"] == meta.loc[ft, "signal"] and len(full[t]) == len(full[ft])]
        if same:
            caps["fig39_mismatch_subtraction"] = F.fig_mismatch(full[ft], full[same[0]], out_dir, ft, same[0])
            break
    if dec:
        note = " Long trials drawn from every k-th sample: " + ", ".join(f"{t} k = {k}" for t, k in sorted(dec.items()))
        caps = {s: (c + note if s.startswith(("fig22", "fig23", "fig24", "fig25", "fig31", "fig37", "fig39", "cal_"))
                    else c)
                for s, c in caps.items()}
    sio.write_json_atomic(caps, out_dir / "captions.json")
    return caps


def export_matlab(dataset_dir: str | Path, trial: str, signals: str | Path, internals: str | Path,
                  model_json: str | Path, out_mat: str | Path, out_csv: str | Path) -> None:
    """One trial's results as MATLAB ``.mat`` and CSV (selfsense.report.export.export_trial)."""
    from selfsense.report.export import export_trial

    why = skipped_reason(signals)
    if why is not None:  # a skipped trial: files that say so (a .mat with one string variable, a one-line CSV)
        from scipy.io import savemat

        sio.write_text_atomic(f"# {why}\n", out_csv)
        with sio.atomic_write(out_mat, "wb") as fh:
            savemat(fh, {"skipped": why})
        return
    export_trial(dataset_dir, trial, signals, internals, model_json, out_mat=out_mat, out_csv=out_csv)


def report(dataset_dir: str | Path, results_dir: str | Path, out_html: str | Path, failed: list[str] | None = None,
           config: Mapping[str, Any] | None = None) -> str:
    """One self-contained HTML report: provenance (``config`` of the run, package version, git commit, dataset hash
    and date), tables, model summary with units, figures with captions, gap verdict in words if present."""
    from selfsense.report.html import build_report
    from selfsense.report.provenance import provenance

    html = build_report(Path(dataset_dir), Path(results_dir), failed=failed or [], config=config,
                        provenance=provenance(dataset_dir))
    sio.write_text_atomic(html, out_html)
    return str(out_html)


#: the log file of the job running in the current thread (a context variable: like a thread-local, and carried into
#: the worker threads a job starts with a copy of its context, e.g. the H(q) selection's,
#: selfsense.hysteresis.models.select.cv_workers)
_LOG_FH: contextvars.ContextVar = contextvars.ContextVar("selfsense_job_log", default=None)
_INSTALL_LOCK = threading.Lock()


class _ThreadStream(io.TextIOBase):
    """``sys.stdout``/``sys.stderr`` stand-in that writes to the log file of the job running in the current thread
    (rules with ``run:`` execute in threads of the Snakemake process) and to the original stream otherwise."""

    def __init__(self, fallback):
        self._fallback = fallback

    def _target(self):
        return _LOG_FH.get() or self._fallback

    def write(self, s):
        return self._target().write(s)

    def flush(self):
        self._target().flush()

    def isatty(self):
        return False


class _ThreadLogHandler(logging.Handler):
    """Logging records of ``selfsense`` (and Python warnings) go to the current thread's job log, if any."""

    def emit(self, record):
        fh = _LOG_FH.get()
        if fh is not None:
            fh.write(self.format(record) + "\n")


def _install_routing() -> None:
    with _INSTALL_LOCK:
        if not isinstance(sys.stdout, _ThreadStream):
            sys.stdout = _ThreadStream(sys.stdout)
        if not isinstance(sys.stderr, _ThreadStream):
            sys.stderr = _ThreadStream(sys.stderr)
        for name in ("selfsense", "py.warnings"):
            lg = logging.getLogger(name)
            if not any(isinstance(h, _ThreadLogHandler) for h in lg.handlers):
                h = _ThreadLogHandler()
                h.setFormatter(logging.Formatter("%(name)s: %(message)s"))
                lg.addHandler(h)
                lg.setLevel(logging.INFO)
        logging.captureWarnings(True)


def _process_age_s() -> float:
    """Seconds since this process started (interpreter start-up, imports, Snakemake's script preamble)."""
    try:
        import psutil

        return max(0.0, time.time() - psutil.Process().create_time())
    except Exception:  # pragma: no cover - psutil comes with Snakemake
        return float("nan")


class logged:
    """Context manager around one pipeline job: its stdout/stderr and ``selfsense`` log records go to the rule's
    log; an exception is logged with its traceback. Thread-safe, so it serves both rule kinds:

    * ``run:`` rules execute in a thread of the Snakemake process (no interpreter start-up, imports paid once);
    * ``script:`` rules run in a process of their own.

    An exception is written to the log with its traceback and its message to stderr (``ERROR: ...``, which
    ``selfsense run`` repeats at the end). In a ``script:`` rule, bad input (ValueError incl. ContractError,
    OSError, KeyError) then ends the script with exit code 1 (no traceback on the terminal); in a ``run:`` rule
    and for anything else the exception is re-raised for Snakemake to report.

    On exit it appends one line ``timing: startup_s=<s> compute_s=<s>`` to the log (``benchmarks/pipeline_speed.py``
    reads it): start-up is the age of the process when the job's code starts (interpreter, imports, Snakemake's
    script preamble; 0 for ``run:`` rules, which share the Snakemake process), compute is the time inside.
    """

    def __init__(self, log_path: str | Path, exit_on_bad_input: bool = True):
        self.log_path = Path(log_path)
        #: end a ``script:`` process with exit code 1 on bad input (no traceback); ``run:`` jobs, which run in the
        #: Snakemake process, pass False and turn the re-raised exception into :class:`BadInput`
        self.exit_on_bad_input = exit_on_bad_input

    def __enter__(self):
        _one_blas_thread()  # same thread count, so the same bits, in run: and script: jobs (docs/reproducibility.md)
        self._in_thread = threading.current_thread() is not threading.main_thread()
        self._startup = 0.0 if self._in_thread else _process_age_s()
        self._t0 = time.perf_counter()
        _install_routing()
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.log_path, "w")
        self._token = _LOG_FH.set(self._fh)
        return self

    def __exit__(self, exc_type, exc, tb):
        import traceback

        compute = time.perf_counter() - self._t0
        if exc is not None:
            self._fh.write(f"ERROR: {exc}\n")
            traceback.print_exception(exc_type, exc, tb, file=self._fh)
        self._fh.write(f"timing: startup_s={self._startup:.3f} compute_s={compute:.3f}\n")
        _LOG_FH.reset(self._token)
        self._fh.close()
        if exc is not None:
            print(f"ERROR: {exc}", file=sys.stderr)
            if self._in_thread:  # run: rule: Snakemake reports the job as failed, with the message
                return False
            if self.exit_on_bad_input and isinstance(exc, (ValueError, OSError, KeyError)):  # bad input: no traceback
                print(f"(traceback in {self.log_path})", file=sys.stderr)
                raise SystemExit(1) from None
        return False


def by_trial(paths) -> dict[str, str]:
    """Map a list of ``.../<trial>.parquet`` paths to {trial: path}, leaving out skip placeholders (trials that
    failed validation with ``on_bad_trial: skip``, :func:`write_skipped`)."""
    return {Path(p).stem: str(p) for p in paths if skipped_reason(p) is None}


#: the pipeline rules that run inside the Snakemake process (``run:``), by rule name: (input, output, params,
#: wildcards) -> stage call. Rules with plotting (figures, gap diagnostic), the H(q) calibration (its workers are
#: forked from its process) and the heavier mode comparison keep ``script:`` and a process of their own.
_JOBS = {
    "validate_dataset": lambda i, o, p, w: validate(p.dataset_dir, o[0], p.on_bad_trial,
                                                    int(getattr(p, "max_trial_samples", MAX_TRIAL_SAMPLES))),
    "ingest": lambda i, o, p, w: ingest(p.dataset_dir, w.trial, o[0], i.validation),
    "regress_coefficients": lambda i, o, p, w: regress(p.dataset_dir, by_trial(i.signals), i.hysteresis, o[0]),
    "estimate": lambda i, o, p, w: estimate(p.dataset_dir, i.signals, i.model, o.estimate, full_out=o.internals),
    "score": lambda i, o, p, w: score(p.dataset_dir, by_trial(i.estimates), p.out_dir),
    "coverage": lambda i, o, p, w: coverage(p.dataset_dir, by_trial(i.signals), i.per_trial, p.out_dir, i.model),
    "report": lambda i, o, p, w: print(report(p.dataset_dir, p.results_dir, o[0], config=p.run_config)),
    "export_matlab": lambda i, o, p, w: export_matlab(p.dataset_dir, w.trial, i.signals, i.internals, i.model,
                                                      o.mat, o.csv),
}


def _one_blas_thread() -> None:
    """Jobs of the Snakemake process run side by side in threads (one core each, ``threads: 1``); a multi-threaded
    BLAS in each of them would oversubscribe the cores (measured: ``Q.T @ Q`` of a 60,000 x 46 regressor matrix,
    thesis eq. 65, takes 0.011 s on one OpenBLAS thread and 0.66 s on two while the other core is busy), and the
    results depend on the thread count: :func:`selfsense.determinism.single_thread_blas`."""
    from selfsense.determinism import single_thread_blas

    single_thread_blas()


def run_job(name: str, input, output, params, wildcards, log) -> None:
    """Body of the workflow's ``run:`` rules (workflow/rules/pipeline.smk): the stage of rule ``name`` inside
    :class:`logged`, in a thread of the Snakemake process (or in a process of its own on a cluster)."""
    _one_blas_thread()
    try:
        with logged(log[0], exit_on_bad_input=False):
            _JOBS[name](input, output, params, wildcards)
    except (ValueError, OSError, KeyError) as exc:  # bad input: its message, the traceback stays in the log
        raise BadInput(f"{type(exc).__name__}: {exc}") from None


class BadInput(Exception):
    """A ``run:`` job stopped on bad input; the message names file, field and expectation (full traceback in the
    rule's log)."""
