#!/usr/bin/env python
"""Why the rate-dependent KP family (``rate_kp``) scores as it does at first contact: two measurements.

    python benchmarks/rate_kp_cause.py --out benchmarks/cross_device/first_contact_rate_kp/cause.md

1. *Rate term off*: the same 10 devices (seeds 0-9, clean preset, thesis protocol) with the loop widening per decade
   of rate set to 0 (every other draw the same), scored by ``selfsense.devices.run_device`` as the benchmark does.
2. *Finer grids*: on devices 0, 2 and 3 (clean, thesis protocol), the default selection against the straight line
   plus one finer Preisach grid (32 cells + 10 plays, 48 cells + 10 plays): blocked-CV H error and Table 3.

Neither changes the project: the finer grids are measured with ``SelfSensingEstimator(h_candidates=...)``.
"""
from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

GRIDS = {"default selection": (),
         "line + preisach(n_grid=32, n_play=10, ridge=1e-5)": (("linear", {}), ("preisach", {"n_grid": 32, "n_play": 10, "ridge": 1e-5})),
         "line + preisach(n_grid=48, n_play=10, ridge=1e-5)": (("linear", {}), ("preisach", {"n_grid": 48, "n_play": 10, "ridge": 1e-5}))}


def _rate_off(seed: int) -> tuple:
    import selfsense.sim.families as fam
    from selfsense.devices import run_device

    orig = fam.draw_device

    def draw(family, s, preset="clean"):
        sc = orig(family, s, preset)
        sc["device"]["h_params"][4] = 0.0   # hp = [w, m, s1, s2, c, r0]: no widening with rate
        return sc

    fam.draw_device = draw
    try:
        r = run_device("rate_kp", "clean", seed, protocol="thesis")
    finally:
        fam.draw_device = orig
    return seed, r["displacement_pct"], r["force_pct"], r["h_fit_rms_v"]


def _grids(seed: int) -> list:
    from selfsense import io as sio
    from selfsense.report import tables
    from selfsense.sensing import SelfSensingEstimator, SensingConfig
    from selfsense.signals import prepare_trial
    from selfsense.sim.families import draw_device
    from selfsense.sim.simulate import simulate_dataset

    sc = draw_device("rate_kp", seed, "clean")
    sc["trials"] = [t for t in sc["trials"] if not (t["role"] == "calibration" and t.get("signal") == "mixed")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        ds = Path(tmp) / sc["name"]
        simulate_dataset(sc, out_dir=ds, truth_dir=Path(tmp) / "truth", contributions=False)
        rig = sio.load_rig(ds)
        meta = sio.load_trials(ds).set_index("trial")
        sigs = {t: prepare_trial(sio.trial_signals(ds, t, rig=rig), rig) for t in meta.index}
        for name, cands in GRIDS.items():
            t0 = time.perf_counter()
            est = SelfSensingEstimator(config=SensingConfig(), rig=rig, h_candidates=cands).fit(sigs, meta)
            sec = time.perf_counter() - t0
            ests = {}
            for t, s in sigs.items():
                e = est.estimate(s, trial=t)
                e["dx_ref"], e["f_ref"] = s["dx_ref"].to_numpy(), s["f_ref"].to_numpy()
                ests[t] = e
            t3 = tables.table3(tables.per_trial_table(ests, meta.reset_index())).set_index("measurement")
            h = est.fit_report_["hysteresis"]
            cv = next(r["cv_rms_mean_v"] for r in h["selection"] if r["selected"])
            rows.append((seed, name, h["selected"], cv, t3.loc["displacement", "percent_of_range"],
                         t3.loc["force", "percent_of_range"], sec))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args()
    with ProcessPoolExecutor(a.jobs) as ex:
        off = list(ex.map(_rate_off, range(10)))
        grids = [r for rows in ex.map(_grids, (0, 2, 3)) for r in rows]
    L = ["# rate_kp: what the first-contact error is made of", "",
         f"Command: `python benchmarks/rate_kp_cause.py --out {a.out}` ({time.strftime('%Y-%m-%d')})", "",
         "## 1. Rate term off (seeds 0-9, clean, thesis protocol)", "",
         "| seed | displacement % | force % | H fit RMS, V |", "|---|---|---|---|"]
    L += [f"| {s} | {d:.2f} | {f:.2f} | {h:.3f} |" for s, d, f, h in off]
    L += ["", f"Median: {np.median([r[1] for r in off]):.2f} % displacement, {np.median([r[2] for r in off]):.2f} % force.",
          "", "## 2. Finer Preisach grids (clean, thesis protocol)", "",
          "| seed | candidates | selected | blocked-CV H error, V | displacement % | force % | fit, s |",
          "|---|---|---|---|---|---|---|"]
    L += [f"| {s} | {n} | {sel} | {cv:.3f} | {d:.2f} | {f:.2f} | {sec:.1f} |" for s, n, sel, cv, d, f, sec in grids]
    Path(a.out).write_text("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
