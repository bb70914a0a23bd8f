"""``selfsense devices``: the cross-device accuracy benchmark (:mod:`selfsense.devices`)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from selfsense.devices import PROTOCOLS, _config_from, bench, run_device, write_record, write_tables

__all__ = ["main"]


def _overrides(items) -> dict:
    """``["adc_bits=18", ...]`` -> ``{"adc_bits": 18}`` (numbers as int or float)."""
    out = {}
    for item in items:
        name, sep, value = str(item).partition("=")
        if not sep or not name:
            raise ValueError(f"--set: expected NAME=VALUE, found {item!r}")
        try:
            out[name] = int(value)
        except ValueError:
            try:
                out[name] = float(value)
            except ValueError:
                raise ValueError(f"--set {name}: expected a number, found {value!r}") from None
    return out


def _members(items) -> dict:
    """``["offset_drift=on", ...]`` -> ``{"offset_drift": "on"}`` (a chain member forced on or off; the names are
    checked by :func:`selfsense.sensing.estimator.member_modes`)."""
    from selfsense.sensing.estimator import member_modes

    out = {}
    for item in items:
        name, sep, mode = str(item).partition("=")
        if not sep or mode not in ("on", "off"):
            raise ValueError(f"--member: expected NAME=on or NAME=off, found {item!r}")
        out[name] = mode
    member_modes(out)
    return out


def main(argv=None) -> int:
    import argparse

    from selfsense.sim.families import FAMILIES, PRESETS, RANDOMISE

    ap = argparse.ArgumentParser(prog="selfsense devices", allow_abbrev=False,
                                 description="Cross-device accuracy benchmark: Table 3 on virtual devices of several "
                                             "truth hysteresis families (selfsense.sim.families).")
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="simulate and score one device (one Snakemake job)", allow_abbrev=False)
    r.add_argument("--family", required=True, choices=FAMILIES, help="truth hysteresis family")
    r.add_argument("--preset", default="clean", choices=PRESETS, help="clean, or drift (leakage + offset + creep)")
    r.add_argument("--seed", type=int, required=True, help="device seed (draws its constants)")
    r.add_argument("--configfile", default=None, help="pipeline config whose calibration/estimation blocks to use")
    r.add_argument("--protocol", default="three_trial", choices=PROTOCOLS,
                   help="calibration trials: thesis (free-tip and blocked sines only) or three_trial (default)")
    r.add_argument("--randomise", default="hysteresis", choices=RANDOMISE,
                   help="hysteresis: the family and the device constants (default); device: also the rig, amplifier, "
                        "dielectric relaxation and drive holds (docs/simulator.md)")
    r.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="device quantity set after the draw, e.g. --set adc_bits=18; repeatable")
    r.add_argument("--member", action="append", default=[], metavar="NAME=on|off",
                   help="a chain member of the estimator forced on or off, e.g. --member offset_drift=on; repeatable")
    r.add_argument("--without", action="append", default=[], metavar="EFFECT",
                   help="an effect of the draw removed (the effect-free twin: the same device, drives and noise), e.g. "
                        "--without offset_drift; repeatable")
    r.add_argument("--out", required=True, help="record file (JSON) to write")
    t = sub.add_parser("table", help="aggregate record files into the cross-device table", allow_abbrev=False)
    t.add_argument("records", nargs="+", help="record JSON files")
    t.add_argument("--out", required=True, help="folder for cross_device.md / .csv and records.csv")
    b = sub.add_parser("bench", help="run many devices in parallel and aggregate (resumable)", allow_abbrev=False)
    b.add_argument("--n", type=int, default=10, help="devices per family and preset (default 10)")
    b.add_argument("--families", default=",".join(FAMILIES), help="comma-separated families (default all)")
    b.add_argument("--presets", default=",".join(PRESETS), help="comma-separated presets (default all)")
    b.add_argument("--jobs", type=int, default=2, help="parallel processes (default 2)")
    b.add_argument("--first-seed", type=int, default=0, help="first device seed (default 0)")
    b.add_argument("--configfile", default=None, help="pipeline config whose calibration/estimation blocks to use")
    b.add_argument("--protocol", default="three_trial", choices=PROTOCOLS,
                   help="calibration trials: thesis (free-tip and blocked sines only, as the thesis) or three_trial "
                        "(plus a free-tip mixed drive; default)")
    b.add_argument("--randomise", default="hysteresis", choices=RANDOMISE,
                   help="hysteresis: the family and the device constants (default); device: also the rig, amplifier, "
                        "dielectric relaxation and drive holds (docs/simulator.md)")
    b.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="device quantity set after the draw, e.g. --set adc_bits=18 (the same devices, drives and "
                        "noise with a finer ADC); repeatable")
    b.add_argument("--member", action="append", default=[], metavar="NAME=on|off",
                   help="a chain member of the estimator forced on or off on every device, e.g. --member "
                        "offset_drift=on; repeatable")
    b.add_argument("--without", action="append", default=[], metavar="EFFECT",
                   help="an effect removed from every device's draw (effect-free twins: each effect's cost is the "
                        "run's Table 3 against one without the option), e.g. --without offset_drift; repeatable")
    b.add_argument("--out", required=True, help="output folder (records/ and the tables)")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "run":
            rec = run_device(a.family, a.preset, a.seed, _config_from(a.configfile), a.protocol, a.randomise,
                             _overrides(a.set), _members(a.member), a.without)
            write_record(rec, a.out)
            print(f"{a.family} {a.preset} {a.seed}: displacement {rec['displacement_pct']:.2f} %, "
                  f"force {rec['force_pct']:.2f} % ({rec['status']})")
        elif a.cmd == "table":
            recs = [json.loads(Path(p).read_text()) for p in a.records]
            write_tables(recs, a.out)
            print(Path(a.out) / "cross_device.md")
        else:
            fams = [f for f in a.families.split(",") if f]
            pres = [p for p in a.presets.split(",") if p]
            for f in fams:
                if f not in FAMILIES:
                    raise ValueError(f"--families: unknown family {f!r}; expected some of {', '.join(FAMILIES)}")
            for p in pres:
                if p not in PRESETS:
                    raise ValueError(f"--presets: unknown preset {p!r}; expected some of {', '.join(PRESETS)}")
            bench(a.n, fams, pres, a.jobs, a.out, _config_from(a.configfile), a.first_seed, protocol=a.protocol,
                  randomise=a.randomise, device_overrides=_overrides(a.set), members=_members(a.member),
                  without=a.without)
            print(Path(a.out) / "cross_device.md")
    except (ValueError, OSError) as exc:
        print(f"selfsense devices: error: {exc}", file=sys.stderr)
        return 2
    return 0
