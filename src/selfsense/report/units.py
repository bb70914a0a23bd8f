"""Units of every quantity the pipeline writes (SI), for the report, the exports and the figures.

Sensing coefficients of thesis ``000_18d138f03f1777c3.txt`` eq. (52) in the form of
:mod:`selfsense.sensing.estimator`: ``dx_tip = A1 Q + A2 V_p``, ``f_tip = B21 Q + B22 V_p`` with the total charge
``Q = n_A q`` [C] and the piezo voltage ``V_p`` [V]; ``A3`` is the thesis' force coefficient per actuator charge
(``B21 = A3 / n_A``, ``B22 = -C_p A3``).
"""
from __future__ import annotations

#: column -> (unit, description)
SIGNALS: dict[str, tuple[str, str]] = {
    "t": ("s", "time"),
    "u_cmd": ("V", "amplifier control voltage (as logged)"),
    "relay": ("1", "1 while the actuator leads are shorted"),
    "V_c": ("V", "amplifier output voltage"),
    "V_s": ("V", "shunt voltage"),
    "V": ("V", "actuator voltage V = V_c - V_s (thesis eq. 56)"),
    "q": ("C", "total charge through the shunt (thesis eq. 57)"),
    "V_H": ("V", "hysteresis voltage H(q)"),
    "V_p": ("V", "piezo voltage V_p = V - H(q) (thesis eqs. 24-27)"),
    "dx_raw": ("m", "self-sensed tip displacement before post-processing (thesis eq. 52)"),
    "f_raw": ("N", "self-sensed tip force before post-processing (thesis eq. 52)"),
    "dx_hat": ("m", "self-sensed tip displacement after limiting and sliding DC offset (thesis sec. 5.2)"),
    "f_hat": ("N", "self-sensed tip force after limiting (thesis sec. 5.2)"),
    "dx_ref": ("m", "reference tip displacement (laser)"),
    "f_ref": ("N", "reference tip force (load cell)"),
}

#: sensing coefficient -> unit
COEFFICIENTS: dict[str, str] = {
    "A1": "m/C",
    "A2": "m/V",
    "A3": "N/C",
    "B21": "N/C",
    "B22": "N/V",
    "dx0": "m",
    "S2": "N/m",
    "h_slope": "V/C",
}


def coef_unit(name: str) -> str:
    """Unit of a sensing coefficient ("see regressor" for a name this table does not know)."""
    return COEFFICIENTS.get(name, "see regressor")
