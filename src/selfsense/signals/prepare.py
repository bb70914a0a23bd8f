"""One trial from SI raw signals to the estimator's inputs: actuator voltage and charge."""
from __future__ import annotations

import pandas as pd

from .charge import actuator_voltage, charge_from_shunt

__all__ = ["prepare_trial", "PREPARED_COLUMNS"]

PREPARED_COLUMNS: tuple[str, ...] = ("t", "V", "q", "u_cmd", "relay", "dx_ref", "f_ref", "V_c", "V_s")


def prepare_trial(df_si: pd.DataFrame, rig, offset="relay") -> pd.DataFrame:
    """Add ``V`` [V] (000_18d138f03f1777c3.txt eq. (56)) and ``q`` [C] (eq. (57), reset while relay == 1,
    in-amp offset removed from the shorted segment) to the SI frame of
    :func:`selfsense.io.trial_signals`.

    ``rig`` needs ``shunt_resistance_ohm``. Returns columns ``PREPARED_COLUMNS``; the subtracted offset [V]
    is in ``.attrs["v_s_offset_v"]``.
    """
    V = actuator_voltage(df_si["V_c"].to_numpy(), df_si["V_s"].to_numpy())
    q, off = charge_from_shunt(df_si["t"].to_numpy(), df_si["V_s"].to_numpy(), df_si["relay"].to_numpy(),
                               rig.shunt_resistance_ohm, offset=offset)
    out = pd.DataFrame({
        "t": df_si["t"].to_numpy(float), "V": V, "q": q, "u_cmd": df_si["u_cmd"].to_numpy(float),
        "relay": df_si["relay"].to_numpy(float), "dx_ref": df_si["dx_ref"].to_numpy(float),
        "f_ref": df_si["f_ref"].to_numpy(float), "V_c": df_si["V_c"].to_numpy(float),
        "V_s": df_si["V_s"].to_numpy(float),
    })
    out.attrs.update(dict(df_si.attrs))
    out.attrs["v_s_offset_v"] = off
    return out
