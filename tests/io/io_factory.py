"""A small valid synthetic dataset, written from scratch (no dependency on selfsense.sim).

Plausible signals: the amplifier drives n_A actuators (total capacitance C = n_A * C_p) through the shunt R,
so V_s = R * C * dV_c/dt, v_shunt = inamp_gain * V_s; the laser sees half the tip displacement
dx = tip_free * V / V_max; a blocked tip presses the load cell with f = 0.1 N * V / V_max.
"""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

RIG = {
    "dataset": "ds",
    "sample_rate_hz": 1000.0,
    "shunt_resistance_ohm": 1000.0,
    "amplifier_gain": 15.0,
    "inamp_gain": 10.0,
    "n_actuators": 5,
    "reference": {"laser_m_per_v": 2.0e-3, "load_cell_n_per_v": 0.1},
    "actuator_catalog": {"free_displacement_m": 10.0e-6, "blocked_force_n": 240.0,
                         "stiffness_n_per_m": 24.0e6, "capacitance_f": 0.25e-6, "max_voltage_v": 150.0},
    "tip_free_displacement_m": 6.3e-3,
}

#: trial, file, role, tip, object_mm, reference, signal
TRIALS = [
    ("free_sine", "free_sine.parquet", "calibration", "free", "", "displacement", "sine"),
    ("blocked_sine", "blocked_sine.csv", "calibration", "blocked", "", "force", "sine"),
    ("obj_mixed", "obj_mixed.parquet", "validation", "object", "2.5", "force", "mixed"),
    ("free_steps", "free_steps.csv", "validation", "free", "", "displacement", "steps"),
]


def make_log(tip: str, reference: str, signal: str, n: int = 1500, fs: float = 1000.0, seed: int = 0,
             amp_v: float = 8.0, freq_hz: float = 1.0, n_relay: int = 200, noise_v: float = 1e-3,
             rig: dict | None = None) -> pd.DataFrame:
    rig = rig or RIG
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    tt = np.clip(t - n_relay / fs, 0.0, None)
    if signal == "steps":
        u = amp_v * (np.floor(tt * freq_hz) % 2 == 0) * (tt > 0.1)
        k = int(0.3 * fs)
        u = np.convolve(u, np.ones(k) / k, mode="full")[:n]  # slow ramps (limited slew rate)
    elif signal == "mixed":
        u = amp_v * 0.5 * (1 - np.cos(2 * np.pi * freq_hz * tt)) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.5 * tt) ** 2)
    else:
        u = amp_v * 0.5 * (1 - np.cos(2 * np.pi * freq_hz * tt))
    u[:n_relay] = 0.0
    Vc = rig["amplifier_gain"] * u
    C = rig["n_actuators"] * rig["actuator_catalog"]["capacitance_f"]
    Vs = rig["shunt_resistance_ohm"] * C * np.gradient(Vc, t)
    v_shunt = rig["inamp_gain"] * Vs + 3e-4 + noise_v * rng.standard_normal(n)
    V = Vc - Vs
    frac = V / rig["actuator_catalog"]["max_voltage_v"]
    if tip == "free":
        dx = rig["tip_free_displacement_m"] * frac
        f = np.zeros(n)
    elif tip == "blocked":
        dx = np.zeros(n)
        f = 0.1 * frac
    else:
        dx = np.minimum(rig["tip_free_displacement_m"] * frac, 2.0e-3)
        f = 0.1 * np.clip(frac - 2.0e-3 / rig["tip_free_displacement_m"], 0, None)
    laser = dx / 2 / rig["reference"]["laser_m_per_v"] + noise_v * rng.standard_normal(n)
    load = f / rig["reference"]["load_cell_n_per_v"] + noise_v * rng.standard_normal(n)
    if reference == "force":
        laser[:] = np.nan
    else:
        load[:] = np.nan
    relay = np.zeros(n)
    relay[:n_relay] = 1.0
    return pd.DataFrame({"t": t, "u_cmd": u, "v_shunt": v_shunt, "laser": laser, "load_cell": load,
                         "relay": relay})


def write_log(df: pd.DataFrame, path: Path) -> None:
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False, float_format="%.9g")


def read_any(path: Path) -> pd.DataFrame:
    return pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)


def write_trials(rows, path: Path, header=("trial", "file", "role", "tip", "object_mm", "reference", "signal")):
    lines = [",".join(header)] + [",".join(r) for r in rows]
    path.write_text("\n".join(lines) + "\n")


def make_dataset(root: Path, name: str = "ds", rig: dict | None = None, trials=None, seed: int = 0,
                 **log_kw) -> Path:
    """Write a valid dataset ``root/name`` (rig.yaml, trials.csv, 4 logs: 2 Parquet, 2 CSV)."""
    d = Path(root) / name
    d.mkdir(parents=True, exist_ok=True)
    rig = copy.deepcopy(rig or RIG)
    rig["dataset"] = name
    (d / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    trials = trials or TRIALS
    write_trials(trials, d / "trials.csv")
    for k, (tr, file, role, tip, om, ref, sig) in enumerate(trials):
        write_log(make_log(tip, ref, sig, seed=seed + k, rig=rig, **log_kw), d / file)
    return d


@pytest.fixture(scope="session")
def pristine(tmp_path_factory) -> Path:
    """The valid dataset, written once per session (copy it before mutating: see ``dataset``)."""
    return make_dataset(tmp_path_factory.mktemp("pristine"))


@pytest.fixture
def dataset(tmp_path, pristine) -> Path:
    """A fresh copy of the valid dataset ``<tmp>/ds`` that a test may mutate."""
    import shutil

    return Path(shutil.copytree(pristine, tmp_path / "ds"))
