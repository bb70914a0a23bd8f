"""A self-contained, deterministic HTML report of one dataset's results (figures embedded as base64 PNG)."""
from __future__ import annotations

import base64
import html
import json
from pathlib import Path



def _md_table_to_html(md: str) -> str:
    """Render the simple pipe tables this project writes (header, separator, rows) and '###' titles."""
    out, rows = [], []

    def flush():
        if rows:
            head, body = rows[0], rows[2:] if len(rows) > 1 else []
            out.append("<table><thead><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in head) + "</tr></thead><tbody>")
            for r in body:
                out.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>")
            out.append("</tbody></table>")
            rows.clear()

    for line in md.splitlines():
        s = line.strip()
        if s.startswith("|"):
            rows.append([c.strip() for c in s.strip("|").split("|")])
            continue
        flush()
        if s.startswith("###"):
            out.append(f"<h3>{html.escape(s.lstrip('#').strip())}</h3>")
        elif s:
            out.append(f"<p>{html.escape(s)}</p>")
    flush()
    return "\n".join(out)


def build_report(dataset_dir: Path, results_dir: Path, failed: list[str]) -> str:
    name = dataset_dir.name
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>selfsense report: {html.escape(name)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;font-size:90%}"
        "figure{margin:1em 0}figcaption{font-size:90%;color:#333}img{max-width:100%}</style></head><body>",
        f"<h1>Self-sensing report: dataset <code>{html.escape(name)}</code></h1>",
        "<p>Method: thesis <i>A force and displacement self-sensing method for a MRI compatible tweezer end effector</i> "
        "(000_18d138f03f1777c3.txt), eqs. (52)-(57), with the on-site calibration of 001_972cacfaa08ad91a.txt. "
        "Errors are mean absolute errors and, per trial, in % of that trial's reference range; Table 3 averages the "
        "validation trials.</p>",
    ]
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
    for md in ("table3.md", "modes.md", "per_trial.md"):
        p = tables / md
        if p.exists():
            parts.append(_md_table_to_html(p.read_text()))
    model = results_dir / "model" / "sensing.json"
    if model.exists():
        d = json.loads(model.read_text())
        rep = d.get("fit_report", {}).get("hysteresis", {})
        coef = {k: v for k, v in d.get("coef", {}).items() if not isinstance(v, dict)}
        parts.append("<h2>Calibrated model</h2>")
        parts.append(
            f"<p>H(q): {html.escape(str(rep.get('h_model')))} calibrated on trial <code>{html.escape(str(rep.get('trial')))}</code> "
            f"({html.escape(d['config']['h_mode'])} mode), fit error RMS {rep.get('rms_pct', float('nan')):.3f} % / "
            f"max {rep.get('max_pct', float('nan')):.3f} % of output range, solver {html.escape(str(rep.get('solver')))}.</p>")
        parts.append("<table><tr>" + "".join(f"<th>{html.escape(k)}</th>" for k in coef) + "</tr><tr>"
                     + "".join(f"<td>{v:.6g}</td>" for v in coef.values()) + "</tr></table>")
    figs = results_dir / "figures"
    caps_path = figs / "captions.json"
    if caps_path.exists():
        caps = json.loads(caps_path.read_text())
        parts.append("<h2>Figures</h2>")
        for stem in sorted(caps):
            png = figs / f"{stem}.png"
            if not png.exists():
                continue
            b64 = base64.b64encode(png.read_bytes()).decode("ascii")
            parts.append(f"<figure><img alt='{html.escape(stem)}' src='data:image/png;base64,{b64}'>"
                         f"<figcaption><b>{html.escape(stem)}</b>: {html.escape(caps[stem])}</figcaption></figure>")
    gap = results_dir / "gap"
    if gap.exists():
        parts.append("<h2>Sim-to-real gap diagnostic</h2>")
        v = gap / "verdict.json"
        if v.exists():
            txt = v.read_text()
            try:
                vd = json.loads(txt)
            except json.JSONDecodeError:
                vd = {}
            if vd:
                eb, ea = vd.get("score_before"), vd.get("score_after_all")
                items = [f"<li><b>Verdict</b>: {html.escape(str(vd.get('message', '')))}</li>"]
                if isinstance(eb, (int, float)) and isinstance(ea, (int, float)):
                    items.append(f"<li><b>Held-out error</b> (mean of displacement and force, % of range): "
                                 f"{eb:.2f} before, {ea:.2f} after the confirmed effects (refit on calibration "
                                 f"trials)</li>")
                items.append(f"<li><b>Unexplained structure</b>: {'yes' if vd.get('unexplained') else 'no'}</li>")
                if vd.get("protocol_proposal"):
                    items.append("<li><b>Next acquisition</b>: <pre>" + html.escape(vd["protocol_proposal"])
                                 + "</pre></li>")
                parts.append("<ul>" + "".join(items) + "</ul>")
            parts.append(f"<details><summary>verdict.json</summary><pre>{html.escape(txt)}</pre></details>")
        for md in sorted(gap.glob("*.md")):
            parts.append(_md_table_to_html(md.read_text()))
        for png in sorted(gap.glob("*.png")):
            b64 = base64.b64encode(png.read_bytes()).decode("ascii")
            parts.append(f"<figure><img alt='{html.escape(png.stem)}' src='data:image/png;base64,{b64}'>"
                         f"<figcaption>{html.escape(png.stem)}</figcaption></figure>")
    parts.append("</body></html>\n")
    return "\n".join(parts)
