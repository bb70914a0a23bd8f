"""Scenario -> trials -> DAQ logs (+ truth): the public API of the virtual tweezer.

Scenario (dict or YAML)::

    name: tweezer_sim                # dataset name (rig.yaml `dataset`)
    seed: 1                          # default seed (the API/CLI seed argument wins)
    sample_rate_hz: 1000.0
    substeps: 10                     # internal sub-steps per sample (10 -> 10 kHz)
    device: {field: value}           # overrides of device_default.yaml
    effects_defaults: true           # start from the default effect magnitudes (else all 0)
    effects: {name: magnitude}       # see selfsense.sim.effects.EFFECTS
    trials:
      - {trial: cal_free, role: calibration, tip: free, object_mm: null, reference: displacement,
         signal: sine, duration: 16, amplitude: 150, freq: 0.5, relay_s: 0.75, rest_before_s: 60}

Noise and drift come from ``numpy.random.default_rng(SeedSequence([seed, trial_index]))`` with a
fixed draw order independent of the effects, so counterfactual runs share the noise exactly.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from .device import DeviceParams, load_device
from .drive import waveform
from .effects import EFFECTS, resolve_effects
from .kernel import NOUT, OUTS, PI, PNAMES, run_kernel
from .truth import NPAR, family_code

__all__ = ["simulate_trial", "simulate_scenario_in_memory", "simulate_dataset", "load_scenario",
           "rig_dict", "trial_params", "LOG_COLUMNS", "TRUTH_COLUMNS"]

LOG_COLUMNS = ("t", "u_cmd", "v_shunt", "laser", "load_cell", "relay")
TRUTH_COLUMNS = ("t", "q", "V", "V_p", "V_H", "x_pzt", "dx_tip", "f_tip")
TRIAL_KEYS = {"trial", "role", "tip", "object_mm", "reference", "signal", "duration", "amplitude", "freq",
              "relay_s", "rest_before_s", "levels", "hold_s", "ramp_s", "samples_v"}
SCENARIO_KEYS = {"name", "seed", "sample_rate_hz", "substeps", "device", "effects", "effects_defaults",
                 "trials", "description", "randomise", "rig_extra"}   # randomise: a record of what draw_device drew
#: optional rig.yaml keys a scenario may add to the rig it writes (``rig_extra``): what the user of the simulated rig
#: knows from data sheets. The blind gap campaigns write none (the amplifier's limit is an effect hidden there).
RIG_EXTRA_KEYS = {"amplifier_current_limit_a"}
MODE_F_REF = 50.0
SECOND_MODE_HZ = 173.0


def _version() -> str:
    try:
        from selfsense import __version__
        return __version__
    except Exception:  # pragma: no cover
        return "unknown"


def load_scenario(path_or_dict) -> dict:
    """Scenario dict from a YAML path, a preset name (``tweezer_sim`` / ``sample``) or a dict."""
    if isinstance(path_or_dict, dict):
        sc = dict(path_or_dict)
    else:
        p = Path(str(path_or_dict))
        if not p.exists() and not p.suffix:
            from importlib import resources
            text = resources.files("selfsense.sim").joinpath("presets", f"{p.name}.yaml").read_text()
        else:
            text = p.read_text()
        sc = yaml.safe_load(text)
    unknown = set(sc) - SCENARIO_KEYS
    if unknown:
        raise ValueError(f"scenario: unknown keys {sorted(unknown)}; allowed {sorted(SCENARIO_KEYS)}")
    bad_rig = set(sc.get("rig_extra") or {}) - RIG_EXTRA_KEYS
    if bad_rig:
        raise ValueError(f"scenario: rig_extra: unknown keys {sorted(bad_rig)}; allowed {sorted(RIG_EXTRA_KEYS)}")
    for i, tr in enumerate(sc.get("trials", [])):
        bad = set(tr) - TRIAL_KEYS
        if bad:
            raise ValueError(f"scenario trial {i}: unknown keys {sorted(bad)}")
        for k in ("trial", "role", "tip", "reference", "signal", "duration"):
            if k not in tr:
                raise ValueError(f"scenario trial {i}: missing key {k!r}")
        if tr["tip"] == "object" and tr.get("object_mm") is None:
            raise ValueError(f"scenario trial {tr['trial']}: tip=object needs object_mm")
    return sc


def _oc_tip_stiffness(dev: DeviceParams) -> float:
    """Open-circuit (constant charge) tip stiffness [N/m] of device + actuators."""
    (k11, k12), (_, k22) = dev.stiffness_matrix
    N, a, cp, k = dev.n_actuators, dev.alpha_n_per_v, dev.cp_f, dev.k_act_n_per_m
    A, Cn, Kn = N * a, N * cp, N * k
    D = Kn + k11
    den = A * A / D + Cn
    p1 = A * k12 / D / den
    x1 = (A * p1 - k12) / D
    return k12 * x1 + k22


def trial_params(dev: DeviceParams, eff: dict, trial: dict, sample_rate_hz: float, substeps: int):
    """Parameter vector for the kernel, the Preisach component array and the other families' parameters."""
    P = np.zeros(len(PNAMES))
    K = dev.stiffness_matrix
    s = {
        "dt_sample": 1.0 / sample_rate_hz, "n_sub": substeps, "N": dev.n_actuators,
        "alpha": dev.alpha_n_per_v, "cp": dev.cp_f, "k": dev.k_act_n_per_m,
        "tc_alpha": 2e-3, "tc_cp": 4e-3, "k11": K[0, 0], "k12": K[0, 1], "k22": K[1, 1],
        "q_ref": dev.q_ref_c, "h_lin": dev.h_lin_v,
        "R_s": dev.shunt_resistance_ohm, "R_relay": dev.relay_resistance_ohm,
        "amp_gain": dev.amplifier_gain, "amp_tau": 1.0 / (2 * math.pi * dev.amplifier_bandwidth_hz),
        "mc_t0": 0.9, "mc_t1": 6.5, "mc_t2": 41.0, "mc_w0": 0.3, "mc_w1": 0.3, "mc_w2": 0.4,
        "f_stress_ref": 0.1, "delta_ref": 20e-6, "sm_omega": 2 * math.pi * SECOND_MODE_HZ, "sm_zeta": 0.015,
        "demag_amp": dev.demag_amplitude, "demag_cycles": dev.demag_cycles,
        "h_family": family_code(dev.h_family), "h_sign": dev.h_sign,
    }
    for j in range(3):
        s[f"ec_c{j}"] = dev.ecreep_c_v[j]
        s[f"ec_t{j}"] = dev.ecreep_tau_s[j]
    s["mc_m"] = eff["creep"]
    s["g_leak"] = eff["leakage"] * 1e-9
    if eff["dielectric_absorption"] > 0:
        s["C_da"] = eff["dielectric_absorption"] * dev.n_actuators * dev.cp_f
        s["R_da"] = 3.7 / s["C_da"]
    else:
        s["C_da"], s["R_da"] = 0.0, 1.0
    if eff["mechanism_mode"] > 0:
        kk = _oc_tip_stiffness(dev)
        m = eff["mechanism_mode"] * kk / (2 * math.pi * MODE_F_REF) ** 2
        s["m_tip"] = m
        s["c_tip"] = 2 * 0.05 * math.sqrt(kk * m)
    if eff["amplifier_limits"] > 0:
        s["i_max"] = 1e-3 / eff["amplifier_limits"]
        s["slew"] = 1500.0 / eff["amplifier_limits"]
    s["dead_zone"] = eff["dead_zone"]
    s["stress_m"] = eff["stress_hysteresis"]
    s["hertz_m"] = min(eff["contact_nonlinearity"], 1.0)
    s["backlash_r"] = eff["backlash"] * 1e-6
    s["sm_m"] = min(eff["second_mode"], 1.0)
    s["preload_u"] = eff["preload"]
    tip = trial["tip"]
    if tip == "free":
        s["env_contact"] = 0.0
    elif tip == "blocked":
        s["env_contact"], s["gap"], s["k_env"] = 1.0, 0.0, dev.load_cell_stiffness_n_per_m
    elif tip == "object":
        s["env_contact"] = 1.0
        s["gap"] = dev.tip_opening_m - float(trial["object_mm"]) * 1e-3
        s["k_env"] = dev.object_stiffness_n_per_m
        if s["gap"] < 0:
            raise ValueError(f"object of {trial['object_mm']} mm larger than the tip opening")
    else:
        raise ValueError(f"unknown tip {tip!r} (free | blocked | object)")
    for k, v in s.items():
        P[PI[k]] = v
    comps = [list(c) for c in dev.preisach_components]
    if eff["virgin_curve"] > 0:
        c = list(dev.virgin_lobe)
        c[3] *= eff["virgin_curve"]
        comps.append(c)
    hp = np.zeros(NPAR)
    hp[:len(dev.h_params)] = dev.h_params
    return P, np.ascontiguousarray(comps, dtype=float), hp


def _quantize(v, dev: DeviceParams):
    lsb = dev.adc_lsb_v
    code = np.clip(np.round((v + dev.adc_range_v) / lsb), 0, 2 ** dev.adc_bits - 1)
    return code * lsb - dev.adc_range_v


def _drive(trial, dev, fs):
    n = int(round(float(trial["duration"]) * fs))
    t = np.arange(n) / fs
    relay_s = float(trial.get("relay_s", 0.75))
    relay = (t < relay_s).astype(np.float64)
    v = waveform(t, trial, start=relay_s + 0.25)
    v[relay > 0] = 0.0
    if not v.max() > 0.0:
        raise ValueError(f"trial {trial.get('trial')!r}: duration {trial['duration']} s too short for one "
                         f"{trial['signal']} cycle after the relay")
    u = _quantize(np.clip(v / dev.amplifier_gain, 0.0, 10.0), dev)
    return t, u, relay


def _run(dev, eff, trial, fs, substeps, t, u, relay, dT_unit):
    P, comps, hp = trial_params(dev, eff, trial, fs, substeps)
    out = np.zeros((NOUT, t.size))
    dT = eff["temperature"] * dT_unit
    run_kernel(u, relay, dT, P, comps, hp, out)
    return {k: out[i] for i, k in enumerate(OUTS)}


def simulate_trial(trial: dict, device: DeviceParams | None = None, effects: dict | None = None,
                   seed: int = 0, index: int = 0, sample_rate_hz: float = 1000.0, substeps: int = 10,
                   campaign_t0: float = 0.0, contributions: bool = False, effects_defaults: bool = True):
    """Simulate one trial in memory.

    Returns ``(log, truth)``: ``log`` has the DAQ columns of docs/data_format.md (``t, u_cmd, v_shunt,
    laser, load_cell, relay``; the channel of the other reference is NaN); ``truth`` has
    ``t, q, V, V_p, V_H, x_pzt, dx_tip, f_tip`` (SI; q = charge through the shunt since t = 0,
    zero while the relay shorts the leads) plus ``q_act, V_c, dx_ref`` and, if
    ``contributions``, ``effect__<name>`` (contribution to the trial's noise-free reference
    quantity: dx_ref [m] or f_tip [N]) and ``effect__<name>__q`` (to the measured charge [C]) for
    every active effect, by counterfactual re-simulation with that effect off (same noise).
    """
    dev = device or load_device()
    eff = resolve_effects(effects, use_defaults=effects_defaults)
    fs = float(sample_rate_hz)
    t, u, relay = _drive(trial, dev, fs)
    n = t.size
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))
    n_ia = rng.standard_normal(n)
    n_la = rng.standard_normal(n)
    n_lc = rng.standard_normal(n)
    n_rw = rng.standard_normal(n)
    rw_unit = np.cumsum(n_rw) * math.sqrt(1.0 / fs)           # Wiener process [sqrt(s)]
    dT_unit = 1.0 - np.exp(-(campaign_t0 + t) / 1500.0)

    def drift_of(e):
        m = e["offset_drift"] * 1e-6
        return m * t + 0.5 * m * rw_unit                        # input-referred [V]

    def ref_of(o):
        return 2.0 * o["arm"] if trial["reference"] == "displacement" else o["f_tip"]

    def qmeas_of(o, e):
        return o["q"] + np.cumsum(drift_of(e)) / fs / dev.shunt_resistance_ohm

    o = _run(dev, eff, trial, fs, substeps, t, u, relay, dT_unit)
    vs = o["i_s"] * dev.shunt_resistance_ohm
    v_shunt = dev.inamp_gain * (vs + drift_of(eff)) + dev.inamp_offset_v + dev.inamp_noise_v * n_ia
    laser = o["arm"] / dev.laser_m_per_v + dev.laser_noise_m / dev.laser_m_per_v * n_la
    load = o["f_tip"] / dev.load_cell_n_per_v + dev.load_cell_noise_n / dev.load_cell_n_per_v * n_lc
    log = {"t": t, "u_cmd": u, "v_shunt": _quantize(v_shunt, dev),
           "laser": _quantize(laser, dev), "load_cell": _quantize(load, dev), "relay": relay}
    if trial["reference"] == "displacement":
        log["load_cell"] = np.full(n, np.nan)
    elif trial["reference"] == "force":
        log["laser"] = np.full(n, np.nan)
    else:
        raise ValueError(f"unknown reference {trial['reference']!r}")
    truth = {"t": t, "q": o["q"], "V": o["V"], "V_p": o["V_p"], "V_H": o["V_H"], "x_pzt": o["x_pzt"],
             "dx_tip": o["dx_tip"], "f_tip": o["f_tip"], "q_act": o["q_act"], "V_c": o["V_c"],
             "dx_ref": 2.0 * o["arm"]}
    if contributions:
        base_ref, base_q = ref_of(o), qmeas_of(o, eff)
        for name in EFFECTS:
            if eff[name] <= 0:
                continue
            e0 = dict(eff)
            e0[name] = 0.0
            o0 = _run(dev, e0, trial, fs, substeps, t, u, relay, dT_unit)
            truth[f"effect__{name}"] = base_ref - ref_of(o0)
            truth[f"effect__{name}__q"] = base_q - qmeas_of(o0, e0)
    return pd.DataFrame(log), pd.DataFrame(truth)


def _scenario_parts(scenario, seed):
    sc = load_scenario(scenario)
    seed = int(sc.get("seed", 0) if seed is None else seed)
    dev = load_device(overrides=sc.get("device") or {})
    fs = float(sc.get("sample_rate_hz", 1000.0))
    sub = int(sc.get("substeps", 10))
    eff = resolve_effects(sc.get("effects") or {}, use_defaults=bool(sc.get("effects_defaults", True)))
    return sc, seed, dev, fs, sub, eff


def simulate_scenario_in_memory(scenario, seed: int | None = None, contributions: bool = False,
                                only=None, progress: bool | None = False) -> dict:
    """All trials of a scenario in memory: ``{trial: (log, truth)}`` (insertion order = scenario order).
    ``only``: optional collection of trial names to simulate (same results as in the full run:
    per-trial seeds and campaign times do not depend on which trials are simulated)."""
    sc, seed, dev, fs, sub, eff = _scenario_parts(scenario, seed)
    res = {}
    tc = 0.0
    from tqdm import tqdm

    # progress: None = a bar on a terminal only (quiet in non-interactive logs); False = never
    bar = tqdm(sc["trials"], desc=f"simulate {sc.get('name', '')}", unit="trial",
               disable=None if progress is None else not progress)
    for i, tr in enumerate(bar):
        tc += float(tr.get("rest_before_s", 60.0))
        if only is not None and tr["trial"] not in only:
            tc += float(tr["duration"])
            continue
        res[tr["trial"]] = simulate_trial(tr, dev, eff, seed=seed, index=i, sample_rate_hz=fs, substeps=sub,
                                          campaign_t0=tc, contributions=contributions, effects_defaults=False)
        tc += float(tr["duration"])
    return res


def rig_dict(name: str, dev: DeviceParams, fs: float) -> dict:
    """rig.yaml content (only the keys of docs/data_format.md)."""
    return {
        "dataset": name,
        "sample_rate_hz": float(fs),
        "shunt_resistance_ohm": float(dev.shunt_resistance_ohm),
        "amplifier_gain": float(dev.amplifier_gain),
        "inamp_gain": float(dev.inamp_gain),
        "n_actuators": int(dev.n_actuators),
        "reference": {"laser_m_per_v": float(dev.laser_m_per_v), "load_cell_n_per_v": float(dev.load_cell_n_per_v)},
        "actuator_catalog": {
            "free_displacement_m": float(dev.catalog_free_displacement_m),
            "blocked_force_n": float(dev.catalog_blocked_force_n),
            "stiffness_n_per_m": float(dev.catalog_stiffness_n_per_m),
            "capacitance_f": float(dev.catalog_capacitance_f),
            "max_voltage_v": float(dev.catalog_max_voltage_v),
        },
        "tip_free_displacement_m": float(dev.tip_free_displacement_m),
    }


def write_parquet(df: pd.DataFrame, path: Path, float32: bool = False):
    arrays, names = [], []
    for c in df.columns:
        x = df[c].to_numpy()
        if c == "relay":
            arrays.append(pa.array(x.astype(np.int8)))
        elif float32 and c != "t":
            arrays.append(pa.array(x.astype(np.float32)))
        else:
            arrays.append(pa.array(x.astype(np.float64)))
        names.append(c)
    table = pa.Table.from_arrays(arrays, names=names)
    pq.write_table(table, str(path), row_group_size=1 << 20, compression="zstd", compression_level=9,
                   use_dictionary=False, write_statistics=False, store_schema=False,
                   use_byte_stream_split=[n for n, a in zip(names, arrays) if pa.types.is_floating(a.type)])


def simulate_dataset(scenario, seed: int | None = None, out_dir=None, truth_dir=None, contributions: bool = True):
    """Write a dataset (docs/data_format.md: rig.yaml, trials.csv, <trial>.parquet) into ``out_dir`` and
    its truth (``<trial>.parquet`` with TRUTH_COLUMNS + effect columns, manifest.json) into
    ``truth_dir`` (default ``<out_dir>.truth``, beside, never inside).  Both folders are
    replaced atomically (written to a temporary sibling, then renamed)."""
    sc, seed, dev, fs, sub, eff = _scenario_parts(scenario, seed)
    out_dir = Path(out_dir)
    truth_dir = Path(truth_dir) if truth_dir is not None else out_dir.with_name(out_dir.name + ".truth")
    if truth_dir.resolve().is_relative_to(out_dir.resolve()):
        raise ValueError("truth_dir must not be inside the dataset folder")
    name = out_dir.name
    res = simulate_scenario_in_memory(sc, seed, contributions=contributions, progress=None)
    tmp_out = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=out_dir.parent if out_dir.parent.exists() else None))
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    truth_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp_truth = Path(tempfile.mkdtemp(prefix=f".{truth_dir.name}.", dir=truth_dir.parent))
    try:
        with open(tmp_out / "rig.yaml", "w") as fh:
            yaml.safe_dump({**rig_dict(name, dev, fs), **{k: float(v) for k, v in (sc.get("rig_extra") or {}).items()}},
                           fh, sort_keys=False)
        rows = []
        for tr in sc["trials"]:
            log, truth = res[tr["trial"]]
            fname = f"{tr['trial']}.parquet"
            write_parquet(log, tmp_out / fname)
            write_parquet(truth, tmp_truth / fname, float32=True)
            om = tr.get("object_mm")
            rows.append({"trial": tr["trial"], "file": fname, "role": tr["role"], "tip": tr["tip"],
                         "object_mm": "" if om is None else f"{float(om):g}", "reference": tr["reference"],
                         "signal": tr["signal"]})
        pd.DataFrame(rows, columns=["trial", "file", "role", "tip", "object_mm", "reference", "signal"]).to_csv(
            tmp_out / "trials.csv", index=False, lineterminator="\n")
        manifest = {
            "dataset": name, "seed": seed, "package_version": _version(),
            "sample_rate_hz": fs, "substeps": sub,
            "effects": {k: v for k, v in eff.items()},
            "active_effects": sorted(k for k, v in eff.items() if v > 0),
            "effect_info": {k: {"family": e.family, "unit": e.unit, "form": e.form} for k, e in EFFECTS.items()},
            "device": dev.to_dict(),
            "scenario": sc,
            "truth_columns": {
                "q": "charge through the shunt since t = 0 [C]", "V": "actuator voltage [V]",
                "V_p": "V - V_H [V]", "V_H": "true hysteretic voltage [V]", "x_pzt": "PZT stroke [m]",
                "dx_tip": "tip closing, both arms [m]", "f_tip": "pinching force [N]",
                "q_act": "actuator charge [C]", "V_c": "amplifier output [V]",
                "dx_ref": "2 x measured-arm displacement, noise-free [m]",
                "effect__<name>": "contribution to the trial's reference quantity (dx_ref [m] or f_tip [N])",
                "effect__<name>__q": "contribution to the measured shunt charge [C]",
            },
        }
        with open(tmp_truth / "manifest.json", "w") as fh:
            json.dump(manifest, fh, indent=2, sort_keys=True, default=float)
            fh.write("\n")
        for tmp, final in ((tmp_out, out_dir), (tmp_truth, truth_dir)):
            os.chmod(tmp, 0o755)
            if final.exists():
                shutil.rmtree(final)
            os.replace(tmp, final)
    finally:
        for tmp in (tmp_out, tmp_truth):
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
    return out_dir, truth_dir
