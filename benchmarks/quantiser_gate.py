"""The quantiser member of the charge link (docs/method.md 1b') on whole-device benchmark devices: the current it
identifies against the simulator's true current, whether the gate adopts it, and Table 3 with it and without it.

    python benchmarks/quantiser_gate.py --seeds 10-14 --jobs 2 --out benchmarks/cross_device/whole_device/quantiser_gate_fresh10
    python benchmarks/quantiser_gate.py --seeds 0-14 --link-only --jobs 2 --out benchmarks/cross_device/whole_device/quantiser_laser_seeds0

Per device of the whole-device benchmark on the thesis protocol (``selfsense devices bench --protocol thesis
--randomise device``: the same draws, drives and noise) this script

1. runs the estimator's voltage and quantiser links alone (``calibration: quantiser: auto``) and records whether the
   shunt channel is undithered, the searched current ``i_q`` and its bound (half an ADC step over R), the blocked-CV
   errors with and without it and the decision; beside them the simulator's true current (an oracle: the in-amp
   offset the simulator adds against the mean the relay short reads, over R; the estimator never reads it);
2. for every device where the member is adopted, scores the whole pipeline twice (``selfsense devices run`` with
   ``quantiser: auto`` and with ``quantiser: off``; a device where it is not adopted is fitted bit for bit as with it
   off, so it is not scored twice).

``--link-only`` stops after step 1. Records: ``link.jsonl`` and ``records/{auto,off}/<family>_<preset>_<seed>.json``
(resumable: existing records are kept); the summary is ``quantiser_gate.md``. Scoring a set of seeds never used while the gate was built is its first
contact.
"""
from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from _args import int_ranges  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

FAMILIES = ("bouc_wen", "gpi", "jiles_atherton", "preisach", "rate_kp")
PRESETS = ("clean", "drift")



def _link(args) -> dict:
    """The voltage and quantiser links of one device (no H(q) selection), with the simulator's true current."""
    family, preset, seed = args
    from selfsense.devices import device_scenario, simulate_device
    from selfsense.sensing import SelfSensingEstimator, SensingConfig

    sc = device_scenario(family, preset, seed, "thesis", "device")
    trials, meta, rig, _ = simulate_device(sc)
    est = SelfSensingEstimator(config=SensingConfig(quantiser="auto"), rig=rig)
    est._quantiser_link(est._voltage_link(trials, meta), meta)
    qz = dict(est.quantiser_)
    rec = {"family": family, "preset": preset, "seed": int(seed), "applied": bool(qz.get("applied", False)),
           "assessed": "i_q_a" in qz, "note": str(qz.get("note", ""))}
    if "i_q_a" in qz:
        # the simulator's true current: the in-amp's offset (a device constant of the simulator) against the mean the
        # relay short reads, over R, with the member's sign (the charge error on the samples off the short's code)
        from selfsense.signals import relay_offset
        from selfsense.sim.device import load_device

        dev = load_device(overrides=sc["device"])
        cal_id = next(t for t in meta.index if meta.loc[t, "role"] == "calibration")
        df = trials[cal_id]
        short = relay_offset(df["V_s"].to_numpy(dtype=float), (df["relay"].to_numpy() >= 0.5).astype(float))
        R = float(rig.shunt_resistance_ohm)
        true_i = -(short - dev.inamp_offset_v / float(rig.inamp_gain)) / R
        rec.update({"i_q_na": qz["i_q_a"] * 1e9, "bound_na": 0.5 * qz["current_step_a"] * 1e9,
                    "true_i_q_na": true_i * 1e9, "cv_ratio": qz["cv_rms_m_with"] / qz["cv_rms_m_without"],
                    "fold_spread_of_bound": qz["fold_spread_a"] / (0.5 * qz["current_step_a"]),
                    "at_bound": bool(qz.get("at_bound")), "supported": bool(qz.get("supported"))})
    return rec


def _score(args) -> str:
    family, preset, seed, mode, path = args
    from selfsense.devices import run_device, write_record

    rec = run_device(family, preset, seed, {"calibration": {"quantiser": mode}, "estimation": {}}, protocol="thesis",
                     randomise="device")
    write_record(rec, path)
    return str(path)


def _summary(links: list[dict], scored: dict) -> str:
    lines = ["# The quantiser member on whole-device devices (thesis protocol)", "",
             f"Generated {datetime.now(timezone.utc).strftime('%Y-%m-%d')} by `python benchmarks/quantiser_gate.py "
             f"{' '.join(sys.argv[1:])}`.", ""]
    undith = [r for r in links if r["assessed"]]
    lines += [f"{len(links)} devices; the shunt channel is undithered on {len(undith)} (the member is assessed there); "
              f"adopted on {sum(r['applied'] for r in links)}; the current reaches its bound on "
              f"{sum(r.get('at_bound', False) for r in undith)}.", ""]
    for preset in sorted({r["preset"] for r in undith}):
        u = [r for r in undith if r["preset"] == preset]
        err = np.array([abs(r["i_q_na"] - r["true_i_q_na"]) / r["bound_na"] for r in u])
        closer = sum(abs(r["i_q_na"] - r["true_i_q_na"]) < abs(r["true_i_q_na"]) for r in u)
        lines.append(f"- {preset}: |identified - true| / bound median {np.median(err):.3f}, 90th percentile "
                     f"{np.quantile(err, 0.9):.3f}, largest {np.max(err):.3f}; nearer the true current than 0 on "
                     f"{closer} of {len(u)}; adopted on {sum(r['applied'] for r in u)}")
    lines += ["", "| device | i_q / bound | true i_q / bound (oracle) | blocked-CV ratio | fold spread / bound | "
              "at bound | adopted | displacement % off -> auto | force % off -> auto |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(undith, key=lambda r: (r["family"], r["preset"], r["seed"])):
        key = f"{r['family']}_{r['preset']}_{r['seed']}"
        d = f = ""
        if key in scored:
            off, on = scored[key]
            d = f"{off['displacement_pct']:.2f} -> {on['displacement_pct']:.2f}"
            f = f"{off['force_pct']:.2f} -> {on['force_pct']:.2f}"
        lines.append(f"| {r['family']} {r['preset']} {r['seed']} | {r['i_q_na'] / r['bound_na']:+.2f} | "
                     f"{r['true_i_q_na'] / r['bound_na']:+.2f} | {r['cv_ratio']:.3f} | "
                     f"{r.get('fold_spread_of_bound', float('nan')):.3f} | "
                     f"{'yes' if r['at_bound'] else 'no'} | {'yes' if r['applied'] else 'no'} | {d} | {f} |")
    if scored:
        lines += ["", "On the devices where it is adopted (Table 3, % of range; better / worse: by more than 10 %):", "",
                  "| quantity | median off | median auto | better | worse |", "|---|---|---|---|---|"]
        for m in ("displacement", "force"):
            a = np.array([scored[k][0][f"{m}_pct"] for k in sorted(scored)], float)
            b = np.array([scored[k][1][f"{m}_pct"] for k in sorted(scored)], float)
            lines.append(f"| {m} | {np.median(a):.2f} | {np.median(b):.2f} | {int(np.sum(b < 0.9 * a))} | "
                         f"{int(np.sum(b > 1.1 * a))} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="10-14", help="device seeds, e.g. 10-14 or 0,3,7")
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", required=True)
    ap.add_argument("--link-only", action="store_true", help="the links alone (identification and gate), no Table 3")
    a = ap.parse_args(argv)
    from selfsense.determinism import single_thread_blas

    single_thread_blas()   # one BLAS thread per process and its workers, as the selfsense command runs
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    devices = [(f, p, s) for f in a.families.split(",") for p in a.presets.split(",") for s in int_ranges(a.seeds)]
    link_path = out / "link.jsonl"
    done = {}
    if link_path.exists():
        for line in link_path.read_text().splitlines():
            r = json.loads(line)
            done[(r["family"], r["preset"], r["seed"])] = r
    todo = [d for d in devices if d not in done]
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        for rec in pool.map(_link, todo):
            done[(rec["family"], rec["preset"], rec["seed"])] = rec
            with link_path.open("a") as fh:
                fh.write(json.dumps(rec, sort_keys=True) + "\n")
            print(f"{rec['family']} {rec['preset']} {rec['seed']}: {'adopted' if rec['applied'] else 'not adopted'}",
                  flush=True)
        links = [done[d] for d in devices]
        jobs = []
        for r in links:
            if not r["applied"] or a.link_only:
                continue
            for mode in ("auto", "off"):
                path = out / "records" / mode / f"{r['family']}_{r['preset']}_{r['seed']}.json"
                path.parent.mkdir(parents=True, exist_ok=True)
                if not path.exists():
                    jobs.append((r["family"], r["preset"], r["seed"], mode, path))
        for p in pool.map(_score, jobs):
            print(f"scored {p}", flush=True)
    scored = {}
    for r in links:
        key = f"{r['family']}_{r['preset']}_{r['seed']}"
        paths = [out / "records" / m / f"{key}.json" for m in ("off", "auto")]
        if all(p.exists() for p in paths):
            scored[key] = tuple(json.loads(p.read_text()) for p in paths)
    (out / "quantiser_gate.md").write_text(_summary(links, scored))
    print((out / "quantiser_gate.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
