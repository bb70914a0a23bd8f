"""Blind-check datasets on the device families (docs/gap.mdcross devices).

A case is a virtual device drawn from one of the truth families of :mod:`selfsense.sim.families` (Preisach,
saturating Bouc-Wen, generalised PI, Jiles-Atherton: none of them a form the diagnostic fits), driven by the
diagnostic protocol of :func:`selfsense.gap.benchmark._device_scenario` (free-tip sine, blocked-tip sine, free-tip
mixed with holds, the step protocol with 0 V and high-V holds; validation on objects, blocked tip and a
rest-then-repeat), with a set of physical effects of :mod:`selfsense.sim.effects` injected at magnitudes
relative to :data:`selfsense.gap.benchmark.SIM_EFFECTS`. The device's own drawn preload is removed: here preload
is an injected effect like the others, so an effect-free case is effect-free.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pandas as pd

__all__ = ["FAMILIES", "device_base", "simulate_family_case"]

FAMILIES = ("preisach", "bouc_wen", "gpi", "jiles_atherton")


@lru_cache(maxsize=8)
def device_base(family: str, device_seed: int) -> tuple:
    """(device overrides, free stroke [m], drive amplitude [V]) of a drawn device (cached: drawing measures the
    free stroke and the peak current by simulation)."""
    from selfsense.sim.families import draw_device

    sc = draw_device(family, int(device_seed), "clean")
    dev = dict(sc["device"])
    amp = float(sc["trials"][0]["amplitude"])
    return tuple(sorted(dev.items(), key=lambda kv: kv[0])), float(dev["tip_free_displacement_m"]), amp


def _protocol(T: float, fs: float, drive_seed: int, stroke: float, amp: float) -> list[dict]:
    from .benchmark import _device_scenario

    trials = _device_scenario(T, fs, drive_seed)
    rng = np.random.default_rng([int(drive_seed), 4242])
    s_amp = stroke * amp / 150.0
    opening = stroke + 1.0e-3
    # objects sized to the device: touched at 30-45 % (displacement) and 55-70 % (force) of the driven stroke
    obj_d = round((opening - rng.uniform(0.30, 0.45) * s_amp) * 1e3, 3)
    obj_f = round((opening - rng.uniform(0.55, 0.70) * s_amp) * 1e3, 3)
    for tr in trials:
        tr["amplitude"] = float(tr["amplitude"]) * amp / 150.0
        if tr.get("tip") == "object":
            tr["object_mm"] = obj_d if tr["reference"] == "displacement" else obj_f
    return trials


def simulate_family_case(family: str, device_seed: int, effects: dict, noise_seed: int, T: float = 10.0,
                         fs: float = 400.0, drive_seed: int | None = None, with_truth: bool = False):
    """In-memory dataset ``(trials, meta, rig[, truth])`` of one family device with ``effects`` (library names,
    relative magnitudes), converted through ``selfsense.io.to_si`` and ``selfsense.signals.prepare_trial`` exactly
    like a disk dataset. ``noise_seed`` sets the sensor noise; ``drive_seed`` (default ``device_seed``) the
    protocol."""
    from selfsense.io import to_si
    from selfsense.signals import prepare_trial
    from selfsense.sim import load_device, rig_dict, simulate_scenario_in_memory

    from .benchmark import _LIB2SIM, SIM_EFFECTS, SUBSTEPS, _ns

    dev_items, stroke, amp = device_base(family, int(device_seed))
    dev = dict(dev_items)
    sim_eff = {}
    for name, mag in effects.items():
        sname = _LIB2SIM[name]
        sim_eff[sname] = float(mag) * SIM_EFFECTS[sname][1]
    spec = _protocol(T, fs, int(device_seed if drive_seed is None else drive_seed), stroke, amp)
    sc = {"name": f"gap_{family}_{device_seed}", "seed": int(noise_seed), "sample_rate_hz": fs, "substeps": SUBSTEPS,
          "device": dev, "effects_defaults": False, "effects": sim_eff, "trials": spec}
    res = simulate_scenario_in_memory(sc, int(noise_seed))
    rig = _ns(rig_dict(sc["name"], load_device(overrides=dev), fs))
    trials, rows, truth = {}, [], {}
    for s in spec:
        log, truth[s["trial"]] = res[s["trial"]]
        trials[s["trial"]] = prepare_trial(to_si(log, rig, s["reference"]), rig)
        rows.append({"trial": s["trial"], "file": s["trial"] + ".parquet", "role": s["role"], "tip": s["tip"],
                     "object_mm": s.get("object_mm", np.nan), "reference": s["reference"],
                     "signal": s.get("signal", "steps")})
    meta = pd.DataFrame(rows).set_index("trial")
    return (trials, meta, rig, truth) if with_truth else (trials, meta, rig)
