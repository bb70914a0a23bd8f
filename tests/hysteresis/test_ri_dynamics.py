"""Vibration / creep sub-models and the integrated PEA model (002_7d89b7147aad52e4.txt eqs. 12, 13, 17)."""
import numpy as np
import pytest
import scipy.signal

from selfsense.hysteresis.ri import RIModel, diagonal_constraint_basis
from selfsense.hysteresis.ri_dynamics import (RIActuatorModel, VibrationModel, d2c_zoh, fit_arx, fit_arx_creep,
                                              fit_second_order_phase, force_from_displacement,
                                              second_order_phase)


def test_vibration_phase_fit_recovers_zeta_omega():
    f = np.geomspace(10, 5000, 25)
    ph = second_order_phase(f, 0.27, 2 * np.pi * 1800) + np.random.default_rng(0).normal(scale=1e-4, size=f.size)
    z, wn = fit_second_order_phase(f, ph)
    assert z == pytest.approx(0.27, rel=2e-3)
    assert wn == pytest.approx(2 * np.pi * 1800, rel=2e-3)


def test_vibration_exact_discretisation_and_inverse():
    vib = VibrationModel(0.3, 2 * np.pi * 500)
    dt = 1e-4
    f = np.ones(4000)
    x = vib.simulate(f, dt)
    assert x[-1] == pytest.approx(1.0, abs=1e-9)                    # unity DC gain
    ov = x.max() - 1.0
    assert ov == pytest.approx(np.exp(-0.3 * np.pi / np.sqrt(1 - 0.09)), rel=2e-2)  # step overshoot
    # eq. (12) inverted from x1 recovers a smooth f
    t = np.arange(4000) * dt
    f2 = 1 + np.sin(2 * np.pi * 20 * t)
    x2 = vib.simulate(f2, dt)
    fh = force_from_displacement(x2, dt, 0.3, 2 * np.pi * 500)
    assert np.max(np.abs(fh - f2)[1000:-100]) < 0.02
    with pytest.raises(ValueError, match="unstable"):
        force_from_displacement(x2, dt, 0.3, 2 * np.pi * 500, method="abg")


def test_arx_recovers_known_discrete_model_and_d2c_roundtrip():
    a = np.array([1.0, -2.2, 1.9, -0.74, 0.1])      # poles 0.6 +- 0.37j, 0.72, 0.28
    b = np.array([0.05, 0.03])
    u = np.random.default_rng(1).standard_normal(3000)
    y = scipy.signal.lfilter(np.r_[0.0, b], a, u)
    ah, bh = fit_arx(u, y)
    np.testing.assert_allclose(ah, a, atol=1e-10)
    np.testing.assert_allclose(bh, b, atol=1e-10)
    cr = fit_arx_creep(u, y, Ts=0.1)
    assert cr.den.size == 5 and cr.num.size <= 5         # eq. (17) form: 4 poles
    # c2d(d2c(G)) == G: simulating the continuous model at Ts reproduces the ARX output
    np.testing.assert_allclose(cr.simulate(u, 0.1), y, atol=1e-8)
    with pytest.raises(ValueError, match="negative real"):
        d2c_zoh([0, 1.0], [1.0, 0.5], 0.1)


def test_integrated_model_cascade():
    H = RIModel([0, 10, 0, 0, 0], diagonal_constraint_basis() @ np.r_[1.0, np.zeros(9)], input_scale=70.0)
    m = RIActuatorModel(H, 0.5, 2 * np.pi * 1000, creep=None)
    u = np.concatenate([np.linspace(0, 70, 2000), np.full(2000, 70.0)])
    x, parts = m.simulate(u, 5e-5, return_parts=True)
    assert x[-1] == pytest.approx(H(u)[-1], rel=1e-9)    # static: x = f = F(70)
    assert x[-1] == pytest.approx(10.0, rel=1e-9)
    with pytest.raises(ValueError, match="non-negative"):
        m.simulate(-u, 5e-5)
