"""Physics of the play, superposition and creep operators (000_18d138f03f1777c3.txt eqs. 29-41)."""

import numpy as np
import pytest

from selfsense.hysteresis import operators as op
from selfsense.hysteresis import reference as ref


def _walk(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(size=n)) * 0.3


def test_play_bounded_by_threshold():
    x = _walk(3000)
    r = np.array([0.0, 0.2, 1.0, 3.0])
    H = op.play_operator(x, r, z0=np.array([5.0, -5.0, 0.0, 10.0]))
    assert np.all(np.abs(H - x[:, None]) <= r[None, :] + 1e-13)  # rounding of x -+ r at |x| ~ 30
    assert np.array_equal(H[:, 0], x)  # r = 0 is the identity


def test_kernels_match_reference():
    x = _walk(400, 1)
    r = np.array([0.0, 0.1, 0.5, 2.0])
    z0 = np.array([0.3, -1.0, 2.0, 0.0])
    np.testing.assert_allclose(op.play_operator(x, r, z0), ref.play_operator(x, r, z0), rtol=0, atol=1e-12)
    rs = np.array([-1.0, 0.0, 0.5, 2.0])
    np.testing.assert_allclose(op.superposition_operator(x, rs), ref.superposition_operator(x, rs), atol=1e-12)
    a = op.log_creep_eigenvalues(3, 1e-3)
    Z0 = np.arange(12.0).reshape(4, 3) / 10
    np.testing.assert_allclose(op.creep_operator(x, r, a, 1e-3, Z0), ref.creep_operator(x, r, a, 1e-3, Z0),
                               rtol=0, atol=1e-12)


def test_superposition_cases_eq33_corrected():
    x = np.array([-3.0, -1.0, 0.0, 1.0, 3.0])
    S = op.superposition_operator(x, [2.0, 0.0, -2.0])
    np.testing.assert_array_equal(S[:, 0], [0, 0, 0, 0, 1])  # max(x - 2, 0), eq. (34)
    np.testing.assert_array_equal(S[:, 1], x)
    np.testing.assert_array_equal(S[:, 2], [-1, 0, 0, 0, 0])  # min(x + 2, 0), corrected third case


def test_log_creep_eigenvalues_eq40():
    np.testing.assert_allclose(op.log_creep_eigenvalues(4, 2e-3), [500.0, 50.0, 5.0, 0.5])


def _pl_path(vertices, pts_per_segment):
    segs = [np.linspace(a, b, pts_per_segment + 1)[:-1] for a, b in zip(vertices[:-1], vertices[1:])]
    return np.r_[np.concatenate(segs), vertices[-1]]


def test_rate_independence():
    v = np.array([0.0, 4.0, 1.0, 3.0, -2.0, 2.5, 0.5])
    r = np.array([0.0, 0.5, 1.0, 2.0])
    for k1, k2 in ((7, 50), (3, 211)):
        y1 = op.play_operator(_pl_path(v, k1), r)
        y2 = op.play_operator(_pl_path(v, k2), r)
        np.testing.assert_allclose(y1[::k1], y2[::k2], atol=1e-12)  # same path, different speeds


def test_return_point_memory_and_wiping_out():
    r = np.linspace(0, 2, 8)
    w = np.linspace(1, 0.2, 8)
    up = np.linspace(0, 4, 41)
    minor = np.r_[np.linspace(4, 1.5, 26), np.linspace(1.5, 3.0, 16)]  # minor excursion inside [1.5, 4]
    back = np.linspace(3.0, 4.0, 11)
    tail = np.linspace(4.0, -1.0, 51)
    with_minor = np.r_[up, minor[1:], back[1:], tail[1:]]
    without = np.r_[up, tail[1:]]
    ya = op.play_sum(with_minor, r, w)
    yb = op.play_sum(without, r, w)
    n_up = len(up)
    k_ret = n_up - 1 + len(minor) - 1 + len(back) - 1
    assert ya[k_ret] == pytest.approx(ya[n_up - 1], abs=1e-12)  # return-point memory
    np.testing.assert_allclose(ya[k_ret:], yb[n_up - 1:], atol=1e-12)  # wiping-out
    assert not np.allclose(ya[n_up:k_ret], yb[n_up:n_up + k_ret - n_up])  # the excursion did change the output


def test_minor_loops_close():
    r = np.linspace(0, 2, 8)
    w = np.linspace(1, 0.2, 8)
    cycle = np.r_[np.linspace(1.0, 3.0, 30, endpoint=False), np.linspace(3.0, 1.0, 30, endpoint=False)]
    x = np.r_[np.linspace(0, 1.0, 10, endpoint=False), np.tile(cycle, 4)]
    y = op.play_sum(x, r, w)
    c1 = y[10 + 60:10 + 120]
    c3 = y[10 + 180:10 + 240]
    np.testing.assert_allclose(c1, c3, atol=1e-12)
    assert np.ptp(c1) > 0.5 and np.max(np.abs(y[10:70] - c1)) > 1e-3  # a real loop; first cycle is transient


def test_creep_bank_step_linear_in_log_t():
    dt = 1e-3
    m = 7
    a = op.log_creep_eigenvalues(m, dt)
    N = 10 ** 5 + 1
    x = np.ones(N)
    y = op.creep_operator(x, [0.0], a, dt).sum(axis=(1, 2))
    # y at t = 10^k dt for k = 1..4: increments per decade (log(t) creep) equal within 10 %
    t_idx = [10 ** k for k in range(1, 5)]
    inc = np.diff(y[t_idx])
    assert np.all(inc > 0)
    assert np.ptp(inc) / inc.mean() < 0.1
    # ... unlike a single eigenvalue, whose response saturates within two decades
    single = op.creep_operator(x, [0.0], a[2:3], dt)[:, 0, 0]
    inc1 = np.diff(single[t_idx])
    assert inc1[-1] < 0.01 * inc1.max()


def test_creep_zoh_exact_against_ode():
    from scipy.integrate import solve_ivp

    dt, a, r = 0.01, 37.0, 0.4
    rng = np.random.default_rng(5)
    x = np.repeat(rng.uniform(-2, 2, 12), 7)  # piecewise constant input
    y0 = 0.3
    yk = op.creep_operator(x, [r], [a], dt, [[y0]])[:, 0, 0]
    ya = [y0]
    y = y0
    for k in range(1, len(x)):
        xk = x[k - 1]  # held over [t_{k-1}, t_k)
        sol = solve_ivp(lambda t, s: a * np.maximum(xk - s - r, np.minimum(xk - s + r, 0.0)), (0, dt), [y],
                        method="DOP853", rtol=1e-12, atol=1e-14)
        y = sol.y[0, -1]
        ya.append(y)
    np.testing.assert_allclose(yk, ya, atol=1e-10)
    assert np.ptp(yk) > 0.5


def test_creep_hysteretic_equilibrium():
    # with a threshold, the creep operator settles anywhere within r of the held input (eq. 38 dead zone)
    dt = 1e-3
    x = np.r_[np.full(3000, 2.0), np.full(3000, 1.7)]
    y = op.creep_operator(x, [0.5], [100.0], dt)[:, 0, 0]
    assert y[2999] == pytest.approx(1.5, abs=1e-9)
    assert y[-1] == y[3001]  # |1.7 - 1.5| < 0.5: no motion


def test_bad_arguments():
    with pytest.raises(ValueError, match="thresholds"):
        op.play_operator([0.0, 1.0], [-1.0])
    with pytest.raises(ValueError):
        op.creep_operator([0.0, 1.0], [0.0], [0.0], 1e-3)
    with pytest.raises(ValueError, match="dt"):
        op.log_creep_eigenvalues(3, 0.0)
