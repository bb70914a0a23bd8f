"""Whole-device statics (thesis sec. 3.1, Table 1; paper Table I)."""
import numpy as np
import pytest

from selfsense.mechanics.device import TweezerMechanics, default_tweezer_mechanics, mechanism_from_targets


def test_default_device_matches_seed_numbers():
    m = default_tweezer_mechanics()
    r = m.free_blocked(150.0)
    assert 6.3e-3 * 0.9 <= float(r["dx_tip_free"]) <= 7e-3 * 1.1      # thesis 7 mm, paper 6.3 mm
    assert float(r["f_tip_block"]) == pytest.approx(0.1, rel=0.1)     # thesis 0.1 N
    assert float(r["x_pzt_free"]) == pytest.approx(10e-6, rel=0.1)    # paper Table I
    assert 0 < float(r["rel_diff_x_pzt"]) < 0.1                        # sec. 5.3: small free/blocked change
    o = m.onsite_parameters()
    assert o["B"] == pytest.approx(1.59e-3, rel=0.1)                  # paper Table I
    assert o["A_q"] == pytest.approx(84.0, rel=0.1)                    # paper Table I, m/C per actuator
    assert np.all(np.linalg.eigvalsh(m.stiffness_matrix()) > 0) and m.S3 < 0


def test_response_linear_in_Vp_and_monotone_in_load():
    m = default_tweezer_mechanics()
    Vp = np.array([0.0, 75.0, 150.0])
    fr = m.free(Vp)
    assert fr["dx_tip"][0] == 0 and fr["dx_tip"][2] == pytest.approx(2 * fr["dx_tip"][1])
    stroke = [float(m.solve(150.0, k_env=ke)["dx_tip"]) for ke in (0.0, 1.0, 10.0, 100.0, 1e4)]
    force = [float(m.solve(150.0, k_env=ke)["f_tip"]) for ke in (0.0, 1.0, 10.0, 100.0, 1e4)]
    assert np.all(np.diff(stroke) < 0) and np.all(np.diff(force) > 0)
    assert force[-1] < float(m.blocked(150.0)["f_tip"])
    assert float(m.solve(150.0, k_env=1e12)["f_tip"]) == pytest.approx(float(m.blocked(150.0)["f_tip"]), rel=1e-6)
    # rigid object with a gap larger than the free stroke: no contact
    r = m.solve(150.0, k_env=np.inf, gap=1.0)
    assert float(r["f_tip"]) == pytest.approx(0.0, abs=1e-15)


def test_roundtrip_and_validation():
    m = default_tweezer_mechanics()
    assert TweezerMechanics.from_dict(m.to_dict()) == m
    with pytest.raises(ValueError, match="PSD"):
        TweezerMechanics(S1=1.0, S2=1.0, S3=-10.0)
    with pytest.raises(ValueError, match="S3 must be < 0"):
        TweezerMechanics(S1=1e7, S2=10.0, S3=1e3)
    with pytest.raises(ValueError, match="infeasible"):
        mechanism_from_targets(6.3e-3, 10.0, 1e-6, 150.0, 2.35, 24e6, 5)
    with pytest.raises(ValueError, match="non-passive"):
        mechanism_from_targets(6.3e-3, 0.1, 20e-6, 150.0, 2.35, 24e6, 5)   # > alpha V / k = 14.7 um


def test_from_targets_hits_targets():
    m = TweezerMechanics.from_targets(dx_tip_free=7e-3, f_tip_block=0.1, dx_pzt_free=7e-6, alpha=1.6, Cp=0.25e-6)
    r = m.free_blocked(150.0)
    assert float(r["dx_tip_free"]) == pytest.approx(7e-3, rel=1e-9)
    assert float(r["f_tip_block"]) == pytest.approx(0.1, rel=1e-9)
    assert float(r["x_pzt_free"]) == pytest.approx(7e-6, rel=1e-9)


def test_array_environment_matches_scalar_solves():
    m = default_tweezer_mechanics()
    Vp = np.array([150.0, 150.0, 100.0, 150.0])
    ke = np.array([0.0, 50.0, np.inf, 1e3])
    gap = np.array([0.0, 1e-3, 2e-3, 9e-3])
    r = m.solve(Vp, k_env=ke, gap=gap)
    for i in range(4):
        ri = m.solve(Vp[i], k_env=ke[i], gap=gap[i])
        for key in ("x_pzt", "dx_tip", "f_tip", "q"):
            assert r[key][i] == pytest.approx(float(ri[key]), rel=1e-12, abs=1e-18)
    assert r["dx_tip"][2] == pytest.approx(2e-3)      # rigid object reached
    assert r["f_tip"][3] == 0.0                        # gap 9 mm > free stroke 6.3 mm
    with pytest.raises(ValueError, match="k_env"):
        m.solve(150.0, k_env=-1.0)
