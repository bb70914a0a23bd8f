"""selfsense.signals: actuator voltage and charge (thesis 000_18d138f03f1777c3.txt eqs. 56-57), offsets,
limiting and the sliding DC offset (thesis Fig. 24)."""
from .charge import SignalError, actuator_voltage, charge_from_shunt, relay_offset
from .offset import limit_to_range, sliding_dc_offset
from .prepare import PREPARED_COLUMNS, prepare_trial
from .runs import true_runs

__all__ = ["SignalError", "actuator_voltage", "charge_from_shunt", "relay_offset", "limit_to_range",
           "sliding_dc_offset", "prepare_trial", "PREPARED_COLUMNS", "true_runs"]
