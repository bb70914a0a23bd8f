"""``selfsense fit-external``: fit the H(q) model registry (selected by blocked CV) on one measured record and score it
out of sample on another, against a straight line and a 10-operator PI (:mod:`selfsense.hysteresis.external`)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from selfsense.hysteresis.external import (_parse_prehistory, _read_record, default_data_dir, fit_pair, run,
                                           to_markdown)

__all__ = ["main"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="selfsense fit-external", allow_abbrev=False,
                                 description="Fit the H(q) model registry (selected by blocked CV) on one measured "
                                             "record and score it out of sample on another, against a straight line "
                                             "and a 10-operator PI. Without --fit/--eval: every pair of the external "
                                             "data folder.")
    ap.add_argument("--out", type=Path, default=None, help="write the markdown table to this file")
    ap.add_argument("--data-dir", type=Path, default=None, help="external data folder (default: $SELFSENSE_EXTERNAL_DATA)")
    ap.add_argument("--fit", default=None, metavar="FILE:X:Y[:T]",
                    help="fit record: CSV/Parquet file and its input, output and optional time columns")
    ap.add_argument("--eval", default=None, metavar="FILE:X:Y[:T]",
                    help="evaluation record (same form); default: the second half of the fit record")
    ap.add_argument("--prehistory", default=None, metavar="X1,X2,...",
                    help="input values [input units] the device went through before each of the two records, e.g. a "
                         "standardisation cycle 0,165,0: every candidate starts from the state they leave")
    ap.add_argument("--quasi-static", action="store_true",
                    help="one sample per input step (a table of steps): no creep bank, stronger ridges")
    ap.add_argument("--solver", default="CLARABEL", help="cvxpy QP solver tried first by the modified PI candidate")
    args = ap.parse_args(argv)
    try:
        if args.fit:
            xf, yf, dtf = _read_record(args.fit)
            if args.eval:
                xe, ye, dte = _read_record(args.eval)
                mask = np.ones(len(xe), bool)
                label = f"{args.fit} -> {args.eval}"
            else:
                half = len(xf) // 2
                xe, ye, dte = xf, yf, dtf
                mask = np.zeros(len(xf), bool)
                mask[half:] = True
                xf, yf = xf[:half], yf[:half]
                label = f"{args.fit}: 1st half -> 2nd half"
            row = {"key": "user", "pair": label, "provenance_baseline": (float("nan"), float("nan"))}
            row.update(fit_pair(xf, yf, dtf, xe, ye, dte, mask, quasi_static=args.quasi_static, names=[args.fit],
                                prehistory=_parse_prehistory(args.prehistory)))
            rows = [row]
        else:
            data_dir = Path(args.data_dir) if args.data_dir is not None else default_data_dir()
            if not data_dir.is_dir():
                raise ValueError(f"external data folder {str(data_dir)!r} not found (give --data-dir, or --fit)")
            rows = run(data_dir, solver=args.solver)
    except (ValueError, OSError) as exc:
        print(f"selfsense fit-external: error: {exc}", file=sys.stderr)
        return 2
    md = ("Errors in % of the evaluation output range (RMS / max). The H model is chosen by blocked cross-validation on "
          "the fit record only (selfsense.hysteresis.external.select_external).\n\n" + to_markdown(rows))
    print(md)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(md)
        tmp.replace(args.out)
    worse = [r["pair"] for r in rows if not (r["h_selected"][0] < r["linear"][0]
                                              and r["h_selected"][0] < r["baseline_pi10"][0])]
    for w in worse:
        print(f"selfsense fit-external: the selected H does not beat the straight line and the PI-10 on {w}",
              file=sys.stderr)
    return 1 if worse else 0
