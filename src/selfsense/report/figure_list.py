"""The pipeline's figures (:mod:`selfsense.report.figures`) by file stem, with their thesis and paper counterparts and
titles. A module without matplotlib: the HTML report orders its figures by this table, and it runs inside the
Snakemake process as the pipeline's last job, where importing the plotting module (matplotlib.pyplot) took 0.45 of
its 0.5 s."""
from __future__ import annotations

__all__ = ["FIGURES"]

#: figure file stem -> (thesis figure, paper figure, title), in the report's order
FIGURES = {
    "fig17_voltage_charge": ("Fig. 17", "Fig. 8", "Hysteresis between actuator voltage and charge, with minor loops"),
    "fig21_h_calibration": ("Fig. 21", "Fig. 12", "Hysteresis operator H(q) calibration on the free-tip trial"),
    "fig22_input_sine": ("Fig. 22", "-", "Sinusoidal driving voltage"),
    "fig23_input_mixed": ("Fig. 23", "-", "Mixed trapezoidal and sinusoidal driving voltage"),
    "fig24_limiting_dc_offset": ("Fig. 24", "Fig. 13", "Effect of limiting and sliding DC offset"),
    "fig25-30_displacement_trials": ("Figs. 25-30", "Fig. 14",
                                     "Self-sensed vs reference tip displacement, validation trials"),
    "fig31-36_force_trials": ("Figs. 31-36", "Fig. 15", "Self-sensed vs reference tip force, validation trials"),
    "fig37_force_displacement": ("Fig. 37", "-", "Force and displacement self-sensed on one time axis"),
    "fig39_mismatch_subtraction": ("Fig. 39", "Fig. 17", "Effect of hysteresis model mismatch (free-case subtraction)"),
    "cal_displacement_trials": ("-", "-", "Self-sensed vs reference tip displacement on the calibration trials"),
    "cal_force_trials": ("-", "-", "Self-sensed vs reference tip force on the calibration trials"),
}
