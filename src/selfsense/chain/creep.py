"""The creep member of the load link: charge-free creep strain at the tip outputs.

A PZT stack keeps straining for seconds to minutes after a voltage step while its charge barely moves: the creep of
the ceramic's domain walls under a held field and stress. The Goldfarb-Celanovic two-port (thesis
``000_18d138f03f1777c3.txt`` eqs. 24-27, 46, 52) maps the charge ``Q`` and the piezo voltage ``V_p`` to the tip; a
strain that the charge does not see is outside it. The gap diagnostic names it ``slow.creep`` (docs/gap.md: after a
step the tip keeps moving while the charge does not).

**Form.** Model the creep strain ``x_cr`` as a linear viscoelastic response to the elastic strain, which is a
combination of ``Q`` and ``V_p`` (the charge equation of the two-port: ``q = n alpha x_el + n C_p V_p``), written as a
Prony series of first-order lags on a fixed log-spaced grid ``CREEP_TAUS_S`` (not the time constants of any one
device; the grid spans the trial lengths), of which the lags the calibration trials can identify are kept
(:func:`identifiable_taus`: no longer than three times the longest calibration trial)::

    x_cr = sum_tau  a_tau LP_tau[Q] + b_tau LP_tau[V_p]

The lags start at rest (the relay short holds Q and V at 0). Each lag is written ``LP_tau[s] - s``
(:func:`creep_columns`): the ``s`` part is the creep's steady share, which the sensing coefficients A1, A2 already
carry, so the bank only adds the transient and the member is the two-port unchanged after a long hold. ``x_cr`` adds
to the actuator's displacement; the mechanism passes it to the tip displacement and the tip force alike (both are
linear in the actuator's force and displacement), so one creep signal ``s_cr = K beta`` enters both outputs::

    dx = A1 Q + A2 V_p + K beta            (thesis eq. 52 + the bank)
    f  = B21 Q + B22 V_p + kappa K beta     (thesis eq. 46 / 52 + the same signal, one coefficient)

**Identification** (``SelfSensingEstimator.fit_coefficients``): ``beta`` jointly with A1, A2 on the displacement
calibration rows (the free-tip laser rows and the blocked tip's ``dx = 0`` rows, which fix the combination of Q and
V_p that creeps); ``kappa`` jointly with the force coefficients on the force rows (the blocked tip's load cell and the
free tip's ``f = 0``). Adopted where the bank lowers the displacement rows' blocked-CV error (contiguous blocks of
every calibration trial, as the H(q) selection) by more than :data:`CREEP_MIN_GAIN`; the gate was set before the
member was scored and is not tuned (measured in docs/gap.md, "The creep member").

**Streaming.** Every column is a first-order recursion ``y_n = a y_{n-1} + (1 - a) s_n``, ``a = exp(-dt / tau)``
(exact for a piecewise-constant input, the recursion of :func:`selfsense.chain.charge.absorption_column`): two
states per lag, carried sample by sample.
"""
from __future__ import annotations

import numpy as np

__all__ = ["CREEP_TAUS_S", "CREEP_MIN_GAIN", "OFFSET_DRIFT_BESIDE_CREEP_GAIN", "creep_columns", "creep_supported",
           "identifiable_taus", "TAU_MAX_PER_RECORD"]

#: the bank's lags [s]: log-spaced over the lengths of a calibration trial (tens of seconds)
CREEP_TAUS_S = (0.3, 1.0, 3.0, 10.0, 30.0)

#: a lag of the bank is kept while it is at most this many times the longest calibration trial
#: (:func:`identifiable_taus`)
TAU_MAX_PER_RECORD = 3.0

#: the bank must lower the displacement rows' blocked-CV error by more than this fraction to be adopted (it adds up to
#: 2 x 5 columns: a gain the size of the offset-drift member's 1 % is within what ten free columns give by chance)
CREEP_MIN_GAIN = 0.10

#: where the creep member is carried, the offset-drift member is kept only if it lowers the displacement rows'
#: blocked-CV error (with the bank) by more than this fraction against the chain calibrated without it (H(q) fitted
#: again with the member off: ``SelfSensingEstimator.fit_coefficients``). Chosen on the development cases of the tip campaign
#: (seed 8080 cases 155, 188, 271; seed 20261209 case 43: no offset drift in the device, the member adopted by the
#: H(q) fit; beside the bank it lowered that error by -60 to 12 %, and dropping it took the contact trials'
#: displacement from 12.7-37.1 % to 2.4-5.4 %), then scored on fresh devices (docs/gap.md, "The creep member")
OFFSET_DRIFT_BESIDE_CREEP_GAIN = 0.25


def creep_columns(Q: np.ndarray, V_p: np.ndarray, dt: float, taus=CREEP_TAUS_S) -> np.ndarray:
    """``[LP_tau[Q] - Q, LP_tau[V_p] - V_p for tau in taus]`` (n x 2 len(taus)), every lag from rest (module
    docstring)."""
    from selfsense.chain.charge import absorption_column

    Q, V_p = np.asarray(Q, float), np.asarray(V_p, float)
    if not dt > 0.0:
        raise ValueError(f"creep_columns: the sample period must be positive, found {dt!r}")
    cols = []
    for tau in taus:
        for s in (Q, V_p):
            cols.append(absorption_column(s, dt, float(tau)) - s)
    return np.column_stack(cols) if cols else np.zeros((len(Q), 0))


def identifiable_taus(durations_s, taus=CREEP_TAUS_S) -> tuple:
    """The lags of the bank that the calibration trials can identify: those no longer than
    :data:`TAU_MAX_PER_RECORD` times the longest calibration trial of the displacement rows (``durations_s`` [s]).

    Over a record of length ``T << tau`` a lag from rest is ``LP_tau[s] ~ (1/tau) int s dt``, so its column
    ``LP_tau[s] - s`` is ``-s`` plus a small integral: fitted beside A1 Q + A2 V_p it is told apart only through a
    coefficient of order ``tau / T`` that the two-port's coefficients cancel (terms up to 1e10 times the range were
    measured on 1.6-s trials with the 10- and 30-s lags), and that cancellation is extrapolated to every longer
    validation trial. At ``tau = 3 T`` the lag's step response over the record still departs from its straight-line
    (integral) approximation by 15 % of its value (``1 - exp(-1/3) = 0.28`` against ``1/3``), and the coefficients stay
    of the order of the signals. A lag the calibration cannot identify is left out rather than regularised: a statement
    about the calibration data, reported with the member (``taus_s``)."""
    longest = max((float(d) for d in durations_s), default=0.0)
    # (a relative 1e-9 for the rounding of n * dt: a 10-s record at 400 Hz measures 9.9999999999998 s). The bound
    # is a sharp edge where a calibration trial is exactly a third of a lag (the gap diagnostic's 10-s tip cases and
    # the 30-s lag): one sample less and that lag is left out.
    return tuple(float(t) for t in taus if t <= TAU_MAX_PER_RECORD * longest * (1.0 + 1e-9))


def creep_supported(cv_with: float, cv_without: float) -> bool:
    """The bank is adopted when it lowers the blocked-CV error by more than :data:`CREEP_MIN_GAIN`."""
    return bool(np.isfinite(cv_with) and cv_with < (1.0 - CREEP_MIN_GAIN) * cv_without)
