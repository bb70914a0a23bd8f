#!/usr/bin/env python
"""The offset-drift member in a stream: Table 3 rows of the bundled sample's validation trials with the batch member
(fitted over the whole trial, the pipeline), the causal member of the stream (fitted on the rest segments seen so
far, ``SelfSensingStream(drift="causal")``) and no drift compensation.

    python benchmarks/causal_drift.py [--dataset data/raw/sample] [--force]

``--force``: the member forced on (``members={"offset_drift": "on"}``) where the default model does not adopt it.

Prints a Markdown table (mean |estimate - reference| in % of the trial's reference range).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default=str(ROOT / "data" / "raw" / "sample"))
    ap.add_argument("--force", action="store_true", help="force the offset-drift member on")
    a = ap.parse_args(argv)
    from selfsense import io as sio
    from selfsense import stages
    from selfsense.sensing import SelfSensingEstimator, SensingConfig
    from selfsense.sensing.streaming import SelfSensingStream

    d = Path(a.dataset)
    meta = sio.load_trials(d).set_index("trial")
    with tempfile.TemporaryDirectory() as td:
        sigs = {t: stages.ingest(d, t, Path(td) / f"{t}.parquet") for t in meta.index}
        est = SelfSensingEstimator(config=SensingConfig(), rig=sio.load_rig(d),
                                   members={"offset_drift": "on"} if a.force else {}).fit(sigs, meta)
        if not est.offset_drift_:
            print(f"{d}: the default model does not adopt the offset-drift member here; nothing to compare "
                  "(--force forces it on)")
            return 0
        none = SelfSensingEstimator.from_dict(est.to_dict(), est.rig)
        none.offset_drift_ = False
        print("| validation trial | batch member | causal member (stream) | no drift compensation |")
        print("|---|---|---|---|")
        for t in meta.index[meta["role"] == "validation"]:
            col = "dx" if meta.loc[t, "reference"] == "displacement" else "f"
            ref = sigs[t][f"{col}_ref"].to_numpy()
            ok = np.isfinite(ref)

            def err(x):
                return float(np.mean(np.abs(x[ok] - ref[ok])) / np.ptp(ref[ok]) * 100)

            raw = sio.read_log(d / meta.loc[t, "file"])
            s = SelfSensingStream(est, drift="causal")
            dx, f = s.process(raw["u_cmd"], raw["v_shunt"], raw["relay"], t=raw["t"])
            causal = dx if col == "dx" else f
            print(f"| {t} ({'displacement' if col == 'dx' else 'force'}, % of range) | "
                  f"{err(est.estimate(sigs[t])[f'{col}_hat'].to_numpy()):.2f} | {err(causal):.2f} | "
                  f"{err(none.estimate(sigs[t])[f'{col}_hat'].to_numpy()):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
