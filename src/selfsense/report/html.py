"""A self-contained, deterministic HTML report of one dataset's results (figures embedded as base64 PNG).

Written for the reviewer who reads it without the code: where the numbers come from (provenance: configuration,
package version, git commit, dataset content hash and date), every coefficient with its unit, the H(q) model and
the trials it was calibrated on, Table 3 of the thesis *A force and displacement self-sensing method for a MRI
compatible tweezer end effector* (``000_18d138f03f1777c3.txt``), the figures with captions in words, and the
sim-to-real gap diagnostic explained in sentences. No raw Markdown or JSON reaches the page: the project's Markdown
tables are rendered (:func:`markdown_to_html`) and JSON documents are turned into tables and sentences.
"""
from __future__ import annotations

import base64
import html
import json
import re
from pathlib import Path
from typing import Any, Mapping

import pandas as pd

from .units import COEFFICIENTS, coef_unit

__all__ = ["build_report", "markdown_to_html", "GAP_FIGURES"]

_SEEDS = {
    "thesis": "<i>A force and displacement self-sensing method for a MRI compatible tweezer end effector</i> "
              "(thesis, 000_18d138f03f1777c3.txt)",
    "paper": "T. McPherson and J. Ueda, <i>A Force and Displacement Self-Sensing Piezoelectric MRI-Compatible "
             "Tweezer End Effector with an On Site Calibration Procedure</i> (001_972cacfaa08ad91a.txt)",
    "ri": "<i>Modeling of piezoelectric actuators based on a new rate-independent hysteresis model</i> "
          "(002_7d89b7147aad52e4.txt)",
}

#: gap diagnostic figure stem -> caption in words
GAP_FIGURES = {
    "stage_gains": "Stage-wise gap diagnostic: held-out gain of each library member, alone, over its null threshold "
                   "(effect-free cases over four device families), per stage (holds = relay short at 0 V, "
                   "electrical = charge against voltage, mechanical = laser against charge, load = load cell against "
                   "the force estimate); red: accepted. The stage split follows the free-case decomposition of "
                   "thesis Fig. 39 (000_18d138f03f1777c3.txt sec. 5.3).",
}

_INLINE = [
    (re.compile(r"`([^`]+)`"), r"<code>\1</code>"),
    (re.compile(r"\*\*([^*]+)\*\*"), r"<b>\1</b>"),
    (re.compile(r"(?<![*\w])\*([^*\s][^*]*)\*(?![*\w])"), r"<i>\1</i>"),
]


def _inline(text: str) -> str:
    """Escape, then render inline code, bold and italics of the project's Markdown."""
    out = html.escape(text, quote=False)
    for pat, rep in _INLINE:
        out = pat.sub(rep, out)
    return out


def markdown_to_html(md: str, heading_level: int = 3) -> str:
    """Render the Markdown this project writes: headings of any level (shown at ``heading_level`` or below), pipe
    tables, bullet lists, paragraphs, inline code / bold / italics. Everything else is escaped text."""
    out: list[str] = []
    rows: list[list[str]] = []
    items: list[str] = []
    para: list[str] = []

    def flush():
        if rows:
            head, body = rows[0], [r for r in rows[1:] if not all(re.fullmatch(r":?-{2,}:?", c) for c in r)]
            out.append("<table><thead><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head)
                       + "</tr></thead><tbody>")
            out.extend("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body)
            out.append("</tbody></table>")
            rows.clear()
        if items:
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
            items.clear()
        if para:
            out.append(f"<p>{_inline(' '.join(para))}</p>")
            para.clear()

    for line in md.splitlines():
        s = line.strip()
        if s.startswith("|"):
            if items or para:
                flush()
            rows.append([c.strip() for c in s.strip("|").split("|")])
            continue
        if rows:
            flush()
        m = re.match(r"^(#{1,6})\s+(.*)$", s)
        if m:
            flush()
            level = min(6, heading_level + len(m.group(1)) - 1)
            out.append(f"<h{level}>{_inline(m.group(2).rstrip('#').strip())}</h{level}>")
        elif re.match(r"^[-*]\s+", s):
            if para:
                flush()
            items.append(re.sub(r"^[-*]\s+", "", s))
        elif not s:
            flush()
        else:
            if items:
                flush()
            para.append(s)
    flush()
    return "\n".join(out)


def _img(png: Path, alt: str) -> str:
    b64 = base64.b64encode(png.read_bytes()).decode("ascii")
    return f"<img alt='{html.escape(alt)}' src='data:image/png;base64,{b64}'>"


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v) if v else "(none)"
    if v is None:
        return "(not set)"
    return str(v)


def _flatten(d: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out = []
    for k in d:
        v = d[k]
        if isinstance(v, Mapping) and v:
            out += _flatten(v, f"{prefix}{k}.")
        else:
            out.append((f"{prefix}{k}", v))
    return out


def _kv_table(rows: list[tuple[str, Any]], head=("setting", "value")) -> str:
    return ("<table><thead><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr></thead><tbody>"
            + "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(_fmt(v))}</td></tr>" for k, v in rows)
            + "</tbody></table>")


def _provenance(prov: Mapping[str, Any] | None, config: Mapping[str, Any] | None) -> list[str]:
    if not prov and not config:
        return []
    parts = ["<h2>Provenance</h2>"]
    if prov:
        labels = [("selfsense_version", "selfsense version"), ("git_commit", "git commit of the code"),
                  ("dataset", "dataset"), ("dataset_sha256", "dataset content hash (SHA-256 of rig.yaml, trials.csv "
                                                           "and every log)"),
                  ("n_files", "raw files hashed"), ("data_date", "raw data last modified (UTC)"),
                  ("python", "Python"), ("snakemake", "Snakemake")]
        parts.append("<table class='prov'><tbody>" + "".join(
            f"<tr><th>{html.escape(lab)}</th><td><code>{html.escape(_fmt(prov[k]))}</code></td></tr>"
            for k, lab in labels if k in prov) + "</tbody></table>")
    if config:
        parts.append("<details><summary>Configuration of this run (packaged defaults with the run's overrides)"
                     "</summary>" + _kv_table(_flatten(config)) + "</details>")
    return parts


def _model_section(results_dir: Path) -> list[str]:
    model = results_dir / "model" / "sensing.json"
    if not model.exists():
        return []
    d = json.loads(model.read_text())
    cfg = d.get("config", {})
    rep = d.get("fit_report", {}).get("hysteresis", {})
    trials = rep.get("trials") or ([rep["trial"]] if rep.get("trial") else [])
    kind = {"modified_pi": "Kuhnen's modified Prandtl-Ishlinskii operator with creep (thesis eqs. 28-43, "
                           "identified as a QP, thesis App. A)",
            "ri": f"the one-sided rate-independent (RI) model of {_SEEDS['ri']} with a creep bank, fitted by "
                  "least squares jointly on all free-tip calibration trials"}.get(str(rep.get("h_model")),
                                                                                   html.escape(str(rep.get("h_model"))))
    if rep.get("selected"):   # the H(q) model registry (h_identification: joint): the model the selection chose
        kind = (f"<code>{html.escape(str(rep['selected']))}</code>"
                + (" (chosen by blocked cross-validation, table below)" if rep.get("h_model") == "auto" else "")
                + ", identified jointly on the free-tip and force-reference calibration trials")
        drift = rep.get("drift") or {}
        if drift:
            src = {"holds": " (from the holds of all trials)", "calibration": " (from the calibration rows)",
                   "holds' measurement": " (the holds' measurement, in place of a contradicted search)",
                   "calibration and holds agree": " (from the calibration rows, agreeing with the holds of all "
                                                  "trials)",
                   "H(q) selection": " (from the calibration rows, adopted by the H(q) selection's blocked CV)"}.get(
                       str(drift.get("source")), "")
            kind += (f"; charge leakage {'compensated, ' + format(drift.get('leakage_s', 0) * 1e9, '.2f') + ' nS' + src if drift.get('applied') else 'not compensated'}"
                     f", offset drift {'compensated' if drift.get('offset_drift_applied') else 'not compensated'}"
                     + (f" ({html.escape(str(drift['note']))})" if drift.get("note") else ""))
            hev = drift.get("hold_evidence") or {}
            if hev.get("note"):
                kind += f"; reference-free hold evidence of all trials: {html.escape(str(hev['note']))}"
        hr = rep.get("hold_rows") or {}
        if hr.get("note"):
            kind += (f"; creep of H(q) from the holds of every trial (V and Q only, docs/method.md 6b'): "
                     f"{'used' if hr.get('applied') else 'not used'}, {html.escape(str(hr['note']))}")
    amp = d.get("amplifier") or {}
    if amp.get("note"):
        kind += (f"; actuator voltage where the HV amplifier sits at its current limit (shunt current of every trial, "
                 f"docs/method.md 1a): {'rebuilt' if amp.get('applied') else 'read from the command, eq. (56)'}, "
                 f"{html.escape(str(amp['note']))}")
    sl = amp.get("slew") or {}
    if sl.get("note"):
        kind += (f"; actuator voltage behind a fast command at the HV amplifier's slew limit (V-Q rows of the "
                 f"calibration and of every free-tip trial, docs/method.md 1a): "
                 f"{'rebuilt' if sl.get('applied') else 'read from the command'}, {html.escape(str(sl['note']))}")
    lag = d.get("amplifier_lag") or {}
    if lag.get("note"):
        kind += (f"; actuator voltage behind the command by the HV amplifier's lag (voltage link, a column gain du/dt "
                 f"in the selected H(q) form's fit, docs/method.md 1a'): "
                 + (f"carried, tau = {float(lag.get('tau_s', 0.0)) * 1e3:.3g} ms" if lag.get("applied")
                    else "not applied")
                 + f", {html.escape(str(lag['note']))}")
    ab = d.get("absorption") or {}
    if ab.get("note"):
        kind += (f"; dielectric absorption (charge link, free-tip calibration laser, docs/method.md 6c): "
                 f"{'its charge taken out of Q' if ab.get('applied') else 'not applied'}, "
                 f"{html.escape(str(ab['note']))}")
    qz = d.get("quantiser") or {}
    if qz.get("note"):
        kind += (f"; offset current of an undithered shunt channel (charge link, docs/method.md 1b'): "
                 f"{'taken out of Q' if qz.get('applied') else 'not applied'}, {html.escape(str(qz['note']))}")
    st = d.get("stress") or {}
    if st.get("note"):
        kind += (f"; stress-dependent hysteresis (load link, V_H = H(q) + w f, w = s_H (H(q) - a_H) + s_Q (Q - a_Q), "
                 f"force-reference "
                 f"calibration rows, docs/method.md 6f): "
                 + (f"carried, s_H = {st.get('s_h_per_n', 0.0):.4g} per N, s_Q = {st.get('s_q_v_per_c_n', 0.0):.4g} "
                    f"V/(C N)" if st.get("applied")
                    else "not applied")
                 + f", {html.escape(str(st['note']))}")
    tc = d.get("tip_creep") or {}
    if tc.get("note"):
        od = tc.get("offset_drift_check") or {}
        kind += (f"; charge-free creep strain (load link, a bank of lags on Q and V_p at both tip outputs, "
                 f"displacement calibration rows, docs/method.md 6h): "
                 f"{'carried' if tc.get('applied') else 'not applied'}, {html.escape(str(tc['note']))}"
                 + (f"; {html.escape(str(od['note']))}" if od.get("note") else ""))
    tm = d.get("temperature") or {}
    if tm.get("note"):
        kind += (f"; charge scale drifting over the campaign (charge link, temperature; free- and blocked-tip trials' "
                 f"reference-free relation, docs/method.md 6i): "
                 + (f"carried, {tm.get('slope_per_trial', 0.0):.3g} per trial of trials.csv" if tm.get("applied")
                    else "not applied")
                 + f", {html.escape(str(tm['note']))}")
    mode = {"thesis": "free-tip target H(q) = V - q / (n_A C_p), thesis eq. (55)",
            "onsite": "on-site calibration, paper eq. (23)"}.get(str(cfg.get("h_mode")), str(cfg.get("h_mode")))
    ntr = "trial" if len(trials) == 1 else "trials"
    on = rep.get("trial")
    fit = (f"fit error RMS {rep.get('rms_pct', float('nan')):.3f} % and max {rep.get('max_pct', float('nan')):.3f} % "
           f"of the H(q) range ({rep.get('rms_v', float('nan')):.3g} V RMS)"
           + (f" on trial <code>{html.escape(str(on))}</code>" if len(trials) > 1 and on else ""))
    parts = ["<h2>Calibrated model</h2>",
             f"<p>H(q): {kind}; calibrated on {ntr} "
             + ", ".join(f"<code>{html.escape(str(t))}</code>" for t in trials)
             + f" ({mode}); {fit}.</p>"]
    # what the calibration warned about (a configured H(q) kind that could not be fitted, one that does not beat a
    # straight line, a member that could not be applied): in the report, not only in a rule's log
    cw = list(dict.fromkeys(str(w) for w in list(rep.get("warnings") or [])
                            + list(d.get("fit_report", {}).get("warnings") or [])))
    if cw:
        parts.append("<p><strong>Calibration warnings:</strong></p><ul>"
                     + "".join(f"<li>{html.escape(w)}</li>" for w in cw) + "</ul>")
    cal = d.get("calibration_trials") or []
    if cal:
        parts.append("<p>Sensing coefficients regressed on the calibration trials "
                     + ", ".join(f"<code>{html.escape(str(t))}</code>" for t in cal)
                     + " (thesis eq. (52): dx_tip = A1 Q + A2 V_p, f_tip = B21 Q + B22 V_p, with the total charge Q "
                       "[C] and the piezo voltage V_p = V - H(q) [V]; B21 = A3 / n_A, B22 = -C_p A3 in the thesis' "
                       "approximation).</p>")
        rest = d.get("fit_report", {}).get("rest_offset") or {}
        if rest.get("note"):
            parts.append(f"<p>Rest offset dx0 (a tip that rests open or closed: remanent charge the integrator never "
                         f"saw): {html.escape(str(rest['note']))}.</p>")
    cres = d.get("fit_report", {}).get("charge_resolution") or {}
    if cres.get("note"):
        parts.append(f"<p>Charge resolution (the shunt channel's ADC step where the current is constant, docs/method.md "
                     f"1b): {html.escape(str(cres['note']))}"
                     + (f"; on the validation trials it is worth {cres.get('validation_dx_pct', 0):.3g} % of the "
                        f"displacement range and {cres.get('validation_f_pct', 0):.3g} % of the force range on average "
                        f"(1 SD of the charge error; compare Table 3)" if cres.get("limited") else "") + ".</p>")
    hcost = d.get("fit_report", {}).get("h_error_cost") or {}
    if hcost.get("note"):
        parts.append(f"<p>What the error of H(q) costs the tip estimates (V_p = V - H(q) enters thesis eq. (52) "
                     f"through A2 and B22; docs/method.md 6g): {html.escape(str(hcost['note']))}.</p>")
    meaning = {"A1": "tip displacement per total charge", "A2": "tip displacement per piezo voltage",
               "A3": "tip force per actuator charge (thesis eq. 52)", "B21": "tip force per total charge",
               "B22": "tip force per piezo voltage",
               "dx0": "tip closing at rest (rest offset: remanent charge the integrator never saw; 0 if not adopted)",
               "S2": "tip-port stiffness of the two-port force row (regression: twoport)",
               "h_slope": "slope of the free-tip H(q) target (1 / (n_A C_p))"}
    rows = []
    for k, v in d.get("coef", {}).items():
        if not isinstance(v, dict):   # (the retired gap library's augmentation terms were nested dicts)
            rows.append((k, v, coef_unit(k), meaning.get(k, "")))
    if "h_slope" in d:
        rows.append(("h_slope", d["h_slope"], COEFFICIENTS["h_slope"], meaning["h_slope"]))
    parts.append("<table><thead><tr><th>coefficient</th><th>value</th><th>unit</th><th>meaning</th></tr></thead>"
                 "<tbody>" + "".join(f"<tr><td>{html.escape(k)}</td><td>{float(v):.6g}</td><td>{html.escape(u)}</td>"
                                     f"<td>{html.escape(m)}</td></tr>" for k, v, u, m in rows) + "</tbody></table>")
    rng = d.get("ranges", {})
    if rng.get("dx") and rng.get("f"):
        parts.append(f"<p>Physical ranges used for limiting (thesis sec. 5.2), from the calibration references: "
                     f"displacement {rng['dx'][0] * 1e3:.3g} to {rng['dx'][1] * 1e3:.3g} mm, force "
                     f"{rng['f'][0] * 1e3:.3g} to {rng['f'][1] * 1e3:.3g} mN.</p>")
    return parts


def _selection_section(results_dir: Path) -> list[str]:
    """The H-model selection table of the final model (results/<d>/model/sensing.json: the sensing regression may
    have calibrated H(q) again), else the calibration's results/<d>/model/h_selection.csv."""
    model, p = results_dir / "model" / "sensing.json", results_dir / "model" / "h_selection.csv"
    df = pd.DataFrame()
    if model.exists():
        from selfsense.report.tables import selection_frame

        df = selection_frame(json.loads(model.read_text()).get("fit_report", {}))
    if df.empty and p.exists():
        df = pd.read_csv(p)
    if df.empty:
        return []
    sel_col = next((c for c in df.columns if c.lower() in ("selected", "is_selected")), None)
    head = "".join(f"<th>{html.escape(str(c).replace('_', ' '))}</th>" for c in df.columns)
    body = []
    for _, r in df.iterrows():
        chosen = sel_col is not None and str(r[sel_col]).strip().lower() in ("true", "1", "yes")
        cells = "".join(f"<td>{html.escape(_fmt(v) if not isinstance(v, float) else f'{v:.4g}')}</td>"
                        for v in r.to_list())
        body.append(f"<tr class='{'selected' if chosen else ''}'>{cells}</tr>")
    chosen_txt = ""
    if sel_col is not None:
        sel = df[df[sel_col].astype(str).str.strip().str.lower().isin(["true", "1", "yes"])]
        if len(sel):
            chosen_txt = (" The selected model (highlighted) is "
                          + html.escape(", ".join(str(v) for v in sel.iloc[0].to_list()[:2])) + ".")
    return ["<h2>H(q) model selection</h2>",
            "<p>Candidate H(q) models and regularisations compared by cross-validation over the calibration trials "
            "(RMS error per fold and mean, in the units of the file's columns) against the linear baseline."
            + chosen_txt + "</p>",
            f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"]


def _pct(x: Any) -> str:
    return f"{x:.2f} %" if isinstance(x, (int, float)) else "n/a"


def _gap_section(gap: Path, results_dir: Path) -> list[str]:
    """The stage-wise gap diagnostic (selfsense.gap.pipeline) in sentences and tables: the stage that carries the
    gap, the effect, the shrink, why each candidate was or was not confirmed."""
    parts = ["<h2>Sim-to-real gap diagnostic (stage by stage)</h2>"]
    v = gap / "verdict.json"
    vd: dict = {}
    if v.exists():
        try:
            vd = json.loads(v.read_text())
        except json.JSONDecodeError:
            parts.append("<p>The verdict file could not be read.</p>")
    if vd and "stages" in vd:
        parts.append(f"<p><b>Verdict.</b> {html.escape(str(vd.get('message', '')))}</p>")
        names = {"holds": "holds (shunt signal while the relay shorts the actuators, 0 V)",
                 "electrical": "electrical (measured charge against the actuator voltage, free-tip trials)",
                 "mechanical": "mechanical (laser against the measured charge, free-tip trials)",
                 "blocked": "blocked (actuator voltage against the measured charge, blocked-tip trials, no reference)",
                 "load": "load (load cell against the nominal force estimate, force trials)",
                 "anchors": "anchors (the fitted chain's charge scale on free- and blocked-tip trials, no reference: "
                            "RMS about the tip offsets, without and with a trend over the campaign)"}
        rows = []
        order = [k for k in ("holds", "electrical", "mechanical", "blocked", "load") if k in vd["stages"]]
        for st in order + [k for k in vd["stages"] if k not in order]:
            d = vd["stages"][st]
            if not d.get("observed"):
                rows.append(f"<tr><td>{html.escape(names.get(st, st))}</td><td colspan='4'>not observed in this "
                            "dataset</td></tr>")
                continue
            acc = ", ".join(html.escape(a["effect"]) for a in d.get("accepted", [])) or "none"
            closed = 1.0 - d["rms_after"] / d["rms_nominal"] if d["rms_nominal"] > 0 else float("nan")
            rows.append(f"<tr><td>{html.escape(names.get(st, st))}</td><td>{d['rms_nominal']:.4g}</td>"
                        f"<td>{d['rms_after']:.4g}</td><td>{closed * 100:.1f} %</td><td>{acc}"
                        + (" (unexplained structure remains)" if d.get("unexplained") else "") + "</td></tr>")
        parts.append("<p><b>Where</b>: held-out RMS of each stage's nominal model (units of the stage's target: "
                     "V, C, m or N) before and after the accepted library members.</p><table><tr><th>stage</th>"
                     "<th>nominal</th><th>with the members</th><th>closed</th><th>effects named there</th></tr>"
                     + "".join(rows) + "</table>")
        tip = vd.get("tip", {})
        b = tip.get("before", {})
        t3 = vd.get("table3") or {}
        rec = ""
        if t3:
            rec = (f" These are Table 3's numbers ({_pct(t3.get('displacement'))} / {_pct(t3.get('force'))}): the "
                   "diagnostic scores the pipeline's fitted model exactly as Table 3 does (difference "
                   + ", ".join(f"{k} {abs(x):.1e} points" for k, x in (vd.get("reconciliation") or {}).items())
                   + ").")
        parts.append(f"<p><b>How far</b>: the configured estimator's held-out error is "
                     f"{_pct(b.get('displacement'))} (displacement) and {_pct(b.get('force'))} (force).{rec} Each "
                     "confirmed effect is corrected with its stage-fitted coefficients fixed, the estimator "
                     "recalibrated on the corrected calibration trials and scored again (shrink.md below; positive "
                     "= smaller error; 90 % interval: the block bootstrap's, its upper side widened for what the "
                     "recalibrated chain leaves of the effect, docs/gap.md).</p>")
        eff = tip.get("effects") or {}
        if eff:
            parts.append("<ul>" + "".join(
                f"<li><code>{html.escape(n)}</code>: {te['shrink']:+.2f} points of range "
                f"({te['shrink_interval_90'][0]:+.2f} to {te['shrink_interval_90'][1]:+.2f}); after it "
                f"{_pct(te['after'].get('displacement'))} / {_pct(te['after'].get('force'))}"
                + (f" ({html.escape(te['how'])})" if te.get("how") else "") + "</li>"
                for n, te in eff.items()) + "</ul>")
        ch = vd.get("chain") or {}
        if ch.get("members"):
            rows = []
            for m, r in ch["members"].items():
                if r.get("adopted"):
                    w = r.get("without") or {}
                    rows.append(f"<tr><td>{html.escape(m.replace('_', ' '))}</td><td>adopted (from the "
                                f"{html.escape(str(r.get('source')))})</td><td>{_pct(w.get('displacement'))} / "
                                f"{_pct(w.get('force'))}</td><td>{r.get('contribution', float('nan')):+.2f}</td></tr>")
                else:
                    rows.append(f"<tr><td>{html.escape(m.replace('_', ' '))}</td><td>not adopted</td><td>"
                                "</td><td></td></tr>")
            parts.append("<p><b>The estimator's own chain members</b> (the charge link: the same leakage, offset "
                         "and absorption models the diagnostic tests; the voltage link: the actuator voltage rebuilt "
                         "where the HV amplifier sits at its current limit; the H link: the creep of H(q) from the "
                         "holds of every trial). "
                         "Table 3 is computed with the adopted members; each row gives "
                         "Table 3 of the chain recalibrated without that member (displacement / force) and the "
                         "change of their mean in points (positive = the member lowers the error). Why a member was "
                         "or was not adopted is in the calibration section above.</p><table><tr><th>member</th>"
                         "<th>decision</th><th>Table 3 without it</th><th>its contribution</th></tr>"
                         + "".join(rows) + "</table>")
        cands = [c for c in vd.get("candidates", []) if not c.get("accepted")]
        cands.sort(key=lambda c: -(c["gain_alone"] / c["threshold"]) if c.get("threshold") else 0.0)
        if cands:
            parts.append("<p><b>Why the other candidates were not confirmed</b> (closest first):</p><ul>" + "".join(
                f"<li><code>{html.escape(c['member'])}</code> ({html.escape(c['stage'])}): {html.escape(c['why'])}"
                "</li>" for c in cands[:8]) + "</ul>"
                + (f"<p>{len(cands) - 8} more in candidates.csv.</p>" if len(cands) > 8 else ""))
        if vd.get("protocol_proposal"):
            parts.append("<p><b>Next acquisition.</b></p>" + markdown_to_html(str(vd["protocol_proposal"]), 4))
    for md in sorted(gap.glob("*.md")):
        parts.append(markdown_to_html(md.read_text(), 3))
    for png in sorted(gap.glob("*.png")):
        cap = GAP_FIGURES.get(png.stem, png.stem.replace("_", " "))
        parts.append(f"<figure>{_img(png, cap)}<figcaption>{html.escape(cap)}</figcaption></figure>")
    return parts


_STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em;line-height:1.4}"
          "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;font-size:90%;"
          "text-align:left}table.prov th{background:#f4f4f4}tr.selected{background:#e6f4e6;font-weight:bold}"
          "figure{margin:1em 0}figcaption{font-size:90%;color:#333}img{max-width:100%}"
          "details{margin:0.5em 0}summary{cursor:pointer}code{background:#f6f6f6;padding:0 2px}")


def build_report(dataset_dir: Path, results_dir: Path, failed: list[str], config: Mapping[str, Any] | None = None,
                 provenance: Mapping[str, Any] | None = None) -> str:
    name = dataset_dir.name
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>selfsense report: {html.escape(name)}</title>",
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>Self-sensing report: dataset <code>{html.escape(name)}</code></h1>",
        f"<p>Method: {_SEEDS['thesis']}, eqs. (52)-(57), with the on-site calibration of {_SEEDS['paper']}. "
        "Errors are mean absolute errors and, per trial, in % of that trial's reference range; Table 3 averages the "
        "validation trials, which no fit has seen.</p>",
    ]
    parts += _provenance(provenance, config)
    vpath = results_dir / "validation.json"
    warnings: list[str] = []
    if vpath.exists():
        vdoc = json.loads(vpath.read_text())
        for trial, msgs in vdoc.get("failed", {}).items():
            failed = list(failed) + [f"{trial}: " + "; ".join(msgs)]
        warnings = list(vdoc.get("warnings", []))
    if warnings:  # physical plausibility warnings of selfsense.io.plausibility (docs/data_format.md)
        parts.append("<h2>Data warnings</h2><p>Plausibility checks of the raw data that did not stop the run:</p><ul>"
                     + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul>")
    if failed:
        parts.append("<h2>Failed trials</h2><p>Left out of every table and figure:</p><ul>"
                     + "".join(f"<li>{html.escape(f)}</li>" for f in failed) + "</ul>")
    tables = results_dir / "tables"
    parts.append("<h2>Accuracy (thesis Table 3 / paper Table II)</h2>")
    for md in ("table3.md", "modes.md", "per_trial.md", "coverage.md"):
        p = tables / md
        if p.exists():
            parts.append(markdown_to_html(p.read_text(), 3))
    parts += _model_section(results_dir)
    parts += _selection_section(results_dir)
    figs = results_dir / "figures"
    caps_path = figs / "captions.json"
    if caps_path.exists():
        caps = json.loads(caps_path.read_text())
        parts.append("<h2>Figures</h2>")
        from .figure_list import FIGURES

        order = {k: i for i, k in enumerate(FIGURES)}
        for stem in sorted(caps, key=lambda k: (order.get(k, len(order)), k)):
            png = figs / f"{stem}.png"
            if png.exists():
                parts.append(f"<figure>{_img(png, caps[stem])}<figcaption>{html.escape(caps[stem])}</figcaption>"
                             "</figure>")
    gap = results_dir / "gap"
    if gap.exists():
        parts += _gap_section(gap, results_dir)
    parts.append("</body></html>\n")
    return "\n".join(parts)
