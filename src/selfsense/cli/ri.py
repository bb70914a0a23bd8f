"""``selfsense ri ...``: RI vs modified-PI comparisons (seed ``002_7d89b7147aad52e4.txt``).

Subcommands
-----------
compare-slac [--data DIR] [--out FILE.md] [--no-precondition]
    SLAC LCLS-II quadrupole (the external data folder's slac_quadrupole/, see ``SELFSENSE_EXTERNAL_DATA``): MAIN current [A] -> integrated gradient BL [T].
    Train on strdat.ru3 (major loop), test on strdat.ru4 (minor loops), and the reverse.
validate-table [--out FILE.md] [--seed N]
    Table in the style of the RI paper's Table 2 on the virtual single stack of ``ri_dynamics``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from selfsense.hysteresis.ri_identify import markdown_table
from selfsense.hysteresis.slac import SLAC_SMOOTH, slac_comparison

__all__ = ["main"]


def _cmd_compare_slac(argv) -> int:
    ap = argparse.ArgumentParser(prog="selfsense ri compare-slac", allow_abbrev=False,
                                 description="RI vs modified-PI model on the SLAC quadrupole magnet data")
    ap.add_argument("--data", default=None, help="folder with strdat.ru3/strdat.ru4 (default: $SELFSENSE_EXTERNAL_DATA/slac_quadrupole)")
    ap.add_argument("--out", default=None, help="also write the Markdown table to this file")
    ap.add_argument("--smooth", type=float, default=SLAC_SMOOTH, help="RI regularisation weight (0 = plain LS)")
    ap.add_argument("--no-precondition", action="store_true",
                    help="treat each run as starting from the virgin state (default: after a 0-165-0 A cycle)")
    a = ap.parse_args(argv)
    try:
        rows = slac_comparison(a.data, precondition=not a.no_precondition, smooth=a.smooth)
    except FileNotFoundError as exc:
        print(f"selfsense ri compare-slac: data not found: {exc}", file=sys.stderr)
        return 1
    md = ("SLAC LCLS-II quadrupole, MAIN current [A] -> BL [T]; errors in % of the output range "
          f"({'preconditioned 0-165-0 A' if not a.no_precondition else 'virgin start'}, RI smooth={a.smooth:g}).\n\n"
          + markdown_table(rows, ["split", "model", "train_rms", "train_max", "test_rms", "test_max", "note"],
                           ["split", "model", "train RMS %", "train max %", "test RMS %", "test max %", "note"]))
    print(md)
    if a.out:
        Path(a.out).write_text(md + "\n")
    return 0


def _cmd_validate_table(argv) -> int:
    from selfsense.hysteresis.ri_dynamics import validation_table

    ap = argparse.ArgumentParser(prog="selfsense ri validate-table", allow_abbrev=False,
                                 description="validation table of the RI model with vibration and creep sub-models")
    ap.add_argument("--out", default=None, help="also write the Markdown table to this file")
    ap.add_argument("--seed", type=int, default=0, help="seed of the synthetic test signals (default 0)")
    a = ap.parse_args(argv)
    rows, info = validation_table(seed=a.seed)
    md = (info + "\n\n" + markdown_table(
        rows, ["freq_hz", "rms_um", "max_um", "rms_pct", "max_pct", "line_rms_pct"],
        ["1/T_v (Hz)", "RMS error (um)", "max error (um)", "RMS % of range", "max % of range",
         "straight line RMS %"]))
    print(md)
    if a.out:
        Path(a.out).write_text(md + "\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    cmds = {"compare-slac": _cmd_compare_slac, "validate-table": _cmd_validate_table}
    if not argv or argv[0] not in cmds:
        print(__doc__)
        return 0 if argv and argv[0] in {"-h", "--help"} else 2
    return cmds[argv[0]](argv[1:])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
