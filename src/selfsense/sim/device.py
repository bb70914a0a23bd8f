"""Device parameters of the virtual tweezer (one documented config).

All SI.  Defaults live in ``device_default.yaml`` next to this file; a scenario may override any
field through its ``device:`` mapping.  Seeds: thesis ``000_18d138f03f1777c3.txt`` eqs. (24)-(27)
(Goldfarb-Celanovic actuator), (44)-(46) (actuators + two-port), (56)-(59), Table 1, sec. 5.1;
paper ``001_972cacfaa08ad91a.txt`` Table I (alpha, C_p).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np
import yaml

__all__ = ["DeviceParams", "default_device", "load_device"]


@dataclass(frozen=True)
class DeviceParams:
    n_actuators: int
    alpha_n_per_v: float
    cp_f: float
    k_act_n_per_m: float
    mech_ratio: float
    mech_k_tip_n_per_m: float
    mech_k_in_free_n_per_m: float
    tip_opening_m: float
    q_ref_c: float
    h_lin_v: float
    preisach_components: tuple
    virgin_lobe: tuple
    demag_amplitude: float
    demag_cycles: int
    ecreep_c_v: tuple
    ecreep_tau_s: tuple
    shunt_resistance_ohm: float
    relay_resistance_ohm: float
    inamp_gain: float
    inamp_offset_v: float
    inamp_noise_v: float
    amplifier_gain: float
    amplifier_bandwidth_hz: float
    laser_m_per_v: float
    laser_noise_m: float
    load_cell_n_per_v: float
    load_cell_noise_n: float
    load_cell_stiffness_n_per_m: float
    object_stiffness_n_per_m: float
    adc_range_v: float
    adc_bits: int
    catalog_free_displacement_m: float
    catalog_blocked_force_n: float
    catalog_stiffness_n_per_m: float
    catalog_capacitance_f: float
    catalog_max_voltage_v: float
    tip_free_displacement_m: float
    h_family: str = "preisach"
    h_sign: float = 1.0
    h_params: tuple = ()

    # ---- derived -------------------------------------------------------------------------
    @property
    def stiffness_matrix(self) -> np.ndarray:
        """Mechanism two-port stiffness K [[k11, k12], [k12, k22]] (N/m): ``f_in = k11 x + k12 d``,
        ``-f_tip = k12 x + k22 d`` (symmetric, reciprocal; thesis eqs. 17-21 in stiffness form)."""
        r, kt, ki = self.mech_ratio, self.mech_k_tip_n_per_m, self.mech_k_in_free_n_per_m
        return np.array([[ki + r * r * kt, -r * kt], [-r * kt, kt]])

    @property
    def adc_lsb_v(self) -> float:
        return 2.0 * self.adc_range_v / 2 ** self.adc_bits

    def replace(self, **kw) -> "DeviceParams":
        return dataclasses.replace(self, **_coerce(kw))

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for k, v in d.items():
            if isinstance(v, tuple):
                d[k] = [list(x) if isinstance(x, tuple) else x for x in v]
        return d


def _coerce(d: dict) -> dict:
    names = {f.name: f for f in dataclasses.fields(DeviceParams)}
    out = {}
    for k, v in d.items():
        if k not in names:
            raise ValueError(f"unknown device parameter {k!r}")
        if k == "h_family":
            from .truth import family_code

            family_code(str(v))
            out[k] = str(v)
            continue
        if k == "h_params":
            v = tuple(float(x) for x in v)
        elif isinstance(v, list):
            v = tuple(tuple(float(y) for y in x) if isinstance(x, (list, tuple)) else float(x) for x in v)
        elif k in ("n_actuators", "adc_bits", "demag_cycles"):
            v = int(v)
        else:
            v = float(v)
        out[k] = v
    return out


def load_device(path=None, overrides: dict | None = None) -> DeviceParams:
    """Device from a YAML file (default: the packaged ``device_default.yaml``) plus overrides."""
    if path is None:
        text = resources.files("selfsense.sim").joinpath("device_default.yaml").read_text()
    else:
        with open(path) as fh:
            text = fh.read()
    d = yaml.safe_load(text)
    d.update(overrides or {})
    return DeviceParams(**_coerce(d))


def default_device() -> DeviceParams:
    return load_device()
