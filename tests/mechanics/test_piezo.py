"""Piezo + mechanism model (thesis eqs. 24-27, 44-59; paper 001_972cacfaa08ad91a.txt eqs. 13-23)."""
import numpy as np
import pytest

from selfsense.mechanics import piezo
from selfsense.mechanics.device import default_tweezer_mechanics

RNG = np.random.default_rng(7)
DEV = default_tweezer_mechanics()
P = DEV._p  # (S1, S2, S3, alpha, Cp, k, n_A)


def test_piezo_matrix_reproduces_eqs_24_26():
    alpha, Cp, k = 2.35, 0.3e-6, 24e6
    for _ in range(5):
        x, Vp = RNG.normal() * 1e-5, RNG.uniform(0, 150)
        q = piezo.charge(alpha, x, Cp, Vp)
        X, F = piezo.piezo_matrix(alpha, Cp, k) @ [q, Vp]
        assert X == pytest.approx(x, rel=1e-9)
        F_ext = k * x - alpha * Vp                       # eq. (26) solved for F
        assert piezo.pzt_displacement(alpha, F_ext, Vp, k) == pytest.approx(x, rel=1e-9)
        assert F == pytest.approx(-F_ext, rel=1e-9, abs=1e-9)  # (44) negates F
    assert np.linalg.det(piezo.piezo_matrix(alpha, Cp, k)) == pytest.approx(1.0)
    assert float(piezo.actuator_voltage(100.0, 20.0)) == 120.0


def test_eq45_product_equals_printed_closed_form():
    for _ in range(5):
        S = (RNG.uniform(1e7, 1e9), RNG.uniform(1e-3, 1e2), -RNG.uniform(1e3, 1e6))
        args = (*S, RNG.uniform(1, 3), RNG.uniform(1e-7, 1e-6), RNG.uniform(1e7, 5e7), 5)
        M = piezo.tip_matrix(*args)
        assert np.allclose(M, piezo.tip_matrix_closed_form(*args), rtol=1e-10, atol=0)
        c = piezo.a_coefficients(*args)
        assert np.allclose(M, [[c["A1"], c["A2"]], [c["B21"], c["B22"]]], rtol=1e-10, atol=0)
        assert np.allclose(piezo.tip_matrix(*args, convention="contract"), M * [[1], [-1]], rtol=0)
    with pytest.raises(ValueError, match="convention"):
        piezo.tip_matrix(*args, convention="pinch")


@pytest.mark.parametrize("env", [dict(), dict(blocked=True), dict(k_env=30.0), dict(k_env=200.0, gap=2e-3),
                                 dict(k_env=np.inf, gap=3e-3)])
def test_sensing_identity_holds_for_every_environment(env):
    """The exact map (45) recovers tip displacement/force from (q_total, V_p) whatever the load."""
    Vp = np.linspace(0, 150, 7)
    r = DEV.solve(Vp, **env)
    dx, f = DEV.sense(r["q"], Vp)
    assert np.allclose(dx, r["dx_tip"], rtol=1e-9, atol=1e-15)
    assert np.allclose(f, r["f_tip"], rtol=1e-9, atol=1e-12)
    assert np.all(r["f_tip"] >= -1e-12)           # object can only push back (pinch >= 0)
    if "k_env" in env and np.isfinite(env["k_env"]):
        assert np.allclose(r["f_tip"], env["k_env"] * np.maximum(r["dx_tip"] - env.get("gap", 0.0), 0),
                           rtol=1e-9, atol=1e-12)


def test_approximation_52_is_f_equals_S3_xpzt_and_fails_when_free():
    S1, S2, S3, alpha, Cp, k, n_A = P
    Vp = 150.0
    for env in (dict(), dict(blocked=True), dict(k_env=20.0)):
        r = DEV.solve(Vp, **env)
        c = piezo.a_coefficients(*P)
        # S2 (A1 q + A2 Vp) == S2 dx_tip exactly (paper eq. 17)
        assert S2 * (c["A1"] * r["q"] + c["A2"] * Vp) == pytest.approx(S2 * r["dx_tip"], rel=1e-9)
        # (52) second row == S3 x_pzt (thesis sign) i.e. pinch force -S3 x_pzt
        approx = c["A3"] / n_A * r["q"] - Cp * c["A3"] * Vp
        assert approx == pytest.approx(S3 * r["x_pzt"], rel=1e-9)
    blocked = DEV.blocked(Vp)
    assert -(c["A3"] / n_A * blocked["q"] - Cp * c["A3"] * Vp) == pytest.approx(blocked["f_tip"], rel=1e-9)
    free = DEV.free(Vp)
    # approximation predicts ~0.1 N pinching for a free tip: 100 % of the range
    assert abs(S3 * free["x_pzt"]) > 0.9 * float(blocked["f_tip"])
    t = piezo.approximation_terms(*P)
    assert t["ratio_21"] > 10 and t["ratio_22"] > 10   # neglected terms dominate for a consistent S set
    # eq. (54) q = Cp Vp is violated by alpha x_pzt per actuator
    assert free["q"] / n_A - Cp * Vp == pytest.approx(alpha * free["x_pzt"], rel=1e-9)


def test_S_from_measurements_recovers_mechanism():
    Vp = 150.0
    fr, bl = DEV.free(Vp), DEV.blocked(Vp)
    f_in_block = float(bl["F_in"]) / DEV.n_A
    S = piezo.S_from_measurements(f_in_block, float(bl["x_pzt"]), float(fr["dx_tip"]), float(fr["x_pzt"]),
                                  float(bl["f_tip"]), n_A=DEV.n_A)
    assert np.allclose(S, P[:3], rtol=1e-9)
    S_pr = piezo.S_from_measurements(f_in_block, float(bl["x_pzt"]), float(fr["dx_tip"]), float(fr["x_pzt"]),
                                     float(bl["f_tip"]), n_A=DEV.n_A, eq50="printed")
    assert S_pr[1] * S[1] == pytest.approx(1.0, rel=1e-9)   # printed (50) is the reciprocal [m/N]
    with pytest.raises(ValueError, match="eq50"):
        piezo.S_from_measurements(1, 1, 1, 1, 1, eq50="x")


def test_table2_recompute_disagrees_with_printed_table():
    r = piezo.table2_recompute()
    assert r["S"]["from_a_printed50"][0] == pytest.approx(2e8)       # S1 matches printed 2(b) (n_A * 200 N / 5 um)
    assert r["S"]["from_a_printed50"][2] == pytest.approx(-2e4)      # printed -2e5: factor 10
    assert r["S"]["from_a_corrected50"][1] == pytest.approx(0.1 * 7e-6 / (5e-6 * 6.4e-3))
    c_b = r["c"]["from_printed_b"]
    assert c_b["A1"] == pytest.approx(200.0)                          # printed -1000
    assert c_b["S3_over_nA_alpha"] == pytest.approx(-2.5e4)           # printed -2500
    assert c_b["Cp_S3_over_alpha"] == pytest.approx(-0.03125)         # printed +3.1e-3
    pr = r["c"]["printed"]
    assert np.sign(c_b["A1"]) != np.sign(pr["A1"])


def test_onsite_calibration_paper_eq23():
    # paper Table I
    B = piezo.onsite_B(10e-6, 6.3e-3)
    assert B == pytest.approx(1.59e-3, rel=3e-3)
    assert 2.35 * B * 84 == pytest.approx(0.3133, rel=1e-3)
    # on the simulated free trial with a known hysteresis voltage, (23) recovers H exactly, (55) does not
    S1, S2, S3, alpha, Cp, k, n_A = P
    V = np.linspace(0, 150, 11)
    H_true = 8.0 * np.sin(V / 40.0)
    Vp = V - H_true
    fr = DEV.free(Vp)
    q_per = fr["q"] / n_A
    A_q = float(piezo.onsite_A_q(fr["dx_tip"][-1], q_per[-1]))
    B = float(piezo.onsite_B(fr["x_pzt"][-1], fr["dx_tip"][-1]))
    H23 = V - piezo.onsite_h_slope(alpha, B, A_q, Cp) * q_per
    assert np.allclose(H23, H_true, atol=1e-9)
    # total-charge form with C_p_total gives the same (CONTRACTS.md)
    assert np.allclose(V - piezo.onsite_h_slope(alpha, B, A_q, Cp) * fr["q"] / (n_A * Cp) * Cp, H23)
    H55 = V - q_per / Cp
    assert np.max(np.abs(H55 - H_true)) > 20.0   # thesis (55) is off by alpha x_pzt / Cp (~78 V at 150 V)
    # mixing per-actuator alpha with total-charge A_q is wrong
    A_q_tot = float(fr["dx_tip"][-1] / fr["q"][-1])
    assert not np.allclose(V - piezo.onsite_h_slope(alpha, B, A_q_tot, Cp) * q_per, H_true, atol=1.0)


def test_fig38_limit_eqs_58_59():
    """Mechanism with zero free-tip input stiffness (S1 S2 = S3^2) reduces to Fig. 38."""
    alpha, Cp, k, n_A, V = 2.0, 0.3e-6, 24e6, 5, 100.0
    S2, S3 = 10.0, -2e4
    S1 = S3 ** 2 / S2                       # = k1 * n_A
    r = piezo.free_blocked_response(S1, S2, S3, alpha, Cp, k, n_A, V)
    f_pzt = alpha * V
    assert r["x_pzt_free"] == pytest.approx(f_pzt / k, rel=1e-9)                 # eq. (58)
    assert r["x_pzt_block"] == pytest.approx(f_pzt / (k + S1 / n_A), rel=1e-9)   # eq. (59)


def test_zero_coupling_and_rigid_limits():
    alpha, Cp, k, n_A, V = 2.35, 0.3e-6, 24e6, 5, 150.0
    r = piezo.free_blocked_response(6e7, 16.0, -1e-6, alpha, Cp, k, n_A, V)
    assert abs(r["f_tip_block"]) < 1e-9 and abs(r["rel_diff_x_pzt"]) < 1e-9
    # very stiff mechanism input: PZT cannot move
    r = piezo.free_blocked_response(1e15, 1e9, -1e11, alpha, Cp, k, n_A, V)
    assert r["x_pzt_free"] < 1e-8 * alpha * V / k * 1e3


def test_pzt_to_tip_sensitivity_linear_and_consistent():
    s = piezo.pzt_to_tip_sensitivity(*P, dV_p=1.0, dq=0.0)
    M = DEV.tip_matrix()
    assert s["d_f_tip"] == pytest.approx(M[1, 1]) and s["d_dx_tip"] == pytest.approx(M[0, 1])
    s2 = piezo.pzt_to_tip_sensitivity(*P, dV_p=np.array([1.0, -2.0]), dq=np.array([1e-6, 0.0]))
    assert np.allclose(s2["d_f_tip"], [M[1, 1] + 1e-6 * M[1, 0], -2 * M[1, 1]])
    # a 1 V error at the PZT moves f_tip by tens of percent of the 0.1 N range
    assert 0.2 < abs(s["f_per_V"]) * 1.0 / 0.1 < 1.0


def test_force_row_is_eq46_and_reduces_to_eq52_without_tip_stiffness():
    """force_row gives the exact (B21, B22) of eq. (46) (f = S3 x_pzt + S2 dx_tip on every environment) and, with
    S2 = 0, the eq. (52) pair (A3 / n_A, -C_p A3)."""
    dev = default_tweezer_mechanics()
    c = dev.a_coefficients()
    B21, B22 = piezo.force_row(c["A1"], c["A2"], c["A3"], dev.S2, dev.n_A, dev.Cp)
    M = dev.tip_matrix("thesis")
    assert B21 == pytest.approx(M[1, 0], rel=1e-12) and B22 == pytest.approx(M[1, 1], rel=1e-12)
    assert piezo.force_row(c["A1"], c["A2"], c["A3"], 0.0, dev.n_A, dev.Cp) == pytest.approx(
        (c["A3"] / dev.n_A, -dev.Cp * c["A3"]), rel=1e-12)
