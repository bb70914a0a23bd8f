"""Families of virtual devices: truth hysteresis family x mechanism and actuator constants drawn per seed.

``draw_device(family, seed)`` returns a complete scenario (device overrides, effects, trials) for one virtual
device. Everything is drawn from ``numpy.random.default_rng(SeedSequence([seed, family index, 7919]))`` over the
documented physical ranges of ``RANGES`` (the table in ``docs/simulator.md`` is generated from it), so that the
cross-device benchmark (``selfsense devices``; ``benchmarks/cross_device.py``) can run any number of devices per
family, one job per device.

Physical ranges (per device, uniform unless stated):

* actuator set (thesis 000_18d138f03f1777c3.txt eqs. 24-27, 45): ``n_A`` in {3, 4, 5, 6}; transformer ratio
  ``alpha`` 1.5-3.5 N/V; clamped capacitance ``C_p`` 0.15-0.5 uF; stiffness ``k`` 15-40 MN/m;
* mechanism (two-port, thesis eqs. 17-21): free-tip stroke at 150 V 4-9 mm (sets the transmission ratio),
  coupling ``F_b S / (n_A alpha V x_free)`` 2-8 % (the share of the actuators' blocked-force x stroke product that
  reaches the tip: it sets the tip-port stiffness and with it how far a blocked tip shifts V_p at equal charge,
  the signal that force sensing lives on -- docs/method.md; blocked forces then span about
  0.05-0.6 N), input compliance ratio
  ``k_in_free / (n_A k)`` 0.1-0.4 (how much of the actuators' stroke the mechanism lets through);
* hysteresis: its swing (peak-to-peak of the hysteretic output on a 0 -> 1 -> 0 charge cycle) 5-18 % of the
  150 V range; the reversible part ``h_lin`` 10-35 % of the ``q / (n_A C_p)`` slope; orientation clockwise or
  counter-clockwise (50 / 50); a remanent preload (prior excursion to 0.3-0.8 q_ref, 50 %);
* electrical creep weights x 0.5-1.5 and time constants x 0.7-1.4 of the default device;
* the catalog values written to rig.yaml differ from the truth by up to +-20 % (a catalog is not the device);
  ``tip_free_displacement_m`` is "measured once" by a simulated quasi-static 150 V stroke S; the tip opening is
  S + 1 mm and the two objects are sized to touch at 35 % and 65 % of the stroke the drive reaches;
* the rig's in-amp gain is chosen for the device (peak shunt voltage about 4 V at the ADC), at most 5, and lowered
  further when a noise-free test drive shows the shunt channel would clip (peak kept below 8 V);
* drives: base frequency 0.4-0.6 Hz, amplitude 120-150 V.

Presets: ``clean`` (no unmodelled effect except the electrical creep and the chosen hysteresis) and ``drift``
(charge leakage 1-5 nS, i.e. 0.2-1 GOhm insulation; in-amp offset drift 1-4 uV/s; mechanical creep 2-5 % of the
elastic strain; realistic rig magnitudes).
"""
from __future__ import annotations

import numpy as np

from .device import load_device
from .preisach import preisach_path
from .truth import FAMILIES, NPAR, truth_path

__all__ = ["FAMILIES", "PRESETS", "RANGES", "draw_device", "device_trials"]

PRESETS = ("clean", "drift")

RANGES = {
    "n_actuators": ("{3, 4, 5, 6}", "-", "number of actuators in parallel (thesis eq. 45)"),
    "alpha_n_per_v": ((1.5, 3.5), "N/V", "transformer ratio alpha (thesis eq. 24)"),
    "cp_f": ((0.15e-6, 0.5e-6), "F", "clamped capacitance C_p of one actuator (thesis eq. 26)"),
    "k_act_n_per_m": ((15e6, 40e6), "N/m", "actuator stiffness"),
    "stroke_m": ((4e-3, 9e-3), "m", "free-tip stroke at 150 V (sets the mechanism ratio)"),
    "coupling": ((0.02, 0.08), "-", "F_b S / (n_A alpha V x_free): blocked-force x free-stroke product at the tip "
                                    "over that of the actuators (sets the tip-port stiffness; the thesis device: "
                                    "6-8 % of the actuators' work reaches the tip)"),
    "compliance_ratio": ((0.1, 0.4), "-", "k_in_free / (n_A k): input compliance ratio of the mechanism"),
    "h_swing_frac": ((0.05, 0.18), "-", "hysteretic swing / 150 V"),
    "h_lin_frac": ((0.10, 0.35), "-", "reversible part h_lin / (q_ref / (n_A C_p))"),
    "catalog_error": ((-0.2, 0.2), "-", "relative error of each catalog value in rig.yaml"),
    "freq_hz": ((0.4, 0.6), "Hz", "drive base frequency"),
    "amplitude_v": ((120.0, 150.0), "V", "drive amplitude"),
    "leakage_ns": ((1.0, 5.0), "nS", "drift preset: insulation conductance of the actuator set"),
    "offset_drift_uv_s": ((1.0, 4.0), "uV/s", "drift preset: in-amp input offset drift"),
    "creep": ((0.02, 0.05), "-", "drift preset: mechanical creep, fraction of the elastic strain"),
}

#: ``randomise="device"``: rig, amplifier, dielectric and drive quantities drawn per device besides the family's
#: (from a random stream of their own, so that everything ``RANGES`` draws stays the same device); log-uniform where
#: marked
DEVICE_RANGES = {
    "sample_rate_hz": ((1000.0, 20000.0), "Hz", "DAQ sample rate (log-uniform); physics substeps keep <= 0.1 ms"),
    "adc_bits": ((12, 18), "bit", "ADC resolution (integer)"),
    "laser_noise_m": ((0.5e-6, 10e-6), "m", "laser resolution (noise, log-uniform)"),
    "amplifier_bandwidth_hz": ((500.0, 5000.0), "Hz", "HV amplifier bandwidth (log-uniform)"),
    "amplifier_limits": ((0.05, 0.5), "1/mA", "HV amplifier current limit 1 mA / m and slew limit 1500 V/s / m: "
                         "2-20 mA, 3-30 kV/s (log-uniform m)"),
    "dielectric_weight": ((0.0, 0.05), "-", "dielectric relaxation in V_H: total weight of its three lags, share of "
                          "the V_H span"),
    "dielectric_tau_s": ((0.1, 100.0), "s", "the three lags (log-uniform)"),
    "hold_s": ((1.0, 10.0), "s", "holds of the mixed drives (trials lengthened to hold two trapezoids)"),
}
RANDOMISE = ("hysteresis", "device")

_V = 150.0


def _u(rng, key):
    lo, hi = RANGES[key][0]
    return float(rng.uniform(lo, hi))


def _unit_cycle() -> np.ndarray:
    """0 -> 1 -> 0.3 -> 0.8 -> 0 normalised charge path used to scale each family's swing."""
    return np.concatenate([np.linspace(0, 1, 400), np.linspace(1, 0.3, 300), np.linspace(0.3, 0.8, 200),
                           np.linspace(0.8, 0, 300)])


def _family_params(family: str, rng) -> tuple[list, list]:
    """(Preisach components, other-family parameter vector) with unit output weight."""
    if family == "preisach":
        n = int(rng.integers(3, 5))
        comps = []
        for _ in range(n):
            comps.append([rng.uniform(0.1, 0.8), rng.uniform(0.04, 0.15), rng.uniform(0.04, 0.09), rng.uniform(0.3, 1.0)])
        if rng.uniform() < 0.5:   # a virgin lobe (beta < 0 < alpha)
            comps.append([rng.uniform(0.15, 0.3), rng.uniform(0.3, 0.45), rng.uniform(0.06, 0.1), rng.uniform(0.1, 0.4)])
        return comps, []
    if family == "bouc_wen":
        n = rng.uniform(1.0, 2.0)
        zmax = rng.uniform(0.15, 0.5)
        frac = rng.uniform(0.55, 0.9)          # beta / (beta + gamma)
        s = 1.0 / zmax ** n                    # beta + gamma (A = 1)
        return [], [1.0, frac * s, (1 - frac) * s, n, 1.0]
    if family == "gpi":
        nr = 8
        rmax = rng.uniform(0.08, 0.3)
        return [], [rng.uniform(0.5, 1.0), rng.uniform(1.0, 3.0), rng.uniform(0.2, 1.0), 1.0, rng.uniform(0.0, 10.0),
                    nr] + list(np.linspace(0.0, rmax, nr))
    if family == "jiles_atherton":
        a = rng.uniform(0.1, 0.3)
        return [], [1.0, a, rng.uniform(0.05, 0.2), rng.uniform(0.1, 0.5), rng.uniform(0.0, 0.3) * a,
                    rng.uniform(0.2, 0.6), 1.0]
    if family == "rate_kp":
        # hp = [w, m, s1, s2, c, r0]: density centre and spread over the hysteron centres, decay over their
        # half-widths, loop widening per decade of |du/dt| (7-18 %), reference rate 1 /s (a 0.3 Hz sine of full stroke)
        return [], [1.0, rng.uniform(0.3, 0.7), rng.uniform(0.15, 0.4), rng.uniform(0.05, 0.2),
                    rng.uniform(0.07, 0.18), 1.0]
    raise ValueError(f"unknown device family {family!r}; expected one of {FAMILIES}")


def _swing(family, comps, hp) -> float:
    u = _unit_cycle()
    if family == "preisach":
        y = preisach_path(u, comps)
    else:
        y = truth_path(family, u, hp)
    # hysteretic part: remove the best straight line in u
    A = np.column_stack([u, np.ones_like(u)])
    r = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
    return float(np.ptp(r)) or 1.0


def _free_stroke(n, alpha, k, kin, ratio) -> float:
    """Linear free-tip stroke [m] at V_p = 150 V: x = n alpha V / (n k + k_in_free), d = ratio x."""
    return ratio * n * alpha * _V / (n * k + kin)


def _log_u(rng, key) -> float:
    lo, hi = DEVICE_RANGES[key][0]
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _randomise_device(sc: dict, family: str, seed: int, swing: float) -> None:
    """Whole-device randomisation (:data:`DEVICE_RANGES`) of a drawn scenario, in place; ``swing`` [V]: the drawn
    hysteretic swing. The dielectric relaxation replaces the family draw's electrical creep (the same element of the
    kernel, now with lags up to 100 s)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), FAMILIES.index(family), 7919, 2]))
    dev = sc["device"]
    fs = _log_u(rng, "sample_rate_hz")
    fs = float(np.round(fs, -2))
    sc["sample_rate_hz"] = fs
    sc["substeps"] = int(max(1, np.ceil(10000.0 / fs)))
    lo, hi = DEVICE_RANGES["adc_bits"][0]
    dev["adc_bits"] = int(rng.integers(lo, hi + 1))
    dev["laser_noise_m"] = _log_u(rng, "laser_noise_m")
    dev["amplifier_bandwidth_hz"] = _log_u(rng, "amplifier_bandwidth_hz")
    sc["effects"]["amplifier_limits"] = _log_u(rng, "amplifier_limits")
    # the user of this rig knows the amplifier's current limit from its data sheet and says so in rig.yaml (the data
    # contract then reads a shunt plateau at it as the amplifier's, not as a clipped channel)
    sc["rig_extra"] = {"amplifier_current_limit_a": 1e-3 / sc["effects"]["amplifier_limits"]}
    # dielectric relaxation: three lags, weights a share of the V_H span (h_lin + the hysteretic swing)
    span = abs(dev["h_lin_v"]) + swing
    lo, hi = DEVICE_RANGES["dielectric_weight"][0]
    w = float(rng.uniform(lo, hi)) * rng.dirichlet(np.ones(3))
    taus = np.sort([_log_u(rng, "dielectric_tau_s") for _ in range(3)])
    dev["ecreep_c_v"] = [float(x * span) for x in w]
    dev["ecreep_tau_s"] = [float(t) for t in taus]
    hold = float(rng.uniform(*DEVICE_RANGES["hold_s"][0]))
    for tr in sc["trials"]:
        if tr.get("signal") == "mixed":
            ramp = float(tr.get("ramp_s", 0.4))
            tr["hold_s"] = round(hold, 3)
            tr["duration"] = float(max(tr["duration"], np.ceil(2 * (2 * ramp + 2 * hold) + 3.0 / tr["freq"])))
    sc["randomise"] = {"sample_rate_hz": fs, "substeps": sc["substeps"], "adc_bits": dev["adc_bits"],
                       "laser_noise_m": dev["laser_noise_m"], "amplifier_bandwidth_hz": dev["amplifier_bandwidth_hz"],
                       "amplifier_limits": sc["effects"]["amplifier_limits"],
                       "dielectric_weight": float(np.sum(w)), "dielectric_tau_s": [float(t) for t in taus],
                       "hold_s": round(hold, 3)}


def draw_device(family: str, seed: int, preset: str = "clean", randomise: str = "hysteresis") -> dict:
    """Scenario dict (``selfsense.sim.simulate`` format) of one virtual device of ``family``, drawn by ``seed``.

    ``randomise``: ``hysteresis`` (the family and the quantities of ``RANGES``) or ``device`` (besides those, the
    rig, amplifier, dielectric and drive quantities of :data:`DEVICE_RANGES`; the drawn values are in
    ``scenario["randomise"]``)."""
    if randomise not in RANDOMISE:
        raise ValueError(f"unknown randomisation {randomise!r}; expected one of {RANDOMISE}")
    if family not in FAMILIES:
        raise ValueError(f"unknown device family {family!r}; expected one of {FAMILIES}")
    if preset not in PRESETS:
        raise ValueError(f"unknown device preset {preset!r}; expected one of {PRESETS}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), FAMILIES.index(family), 7919]))
    n = int(rng.choice([3, 4, 5, 6]))
    alpha = _u(rng, "alpha_n_per_v")
    cp = _u(rng, "cp_f")
    k = _u(rng, "k_act_n_per_m")
    stroke = _u(rng, "stroke_m")
    kappa = _u(rng, "coupling")
    rho = _u(rng, "compliance_ratio")
    kin = rho * n * k
    x_free = n * alpha * _V / (n * k + kin)
    ratio = stroke / x_free
    fb = kappa * n * alpha * _V * x_free / stroke     # blocked tip force at 150 V [N]
    k_tip = fb / stroke
    q_ref = n * (alpha * x_free + cp * _V)
    swing = _u(rng, "h_swing_frac") * _V
    h_lin = _u(rng, "h_lin_frac") * q_ref / (n * cp)
    sign = 1.0 if rng.uniform() < 0.5 else -1.0
    preload = float(rng.uniform(0.3, 0.8)) if rng.uniform() < 0.5 else 0.0
    comps, hp = _family_params(family, rng)
    scale = swing / _swing(family, comps, hp)
    if family == "preisach":
        comps = [[c, h, s, w * scale] for c, h, s, w in comps]
    elif family == "bouc_wen":
        hp[4] *= scale
    elif family == "gpi":
        hp[3] *= scale
    elif family == "rate_kp":
        hp[0] *= scale
    else:
        hp[6] *= scale
    base = load_device()
    ec_w = rng.uniform(0.5, 1.5)
    ec_t = rng.uniform(0.7, 1.4)
    cat = [1.0 + _u(rng, "catalog_error") for _ in range(4)]
    opening = stroke + 1.0e-3   # provisional; set from the measured stroke below
    dev = {
        "n_actuators": n, "alpha_n_per_v": alpha, "cp_f": cp, "k_act_n_per_m": k,
        "mech_ratio": ratio, "mech_k_tip_n_per_m": k_tip, "mech_k_in_free_n_per_m": kin,
        "tip_opening_m": opening, "q_ref_c": q_ref, "h_lin_v": h_lin,
        "h_family": family, "h_sign": sign, "h_params": list(hp),
        "preisach_components": comps if comps else [list(c) for c in base.preisach_components],
        "ecreep_c_v": [c * ec_w for c in base.ecreep_c_v],
        "ecreep_tau_s": [t * ec_t for t in base.ecreep_tau_s],
        "load_cell_stiffness_n_per_m": base.load_cell_stiffness_n_per_m * rng.uniform(0.5, 2.0),
        "object_stiffness_n_per_m": base.object_stiffness_n_per_m * rng.uniform(0.5, 2.0),
        "catalog_free_displacement_m": alpha * _V / k * cat[0],
        "catalog_blocked_force_n": alpha * _V * cat[1],
        "catalog_stiffness_n_per_m": k * cat[2],
        "catalog_capacitance_f": cp * cat[3],
        "catalog_max_voltage_v": _V,
        # the rig's in-amp gain is chosen for the device, as a user would: peak shunt current ~3 q_ref / s
        # (0.4 s ramps to full charge) must stay within +-4 V of the +-10 V ADC (before the ADC margin)
        "inamp_gain": float(min(5.0, 4.0 / (base.shunt_resistance_ohm * 3.0 * q_ref))),
        "tip_free_displacement_m": stroke,   # replaced by the simulated quasi-static stroke in measure_free_stroke
    }
    if len(dev["h_params"]) > NPAR:
        raise AssertionError("too many truth parameters")
    effects = {"preload": preload}
    if preset == "drift":
        effects.update({"leakage": _u(rng, "leakage_ns"), "offset_drift": _u(rng, "offset_drift_uv_s"),
                        "creep": _u(rng, "creep")})
    freq = _u(rng, "freq_hz")
    amp = _u(rng, "amplitude_v")
    sc = {
        "name": f"{family}_{preset}_{seed}",
        "seed": int(seed),
        "sample_rate_hz": 1000.0,
        "substeps": 10,
        "device": dev,
        "effects_defaults": False,
        "effects": effects,
        "trials": [],
        "description": f"virtual device: {family} truth hysteresis, preset {preset}, seed {seed}",
    }
    # the free stroke the user "measures once" at 150 V; the tip opens 1 mm wider; the two objects are sized to
    # touch at 35 % and 65 % of the stroke the drive amplitude reaches (thesis: 4 mm and 2 mm objects)
    S = measure_free_stroke(sc)
    dev["tip_free_displacement_m"] = S
    dev["tip_opening_m"] = S + 1.0e-3
    s_amp = S * amp / _V
    large_mm = round((S + 1.0e-3 - 0.35 * s_amp) * 1e3, 3)
    small_mm = round((S + 1.0e-3 - 0.65 * s_amp) * 1e3, 3)
    sc["trials"] = device_trials(freq, amp, large_mm, small_mm)
    if randomise == "device":
        _randomise_device(sc, family, seed, swing)
    # and lowers the in-amp gain if a test drive shows the shunt channel would clip (steep V_H(q) segments draw
    # current spikes): peak of the free mixed and blocked sine calibration drives kept within 8 V of the 10 V ADC
    i_max = _peak_current(sc)
    R = base.shunt_resistance_ohm
    if dev["inamp_gain"] * R * i_max > 8.0:
        dev["inamp_gain"] = float(8.0 / (R * i_max))
    return sc


def _peak_current(sc: dict) -> float:
    """Largest |dq/dt| [A] of the free-tip mixed and blocked-tip sine calibration drives (noise-free truth)."""
    from .effects import resolve_effects
    from .simulate import simulate_trial

    dev = load_device(overrides=sc["device"])
    eff = resolve_effects(sc.get("effects") or {}, use_defaults=bool(sc.get("effects_defaults", False)))
    peak = 0.0
    for tr in sc["trials"]:
        if tr["trial"] in ("cal_free_mixed", "cal_blocked_sine"):
            _, truth = simulate_trial(tr, dev, eff, seed=0, index=0, sample_rate_hz=1000.0, substeps=4,
                                      effects_defaults=False)
            q = truth["q"].to_numpy()
            peak = max(peak, float(np.max(np.abs(np.diff(q)))) * 1000.0)
    return peak


def device_trials(freq: float, amp: float, large_mm: float = 4.0, small_mm: float = 2.0) -> list[dict]:
    """The thesis' protocol (000_18d138f03f1777c3.txt sec. 5.2) shortened for benchmarks: free-tip sine and mixed
    and blocked-tip sine calibration, then 3 displacement and 3 force validation trials (free / object / blocked)."""
    f = round(freq, 4)
    a = round(amp, 2)
    return [
        {"trial": "cal_free_sine", "role": "calibration", "tip": "free", "reference": "displacement",
         "signal": "sine", "duration": 20, "freq": f, "amplitude": a},
        {"trial": "cal_blocked_sine", "role": "calibration", "tip": "blocked", "reference": "force",
         "signal": "sine", "duration": 20, "freq": f, "amplitude": a},
        {"trial": "cal_free_mixed", "role": "calibration", "tip": "free", "reference": "displacement",
         "signal": "mixed", "duration": 16, "freq": f, "amplitude": a},
        {"trial": "val_disp_free_mixed", "role": "validation", "tip": "free", "reference": "displacement",
         "signal": "mixed", "duration": 12, "freq": round(f * 1.1, 4), "amplitude": a},
        {"trial": "val_disp_small_sine", "role": "validation", "tip": "object", "object_mm": small_mm,
         "reference": "displacement", "signal": "sine", "duration": 12, "freq": f, "amplitude": a},
        {"trial": "val_disp_large_mixed", "role": "validation", "tip": "object", "object_mm": large_mm,
         "reference": "displacement", "signal": "mixed", "duration": 12, "freq": f, "amplitude": a},
        {"trial": "val_force_blocked_sine", "role": "validation", "tip": "blocked", "reference": "force",
         "signal": "sine", "duration": 12, "freq": round(f * 0.9, 4), "amplitude": a},
        {"trial": "val_force_large_mixed", "role": "validation", "tip": "object", "object_mm": large_mm,
         "reference": "force", "signal": "mixed", "duration": 12, "freq": f, "amplitude": a},
        {"trial": "val_force_small_sine", "role": "validation", "tip": "object", "object_mm": small_mm,
         "reference": "force", "signal": "sine", "duration": 12, "freq": f, "amplitude": a},
    ]


def measure_free_stroke(scenario: dict) -> float:
    """Tip free displacement [m] at 150 V "measured once" on the simulated device: a 1 s ramp to 150 V and hold on a
    free tip, no noise needed (the truth's dx_ref at the end of the hold)."""
    from .effects import resolve_effects
    from .simulate import simulate_trial

    dev = load_device(overrides=scenario["device"])
    tr = {"trial": "stroke", "role": "calibration", "tip": "free", "reference": "displacement", "signal": "steps",
          "duration": 3.5, "levels": [1.0], "ramp_s": 0.5, "hold_s": 1.0, "amplitude": _V}
    eff = resolve_effects(scenario.get("effects") or {}, use_defaults=bool(scenario.get("effects_defaults", False)))
    _, truth = simulate_trial(tr, dev, eff, seed=0, index=0, sample_rate_hz=1000.0, substeps=4, effects_defaults=False)
    return float(np.max(truth["dx_ref"].to_numpy()))
