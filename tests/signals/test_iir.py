"""selfsense.signals.iir.lfilter stands in for scipy.signal.lfilter in the chain's low-order filters: the same bits
(so no result of the pipeline moved when it replaced SciPy's), the same final state, clear errors."""
import numpy as np
import pytest
from scipy import signal as ss

from selfsense.signals.iir import lfilter


def _resonator(f_hz, zeta, dt):
    w = 2 * np.pi * f_hz
    K = w / np.tan(w * dt / 2)
    a0 = K * K + 2 * zeta * w * K + w * w
    return (np.array([w * w, 2 * w * w, w * w]) / a0,
            np.array([1.0, (2 * w * w - 2 * K * K) / a0, (K * K - 2 * zeta * w * K + w * w) / a0]))


@pytest.mark.parametrize("seed", range(6))
def test_same_bits_as_scipy_for_first_and_second_order_filters(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=int(rng.integers(1, 4000))) * 10.0 ** rng.uniform(-6, 3)
    a = float(np.exp(-rng.uniform(1e-4, 1.0)))
    cases = [([1.0 - a], [1.0, -a]), ([1e-4], [1.0, -a]), _resonator(rng.uniform(10, 1000), rng.uniform(0.05, 1), 1e-4),
             ([0.5, 0.25], [2.0, -0.4, 0.1])]   # a[0] != 1 and b shorter than a: normalised as SciPy does
    for b, aa in cases:
        assert np.array_equal(lfilter(b, aa, x), ss.lfilter(b, aa, x))
    zi = [a * x[0]]
    y, zf = lfilter([1.0 - a], [1.0, -a], x, zi=zi)
    y_ref, zf_ref = ss.lfilter([1.0 - a], [1.0, -a], x, zi=zi)
    assert np.array_equal(y, y_ref) and np.array_equal(zf, zf_ref)


def test_first_order_low_pass_settles_at_its_input_with_its_time_constant():
    dt, tau = 1e-3, 0.05
    a = np.exp(-dt / tau)
    y = lfilter([1.0 - a], [1.0, -a], np.ones(1000))
    n = int(round(tau / dt))
    assert y[n - 1] == pytest.approx(1.0 - np.exp(-1.0), rel=1e-12)   # one time constant: 63.2 %
    assert y[-1] == pytest.approx(1.0, abs=1e-8)


def test_bad_coefficients_and_state_are_named():
    with pytest.raises(ValueError, match="a\\[0\\]"):
        lfilter([1.0], [0.0, 1.0], np.ones(3))
    with pytest.raises(ValueError, match="zi has shape"):
        lfilter([1.0], [1.0, -0.5], np.ones(3), zi=[0.0, 0.0])
    with pytest.raises(ValueError, match="one-dimensional"):
        lfilter([1.0], [1.0, -0.5], np.ones((3, 2)))
