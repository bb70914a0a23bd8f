"""The true hysteresis (Preisach, selfsense.sim.preisach) against an independent relay-grid
reference, and its qualitative features: virgin curve, return-point memory, flattening loops."""
import numpy as np

from selfsense.sim import load_device
from selfsense.sim.preisach import preisach_path, preisach_reference_grid


def _comps():
    return np.array(load_device().preisach_components, float)


def test_everett_stack_matches_brute_force_relays():
    u = np.concatenate([np.linspace(0, 1, 60), np.linspace(1, 0.3, 30), np.linspace(0.3, 0.7, 20),
                        np.linspace(0.7, 0.0, 40), np.linspace(0, 0.8, 40)])
    y = preisach_path(u, _comps())
    e_coarse = np.abs(y - preisach_reference_grid(u, _comps(), n=250)).max()
    e_fine = np.abs(y - preisach_reference_grid(u, _comps(), n=500)).max()
    assert e_fine < 0.6 * e_coarse          # discretisation error of the relay grid shrinks ~1/n
    assert e_fine < 0.01 * np.ptp(y)


def _H(u):
    dev = load_device()
    y = preisach_path(u, np.array(dev.preisach_components, float))
    return dev.h_lin_v * u - (y - y[0])


def test_virgin_curve_and_return_point_memory():
    up = np.linspace(0, 1, 201)
    down = up[::-1]
    u = np.concatenate([up, down[1:], up[1:]])
    H = _H(u)
    first, second = H[:201], H[400:]
    # initial ascending (virgin) curve differs from the later ascending branch
    assert np.abs(first - second).max() > 0.5
    # the descending branch lies below the ascending one (charge lags voltage)
    desc = H[200:401][::-1]
    assert (second[20:180] - desc[20:180]).min() > 0.0
    # return-point memory: a minor loop 0.7 -> 0.5 -> 0.7 returns exactly to its reversal point,
    # and the branch then continues as if the loop had not happened (wiping out)
    seg = [np.linspace(0, 1, 101), np.linspace(1, 0.3, 71)[1:], np.linspace(0.3, 0.7, 41)[1:],
           np.linspace(0.7, 0.5, 21)[1:], np.linspace(0.5, 0.9, 41)[1:]]
    u2 = np.concatenate(seg)
    H2 = _H(u2)
    i_rev = 100 + 70 + 40                    # reversal at u = 0.7
    i_back = i_rev + 20 + 20                 # back at 0.7 after the minor loop
    assert u2[i_rev] == u2[i_back] == 0.7
    assert abs(H2[i_back] - H2[i_rev]) < 1e-9
    assert abs(H2[i_rev + 10] - H2[i_back - 10]) > 0.05   # the minor loop is open in between
    u3 = np.concatenate(seg[:3] + [np.linspace(0.7, 0.9, 21)[1:]])
    np.testing.assert_allclose(_H(u3)[-1], H2[-1], atol=1e-9)


def test_loops_flatten_near_the_top():
    up = np.linspace(0, 1, 201)
    u = np.concatenate([up, up[::-1][1:], up[1:]])
    H = _H(u)
    asc, desc = H[400:], H[200:401][::-1]
    width = asc - desc
    assert width.max() > 3.0                          # several volts of hysteresis
    assert width[190] < 0.35 * width.max()            # branches converge near the top (saturation)
    # after the reversal at the top the descending slope decreases (flattening), unlike play operators
    s = np.diff(desc)
    assert s[-1] > 0 and s[-1] > s[-40]  # reversed order: desc[-1] is the top
