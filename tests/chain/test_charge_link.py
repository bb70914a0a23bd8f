"""The charge link of the stage chain (selfsense.chain.charge): the leakage column, the hold evidence, and the
estimator carrying the members the evidence supports without reading any validation reference."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from selfsense.chain.charge import find_holds, hold_evidence, leak_column

C = 2e-6  # actuator capacitance [F]


def _trial(levels, hold_s, g, *, relax_tau=1.0, relax_frac=0.02, offset_rate=0.0, seed=0, fs=200.0, ramp_s=0.5):
    """V steps through ``levels`` with holds of ``hold_s``; measured charge = C V + a first-order relaxation of
    ``relax_frac`` C V (time constant ``relax_tau``) + g int V dt + an offset charge ramp + noise."""
    rng = np.random.default_rng(seed)
    knots_t, knots_v, t0, _v0 = [0.0], [0.0], 0.0, 0.0
    for lev in levels:
        t0 += ramp_s
        knots_t.append(t0); knots_v.append(lev)
        t0 += hold_s
        knots_t.append(t0); knots_v.append(lev)
    t = np.arange(0.0, t0, 1.0 / fs)
    V = np.interp(t, knots_t, knots_v)
    a = np.exp(-1.0 / fs / relax_tau)
    from scipy.signal import lfilter

    lp = lfilter([1 - a], [1, -a], V)
    q = C * V + relax_frac * C * lp + g * leak_column(V, 1.0 / fs) + offset_rate * t
    q = q + 1e-10 * rng.standard_normal(len(t))
    return pd.DataFrame({"t": t, "V": V + 2e-3 * rng.standard_normal(len(t)), "q": q, "relay": np.zeros(len(t))})


def test_leak_column_is_the_trapezoid_integral():
    t = np.linspace(0.0, 2.0, 2001)
    V = 3.0 + np.sin(2 * np.pi * t)
    iv = leak_column(V, t[1] - t[0])
    assert iv[0] == 0.0
    # int_0^2 (3 + sin) dt = 6 exactly; trapezoid error O(dt^2)
    assert iv[-1] == pytest.approx(6.0, abs=1e-5)
    np.testing.assert_allclose(np.diff(iv), 0.5 * (V[1:] + V[:-1]) * (t[1] - t[0]))


def test_find_holds_finds_each_level_and_ignores_ramps():
    df = _trial([50.0, 0.0, 100.0], 3.0, 0.0)
    holds = find_holds(df["t"].to_numpy(), df["V"].to_numpy())
    levels = [float(np.mean(df["V"].to_numpy()[a:b])) for a, b in holds]
    assert len(holds) == 3
    np.testing.assert_allclose(levels, [50.0, 0.0, 100.0], atol=0.5)
    t = df["t"].to_numpy()
    assert all(t[b - 1] - t[a] >= 2.0 for a, b in holds)


def test_long_holds_recover_the_leakage_conductance():
    g = 20e-9
    trials = {f"tr{k}": _trial([50.0, 0.0, 100.0, 0.0, 75.0], 20.0, g, seed=k, offset_rate=(k - 1) * 2e-10)
              for k in range(3)}
    ev = hold_evidence(trials)
    assert ev.supported, ev.note
    assert ev.g_s == pytest.approx(g, rel=0.1)
    assert ev.n_trials == 3 and ev.n_levels >= 3


def test_no_leakage_is_not_supported():
    trials = {f"tr{k}": _trial([50.0, 0.0, 100.0, 0.0, 75.0], 20.0, 0.0, seed=k) for k in range(3)}
    ev = hold_evidence(trials)
    assert not ev.supported
    assert abs(ev.g_s) < 1e-9


def test_holds_bound_the_conductance_they_do_not_measure():
    """Without leakage, the holds' upper bound (estimate + 4 standard errors, with and without the slow relaxation
    column) is small against the 20 nS the long holds recover on a leaky device, and that device's bound covers its g."""
    from selfsense.chain.charge import leakage_upper_bound

    clean = hold_evidence({f"tr{k}": _trial([50.0, 0.0, 100.0, 0.0, 75.0], 20.0, 0.0, seed=k) for k in range(3)})
    ub = leakage_upper_bound(clean.to_dict())
    assert ub is not None and 0.0 < ub < 1e-9
    assert np.isfinite(clean.g_slow_se_s) and clean.g_slow_se_s > 0
    g = 20e-9
    leaky = hold_evidence({f"tr{k}": _trial([50.0, 0.0, 100.0, 0.0, 75.0], 20.0, g, seed=k) for k in range(3)})
    assert leakage_upper_bound(leaky.to_dict()) >= g


def test_slow_relaxation_over_short_holds_is_not_called_leakage():
    """A 10 s relaxation seen through 1 s holds looks like a charge ramp at every level: the identifiability check
    refuses it and says which measurement would separate the two."""
    trials = {f"tr{k}": _trial([100.0, 0.0, 60.0, 0.0, 100.0, 30.0], 1.0, 0.0, relax_tau=10.0, relax_frac=0.2,
                               seed=k) for k in range(3)}
    ev = hold_evidence(trials)
    assert not ev.supported
    assert "not supported" in ev.note


def test_without_holds_the_evidence_says_so():
    t = np.arange(0.0, 10.0, 1e-3)
    V = 50 + 50 * np.sin(2 * np.pi * 0.5 * t)
    df = pd.DataFrame({"t": t, "V": V, "q": C * V, "relay": np.zeros(len(t))})
    ev = hold_evidence({"sine": df})
    assert not ev.supported and ev.n_holds == 0
    assert "no hold" in ev.note


def test_relay_short_is_excluded():
    """Samples while the relay shorts the leads are not a hold of the drive."""
    df = _trial([50.0, 0.0, 100.0], 3.0, 0.0)
    n = len(df)
    relay = np.zeros(n)
    relay[: n // 2] = 1.0
    df["relay"] = relay
    ev_all = hold_evidence({"a": df.assign(relay=0.0)})
    ev_half = hold_evidence({"a": df})
    assert ev_half.n_holds < ev_all.n_holds


def test_offset_bases_integrate_hat_functions():
    """The wandering-offset columns are the running integrals of hat functions (a piecewise-linear offset current
    integrated into charge), zero at the relay release."""
    from selfsense.chain.charge import offset_bases

    t = np.linspace(0.0, 10.0, 10001)
    B = offset_bases(t, 10.0)
    assert set(B) >= {"ramp", "wander2", "wander4", "wander8"}
    knots = np.linspace(0.0, 10.0, 6)
    h = knots[1] - knots[0]
    for j, kn in enumerate(knots):
        hat = np.clip(1 - np.abs(t - kn) / h, 0, None)
        ci = np.concatenate([[0.0], np.cumsum(0.5 * (hat[1:] + hat[:-1]) * (t[1] - t[0]))])
        np.testing.assert_allclose(B["wander4"][:, j], ci / np.max(ci), atol=1e-6)
    assert np.all(B["wander8"][0] == 0.0)


@pytest.mark.parametrize("kind", ["ramp", "wander"])
def test_offset_form_is_chosen_by_held_out_rests(kind):
    """Rest residuals from a thermal ramp keep the ramp; from an offset that reverses twice, a wander form wins."""
    from selfsense.chain.charge import offset_bases, select_offset_form

    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 20.0, 4001)
    rest = (np.sin(2 * np.pi * 0.4 * t) < -0.8)  # rests once per cycle, spread over the trial
    runs = np.cumsum(np.diff(np.concatenate([[0], rest.astype(int)])) == 1)[rest]
    if kind == "ramp":
        dq = 1e-8 * (0.3 * t + 0.05 * t * t)
    else:
        dq = 1e-7 * np.sin(2 * np.pi * t / 13.0)
    sens = np.full(rest.sum(), 2e6)  # V per C
    r0 = (sens * dq[rest]) + 1e-4 * rng.standard_normal(rest.sum())
    form, cv = select_offset_form(-r0, sens, {n: b[rest] for n, b in offset_bases(t, 20.0).items()}, runs)
    assert (form == "ramp") == (kind == "ramp"), cv


def _with_quantised_shunt(df, R, step, noise_steps, seed=0):
    """The trial with a shunt channel: ``R dq/dt`` plus an in-amp offset of a third of a step, noise of
    ``noise_steps`` steps, rounded to the ADC step."""
    t = df["t"].to_numpy(float)
    i = np.concatenate([[0.0], np.diff(df["q"].to_numpy(float)) / np.diff(t)])
    rng = np.random.default_rng(seed)
    vs = R * i + step / 3 + noise_steps * step * rng.standard_normal(len(t))
    return df.assign(V_s=np.round(vs / step) * step)


def test_holds_below_an_undithered_adc_step_do_not_support_leakage():
    """A leakage of 2 nS draws 0.2 uA at 100 V: measured by a channel whose undithered step is 1 uA, the holds' charge
    slopes are off by up to half a step, so the evidence is not supported (and no measured g is handed to the
    calibration's bound); with dither or a 50x finer step (4 steps = 0.08 uA) the holds resolve it."""
    from selfsense.sensing.estimator import leakage_measured_by_holds

    g, R = 2e-9, 1000.0
    base = {f"tr{k}": _trial([50.0, 0.0, 100.0, 0.0, 75.0], 20.0, g, seed=k) for k in range(3)}
    assert hold_evidence(base).supported
    coarse = {k: _with_quantised_shunt(v, R, 1e-3, 0.1, seed=i) for i, (k, v) in enumerate(base.items())}
    ev = hold_evidence(coarse, R=R)
    assert not ev.supported and not ev.resolved
    assert ev.resolution_floor_a == pytest.approx(1e-6)
    assert "resolves" in ev.note and "ADC step" in ev.note
    assert leakage_measured_by_holds(ev.to_dict()) is None
    for step, noise in ((2e-5, 0.1), (1e-3, 1.0)):
        fine = {k: _with_quantised_shunt(v, R, step, noise, seed=i) for i, (k, v) in enumerate(base.items())}
        ev = hold_evidence(fine, R=R)
        assert ev.resolved, (step, noise, ev.note)
    # without R (or without V_s) the channel's resolution is not assessed: the evidence is that of the charge alone
    assert hold_evidence(coarse).resolution_floor_a == 0.0
