"""ModifiedPI (000_18d138f03f1777c3.txt eqs. 36, 42) and its inverse (eqs. 79-80)."""

import json

import numpy as np
import pytest

from selfsense.hysteresis import reference as ref
from selfsense.hysteresis.operators import superposition_sum
from selfsense.hysteresis.pi import ModifiedPI, invert_superposition


def _model(dt=1e-3, seed=0, creep=True, z0=0.3):
    rng = np.random.default_rng(seed)
    nH = 8
    rH = np.linspace(0, 3, nH)
    wH = rng.uniform(0.1, 1, nH)
    rS = np.array([0.0, -2.0, -0.7, 0.8, 2.5, 5.0])
    wS = np.array([1.0, 0.3, 0.2, -0.3, -0.4, 0.5])  # saturating on the positive side, still increasing
    if creep:
        return ModifiedPI.with_log_creep(rH, wH, rS, wS, dt, rH, rng.uniform(0, 0.1, nH), 4, z_H0=z0,
                                         Z_K0=rng.uniform(-0.2, 0.2, (nH, 4)))
    return ModifiedPI(r_H=rH, w_H=wH, r_S=rS, w_S=wS, dt=dt, z_H0=z0)


def _input(n=3000, seed=1):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(size=n)) * 0.1 + np.repeat(rng.uniform(-2, 2, n // 100 + 1), 100)[:n]


def test_kernel_matches_reference():
    m = _model()
    x = _input(800)
    y = m(x)
    yr = ref.modified_pi(x, m.r_H, m.w_H, m.z_H0, m.r_K, m.w_K, m.a_K, m.Z_K0, m.r_S, m.w_S, m.dt, m.offset)
    np.testing.assert_allclose(y, yr, rtol=1e-12, atol=1e-12 * np.abs(yr).max())


@pytest.mark.parametrize("creep", [True, False])
def test_inverse_round_trip(creep):
    m = _model(creep=creep)
    x = _input()
    xi = m.inverse(m(x))
    assert np.max(np.abs(xi - x)) <= 1e-9 * np.max(np.abs(x))


def test_inverse_of_output_is_input_direction():
    m = _model()
    y = np.sin(np.linspace(0, 20, 2000)) * 3
    x = m.inverse(y)
    np.testing.assert_allclose(m(x), y, rtol=0, atol=1e-9 * 3)


def test_invert_superposition_eq79_80_one_sided():
    r = np.array([0.0, 1.0, 2.0])
    w = np.array([2.0, -0.5, 1.0])
    r_inv, w_inv = invert_superposition(r, w)
    # eq. (80): r_i = sum_j w'_j (r'_i - r'_j); eq. (79): w_i = -w'_i / (s_i s_{i-1})
    np.testing.assert_allclose(r_inv, [0.0, 2.0, 2 * 2 - 0.5 * 1])
    np.testing.assert_allclose(w_inv, [0.5, 0.5 / (1.5 * 2.0), -1.0 / (2.5 * 1.5)])
    u = np.linspace(-3, 5, 101)
    np.testing.assert_allclose(superposition_sum(superposition_sum(u, r, w), r_inv, w_inv), u, atol=1e-12)


def test_invert_superposition_two_sided_and_non_monotone():
    r = np.array([0.0, -1.5, -0.5, 0.5, 2.0])
    w = np.array([1.0, 0.4, -0.3, -0.5, 2.0])
    r_inv, w_inv = invert_superposition(r, w)
    u = np.linspace(-4, 4, 201)
    np.testing.assert_allclose(superposition_sum(superposition_sum(u, r, w), r_inv, w_inv), u, atol=1e-12)
    with pytest.raises(ValueError, match="not strictly increasing"):
        invert_superposition([0.0, 1.0], [1.0, -1.0])


def test_json_round_trip_exact():
    m = _model()
    d = json.loads(json.dumps(m.to_dict()))
    m2 = ModifiedPI.from_dict(d)
    assert m2.to_dict() == m.to_dict()
    x = _input(500)
    assert np.array_equal(m(x), m2(x))
    assert all(isinstance(v, float) for v in d["w_H"])


def test_streaming_equals_batch_exactly():
    m = _model()
    x = _input(2000)
    y = m(x)
    st = None
    parts = []
    for blk in np.split(x, [1, 7, 500, 1333]):
        yb, st = m.apply(blk, st)
        parts.append(yb)
    assert np.array_equal(np.concatenate(parts), y)
    xs, st = [], None
    for blk in np.split(y, [3, 900]):
        xb, st = m.apply_inverse(blk, st)
        xs.append(xb)
    assert np.array_equal(np.concatenate(xs), m.inverse(y))


def test_superposition_makes_saturating_loops():
    # a play sum alone steepens after a reversal; with a concave superposition the loop flattens near the top
    rH = np.linspace(0, 1, 6)
    wH = np.full(6, 0.2)
    x = np.r_[np.linspace(0, 2, 201), np.linspace(2, 0, 201)]
    plain = ModifiedPI(r_H=rH, w_H=wH, r_S=[0.0], w_S=[1.0], dt=1.0)(x)
    sat = ModifiedPI(r_H=rH, w_H=wH, r_S=[0.0, 0.6], w_S=[1.0, -0.8], dt=1.0)(x)
    s_plain, s_sat = np.diff(plain[:201]), np.diff(sat[:201])
    assert s_plain[-1] > s_plain[60]  # play sum: the branch only steepens
    assert s_sat[-1] < 0.5 * s_sat[60]  # concave superposition: the branch flattens (saturates)


def test_invalid_models():
    with pytest.raises(ValueError, match="zero threshold"):
        ModifiedPI(r_H=[0.0], w_H=[1.0], r_S=[1.0], w_S=[1.0], dt=1.0)
    with pytest.raises(ValueError, match="dt"):
        ModifiedPI(r_H=[0.0], w_H=[1.0], r_S=[0.0], w_S=[1.0], dt=0.0)
    m = ModifiedPI(r_H=[0.0, 1.0], w_H=[0.0, 1.0], r_S=[0.0], w_S=[1.0], dt=1.0)
    with pytest.raises(ValueError, match="positive weight"):
        m.inverse([0.0, 1.0])
