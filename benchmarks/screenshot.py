#!/usr/bin/env python
"""The report screenshot of the docs, from a pipeline run of the bundled dataset, with the Table 3 it shows.

    selfsense run --cores 2 && python benchmarks/screenshot.py [--results results/tweezer_sim]

Writes ``docs/img/report_tweezer_sim_top.png`` (headless Chromium, the top of ``report.html``) and
``docs/img/report_tweezer_sim_top.json`` (the Table 3 of that report). ``benchmarks/figures.py --check`` compares the
latter with the Table 3 of ``benchmarks/RESULTS.json``, so a screenshot of an earlier default fails the tests.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def table3(md: Path) -> dict:
    rows = {}
    for line in md.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] in ("displacement", "force"):
            rows[cells[0]] = cells[2]
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=ROOT / "results" / "tweezer_sim")
    a = ap.parse_args(argv)
    from selfsense.report.browser import screenshot

    png = ROOT / "docs" / "img" / "report_tweezer_sim_top.png"
    screenshot(a.results / "report.html", png, width=1200, height=1600)
    t3 = table3(a.results / "tables" / "table3.md")
    png.with_suffix(".json").write_text(json.dumps({"table3_percent_of_range": t3}, indent=1, sort_keys=True) + "\n")
    print(f"wrote {png.relative_to(ROOT)} and its .json (Table 3: {t3})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
