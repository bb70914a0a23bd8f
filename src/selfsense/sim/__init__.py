"""selfsense.sim: the virtual tweezer (truth simulator of higher fidelity than the estimator).

Public API::

    simulate_dataset(scenario, seed, out_dir, truth_dir=None)        -> (out_dir, truth_dir)
    simulate_scenario_in_memory(scenario, seed=None, contributions=False) -> {trial: (log, truth)}
    simulate_trial(trial, device=None, effects=None, seed=0, index=0, ...) -> (log, truth)
    load_scenario(path | preset name | dict), load_device(path=None, overrides=None), EFFECTS

Never imports selfsense.sensing, selfsense.gap or selfsense.hysteresis.pi / .identify (the truth
must not share its forms with the estimator).  See docs/simulator.md.
"""
from .device import DeviceParams, default_device, load_device
from .effects import DEFAULT_EFFECTS, EFFECTS, OPEN_SET, resolve_effects
from .simulate import (LOG_COLUMNS, TRUTH_COLUMNS, load_scenario, rig_dict, simulate_dataset,
                       simulate_scenario_in_memory, simulate_trial)

__all__ = ["DeviceParams", "default_device", "load_device", "EFFECTS", "DEFAULT_EFFECTS", "OPEN_SET",
           "resolve_effects", "simulate_dataset", "simulate_scenario_in_memory", "simulate_trial",
           "load_scenario", "rig_dict", "LOG_COLUMNS", "TRUTH_COLUMNS"]
