"""One sensing core (selfsense.sensing.core): the batch estimator, the streaming kernel and the gap diagnostic's fast
estimator evaluate the same eqs. (27), (52), (55) and (57) of thesis 000_18d138f03f1777c3.txt, so with the same
coefficients, H(q) and input they give the same tip displacement and force."""
from __future__ import annotations

import numpy as np
import pytest

from selfsense.gap.standin import FastSensingEstimator
from selfsense.sensing.core import force_coefficients, force_regressor, tip_force
from selfsense.sensing.streaming import SelfSensingStream
from selfsense.signals import charge_from_shunt
from test_streaming import RIG, _fit, _raw, make_dataset


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("core")
    d = make_dataset(tmp)
    # raw estimates (no DC offset, no limiting): the three paths share eqs. 27 / 52, not the post-processing
    est, sigs = _fit(d, tmp, dc_offset=False, limit=False)
    return d, est, sigs


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b))) / max(float(np.ptp(b)), 1e-300)


def test_batch_streaming_and_gap_paths_give_the_same_tip_estimates(fitted):
    d, est, sigs = fitted
    c = est.coef_
    gap = FastSensingEstimator(rig=est.rig)  # the gap stand-in with the batch estimator's H and coefficients
    gap.hysteresis_ = est.hysteresis_
    gap.cd_ = np.array([c["A1"], c["A2"]])
    gap.cf_ = np.array([c["B21"], c["B22"]])
    stream = SelfSensingStream(est)
    for trial, sig in sigs.items():
        raw = _raw(d, trial)
        batch = est.estimate(sig)
        stream.reset()
        s = stream.process(raw["u_cmd"], raw["v_shunt"], raw["relay"], t=raw["t"], full=True)
        g = gap.estimate(sig)
        for col in ("dx", "f"):
            b = batch[f"{col}_raw"].to_numpy()
            assert np.ptp(b) > 0, f"{trial}: {col} does not move"
            assert _rel(s[f"{col}_raw"], b) <= 1e-9, (trial, col, "streaming")
            assert _rel(g[f"{col}_hat"], b) <= 1e-9, (trial, col, "gap")
        assert _rel(g["V_p"], batch["V_p"]) <= 1e-9
    # eq. (52): the force row through its one regressor equals the B21 / B22 form
    q, vp = sigs["obj_val"]["q"].to_numpy(), batch["V_p"].to_numpy()
    A3, n_A, C_p = c["A3"], RIG["n_actuators"], RIG["actuator_catalog"]["capacitance_f"]
    B21, B22 = force_coefficients(A3, n_A, C_p)
    assert _rel(A3 / n_A * force_regressor(q, vp, n_A, C_p), tip_force(q, vp, B21, B22)) <= 1e-12


def test_batch_and_streaming_charge_integrators_are_the_same_rule(fitted):
    """Eq. (57): the batch integral (``charge_from_shunt``) and the streaming per-sample recursion agree to 1e-12 of
    the charge range on an uneven time grid, and a constant current integrates to ``i (t - t_open)``."""
    d, est, sigs = fitted
    raw = _raw(d, "obj_val")
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, len(raw)))  # uneven sampling
    v_shunt, relay = raw["v_shunt"].to_numpy(), raw["relay"].to_numpy()
    R, g = RIG["shunt_resistance_ohm"], RIG["inamp_gain"]
    q_batch, off = charge_from_shunt(t, v_shunt / g, relay, R)
    s = SelfSensingStream(est).process(raw["u_cmd"], v_shunt, relay, t=t, full=True)
    assert np.ptp(q_batch) > 0
    assert _rel(s["q"], q_batch) <= 1e-12
    # a current step to I when the relay opens: the trapezoidal rule puts the step half-way through the first open
    # interval, q = I (t - t_open) with t_open = (t[k0-1] + t[k0]) / 2
    I = 2.0e-6
    vs = np.where(relay == 1, off, off + I * R)
    q_const, _ = charge_from_shunt(t, vs, relay, R, offset=off)
    k0 = int(np.argmax(relay == 0))
    np.testing.assert_allclose(q_const[k0:], I * (t[k0:] - 0.5 * (t[k0 - 1] + t[k0])), rtol=1e-9)
    assert np.all(q_const[:k0] == 0.0)
