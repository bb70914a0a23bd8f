"""Switchable unmodelled effects of the virtual tweezer.

Each effect has ONE magnitude (0 = off) and a documented physical form.  The forms are chosen
on purpose to differ from the gap diagnostic's library forms (docs/gap.md): physical
circuit elements and Prony series with non-log-spaced time constants, not integral-of-V features
or log-spaced lag banks.  The table in ``docs/simulator.md`` is generated from ``EFFECTS``.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Effect", "EFFECTS", "DEFAULT_EFFECTS", "resolve_effects", "OPEN_SET"]


@dataclass(frozen=True)
class Effect:
    name: str
    family: str          #: slow | rate | hysteresis | load | open-set
    unit: str            #: unit of the magnitude
    default: float       #: magnitude in the default device (0 = off)
    form: str            #: physical form (one line)


EFFECTS: dict[str, Effect] = {e.name: e for e in [
    Effect("creep", "slow", "fraction of the elastic PZT strain reached after a long hold", 0.02,
           "charge-free creep strain x_cr = m * sum_j w_j z_j, dz_j/dt = (x_el - z_j)/tau_j, "
           "tau = (0.9, 6.5, 41) s, w = (0.3, 0.3, 0.4) (Prony series of a power-law creep)"),
    Effect("leakage", "slow", "nS (insulation conductance of the actuator set)", 0.5,
           "resistor R_leak = 1/(m * 1e-9 S) in parallel with the actuators: the shunt sees V/R_leak too"),
    Effect("offset_drift", "slow", "uV/s (in-amp input-referred drift rate)", 1.0,
           "in-amp input offset after the relay: m*1e-6*t (thermal ramp) + random walk with "
           "0.5*m uV/sqrt(s) (fixed trial RNG stream)"),
    Effect("dielectric_absorption", "slow", "C_da / (n_A C_p)", 0.01,
           "series R_da-C_da branch in parallel with the actuators, R_da C_da = 3.7 s"),
    Effect("temperature", "slow", "K (temperature rise over the campaign)", 1.0,
           "T(t) = m * (1 - exp(-t_campaign / 1500 s)); C_p(1 + 4e-3 dT), alpha(1 + 2e-3 dT)"),
    Effect("mechanism_mode", "rate", "(50 Hz / f_n)^2 (tip modal mass, 0 = quasi-static)", 0.5,
           "tip modal mass m_t = m * k_oc / (2 pi 50 Hz)^2, damping ratio 0.05, implicit in the "
           "sub-step loop (couples back into the charge)"),
    Effect("amplifier_limits", "rate", "1 / (current limit in mA)", 0.0,
           "HV amplifier current limit i_max = 1 mA / m and slew limit 1500 V/s / m"),
    Effect("virgin_curve", "hysteresis", "x extra Preisach lobe (beta < 0 < alpha)", 0.0,
           "adds m times the `virgin_lobe` Preisach component: stronger one-sided initial ascending curve"),
    Effect("preload", "hysteresis", "prior charge excursion / q_ref", 0.0,
           "before the trial the Preisach state is driven to u = m and back to 0 (not relaxed); "
           "the relay then shorts a remanent V_H"),
    Effect("stress_hysteresis", "load", "relative change of V_H at f_tip = 0.1 N", 0.05,
           "V_H(q) * (1 + m * f_tip / 0.1 N) (actuator stress from the tip load)"),
    Effect("contact_nonlinearity", "load", "Hertz blend 0..1", 0.3,
           "f = k_c delta [(1 - m) + m sqrt(delta / 20 um)] instead of k_c delta"),
    Effect("backlash", "open-set", "um (dead band of the tip closing)", 0.0,
           "play element between mechanism and tip, total width m um"),
    Effect("dead_zone", "open-set", "V (amplifier crossover half-width at its output)", 0.0,
           "V_c = sign(v) max(|v| - m, 0), v = gain u_cmd"),
    Effect("second_mode", "open-set", "participation 0..1 of a 173 Hz arm mode", 0.0,
           "measured arm = (1-m) d/2 + m w, w'' = -2 zeta w_n (w' - d'/2) - w_n^2 (w - d/2), "
           "zeta = 0.015 (laser sees it, the tip closing does not)"),
]}

OPEN_SET = tuple(n for n, e in EFFECTS.items() if e.family == "open-set")
DEFAULT_EFFECTS: dict[str, float] = {n: e.default for n, e in EFFECTS.items()}


def resolve_effects(effects: dict | None, use_defaults: bool = True) -> dict[str, float]:
    """Full magnitude dict: defaults (or all 0) updated by ``effects``; unknown names raise."""
    out = dict(DEFAULT_EFFECTS) if use_defaults else {n: 0.0 for n in EFFECTS}
    for k, v in (effects or {}).items():
        if k not in EFFECTS:
            raise ValueError(f"unknown effect {k!r}; known: {', '.join(EFFECTS)}")
        v = float(v)
        if not v >= 0.0:
            raise ValueError(f"effect {k!r}: magnitude must be >= 0, got {v}")
        out[k] = v
    return out
