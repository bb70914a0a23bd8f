"""``selfsense export-c``: a fitted model as dependency-free C99 for a controller (:mod:`selfsense.sensing.export_c`).

    selfsense export-c results/<d>/model/sensing.json --dataset data/raw/<d> --out DIR [--dt SECONDS] [--name NAME]

writes ``DIR/NAME.h`` and ``DIR/NAME.c`` (default name ``selfsense_estimator``): ``ss_init`` and
``ss_step(u_cmd, v_shunt, relay) -> (dx, f)`` at the fixed sample period ``--dt`` (default: the calibration's).
docs/realtime.md has a control-loop example and the measured cost per sample.
"""
from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="selfsense export-c", allow_abbrev=False,
                                 description="write a fitted model as dependency-free C99 (one .c, one .h): a state "
                                             "struct, ss_init, ss_step(u_cmd, v_shunt, relay) -> (dx, f)")
    ap.add_argument("model", help="fitted estimator JSON (results/<d>/model/sensing.json)")
    ap.add_argument("--dataset", required=True, help="dataset directory holding rig.yaml (data/raw/<d>)")
    ap.add_argument("--out", required=True, help="output folder (created)")
    ap.add_argument("--dt", type=float, default=None,
                    help="sample period of the controller [s] (default: the model's calibration sample time)")
    ap.add_argument("--name", default="selfsense_estimator", help="file and guard name (a C identifier)")
    a = ap.parse_args(argv)
    from selfsense.sensing.export_c import export_c

    h, c = export_c(a.model, a.dataset, a.out, dt=a.dt, name=a.name)
    print(f"wrote {h} and {c}", file=sys.stderr)
    return 0
