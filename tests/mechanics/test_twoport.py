"""Two-port algebra vs direct solves of the lumped networks (thesis 000_18d138f03f1777c3.txt eqs. 1-21)."""
import numpy as np
import pytest

from selfsense.mechanics import twoport as tp
from selfsense.mechanics.twoport import TwoPort

from .network import Network

RNG = np.random.default_rng(12345)


def rand_rhomboid(rng=RNG):
    return dict(k_BI=rng.uniform(1e6, 1e8), k_BO=rng.uniform(1e5, 1e7), k_J=rng.uniform(1e3, 1e6),
                a=rng.uniform(2.0, 10.0))


def rel(A, B):
    A, B = np.asarray(A, float), np.asarray(B, float)
    return np.max(np.abs(A - B)) / np.max(np.abs(B))


def test_rhomboid_matches_direct_solve_and_is_passive():
    for _ in range(5):
        p = rand_rhomboid()
        net = Network()
        net.rhomboid(p["k_BI"], p["k_BO"], p["k_J"], p["a"], "x", "c", "y")
        K = net.port_stiffness(["x", "y"])
        s = tp.rhomboid_s_parameters(**p)
        assert rel(TwoPort(*s).stiffness_matrix(), K) < 1e-9
        assert TwoPort(*s).is_passive()
        assert s[2] < 0  # output moves forward when the input expands


def test_printed_eq7_is_force_on_load_and_eq6_sign():
    # eq. (7): f1 = force the rhomboid exerts on the load = -(external force on the output)
    p = rand_rhomboid()
    k_BI, k_BO, k_J, a = p["k_BI"], p["k_BO"], p["k_J"], p["a"]
    D = k_J + k_BI + a * a * k_BO
    s1, s2, s3 = tp.rhomboid_s_parameters(**p)
    assert s3 == pytest.approx(-(a * k_BO * k_BI / D), rel=1e-12)           # eq. (11), negated
    assert s2 == pytest.approx(-(k_BO ** 2 * a * a / D - k_BO), rel=1e-12)    # eq. (10), negated
    # eq. (6)/(9) as printed has the wrong dimension (k_BI/D): the correct s1 uses k_BI^2/D
    assert s1 == pytest.approx(k_BI - k_BI ** 2 / D, rel=1e-12)
    # with eqs. (1), (5): f_in = k_BI (x_pzt - x_c) > 0 for a blocked output
    net = Network()
    net.rhomboid(k_BI, k_BO, k_J, a, "x", "c", "y")
    u, F = net.solve({"x": 1e-6, "y": 0.0})
    assert k_BI * (u["x"] - u["c"]) == pytest.approx(F["x"], rel=1e-9)
    assert F["x"] > 0


def test_transmission_roundtrip_and_port_relations():
    for _ in range(5):
        s = tp.rhomboid_s_parameters(**rand_rhomboid())
        T = tp.stiffness_to_transmission(*s)
        assert np.linalg.det(T) == pytest.approx(-1.0, rel=1e-9)
        assert np.allclose(tp.transmission_to_stiffness(T), s, rtol=1e-12)
        x = RNG.normal(size=2) * 1e-6
        F = TwoPort(*s).stiffness_matrix() @ x
        assert np.allclose(T @ [x[0], F[0]], [x[1], F[1]], rtol=1e-9, atol=0)


def test_transmission_to_stiffness_rejects_nonreciprocal():
    with pytest.raises(ValueError, match="det T"):
        tp.transmission_to_stiffness([[1.0, 2.0], [3.0, 4.0]])


def series_network(params, common_input=True, k_pzt=None):
    """n rhomboids: outputs in series (y0=ground .. yn), inputs in parallel."""
    net = Network()
    for i, p in enumerate(params):
        xin = "x" if common_input else f"x{i}"
        if not common_input:
            net.spring(k_pzt, **{xin: 1.0})
        net.rhomboid(p["k_BI"], p["k_BO"], p["k_J"], p["a"], xin, f"c{i}", f"y{i + 1}",
                     None if i == 0 else f"y{i}")
    return net


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_series_identical_matches_network(n):
    p = rand_rhomboid()
    net = series_network([p] * n)
    K = net.port_stiffness(["x", f"y{n}"])
    S = tp.series_identical(*tp.rhomboid_s_parameters(**p), n)
    assert rel(TwoPort(*S).stiffness_matrix(), K) < 1e-9
    assert np.allclose(tp.series_general([tp.rhomboid_s_parameters(**p)] * n), S, rtol=1e-12)


def test_series_identical_separate_pzts_by_symmetry():
    # each rhomboid driven by its own PZT (stiffness k_pzt, same force f_pzt) -> same response
    n, p, k_pzt, f_pzt = 5, rand_rhomboid(), 24e6, 200.0
    net = series_network([p] * n, common_input=False, k_pzt=k_pzt)
    S1, S2, S3 = tp.series_identical(*tp.rhomboid_s_parameters(**p), n)
    k_load = 50.0
    net.spring(k_load, **{f"y{n}": 1.0})
    u, _ = net.solve({}, forces={f"x{i}": f_pzt for i in range(n)})
    # reduced: n PZTs in parallel on the combined two-port, load spring at output
    A = np.array([[n * k_pzt + S1, S3], [S3, S2 + k_load]])
    x, y = np.linalg.solve(A, [n * f_pzt, 0.0])
    assert all(u[f"x{i}"] == pytest.approx(x, rel=1e-9) for i in range(n))
    assert u[f"y{n}"] == pytest.approx(y, rel=1e-9)


def test_series_claim_fails_for_nonidentical_rhomboids():
    ps = [rand_rhomboid() for _ in range(3)]
    ss = [tp.rhomboid_s_parameters(**p) for p in ps]
    K = series_network(ps).port_stiffness(["x", "y3"])
    mean = np.mean(ss, axis=0)
    naive = TwoPort(*tp.series_identical(*mean, 3)).stiffness_matrix()
    assert rel(naive, K) > 1e-3
    assert rel(TwoPort(*tp.series_general(ss)).stiffness_matrix(), K) < 1e-9


def nested_network(p1, p2, n1=1):
    net = series_network([p1] * n1)
    net.rhomboid(p2["k_BI"], p2["k_BO"], p2["k_J"], p2["a"], f"y{n1}", "c_L2", "z")
    return net


def test_cascade_two_layers_matches_network():
    for _ in range(4):
        p1, p2 = rand_rhomboid(), rand_rhomboid()
        K = nested_network(p1, p2).port_stiffness(["x", "z"])
        t1, t2 = TwoPort.rhomboid(**p1), TwoPort.rhomboid(**p2)
        T = tp.cascade(t1.transmission(), t2.transmission())
        assert rel(TwoPort.from_transmission(T).stiffness_matrix(), K) < 1e-9
        assert rel(t1.then(t2).stiffness_matrix(), K) < 1e-9
        assert t1.then(t2).is_passive()
        # the plain product printed in eq. (20) is not even reciprocal for two layers
        naive = t2.transmission() @ t1.transmission()
        assert np.linalg.det(naive) == pytest.approx(1.0, rel=1e-9)
        with pytest.raises(ValueError):
            tp.transmission_to_stiffness(naive)


def test_full_device_network_vs_cascade():
    """5 rhomboids in series -> second rhomboid -> lever (compliance element), eqs. (13)-(21)."""
    p1, p2 = rand_rhomboid(), rand_rhomboid()
    Q = np.array([[2e-4, 5e-3], [5e-3, 0.4]])  # m/N, positive definite
    net = nested_network(p1, p2, n1=5)
    net.element(np.linalg.inv(Q), ["z", "tip"])
    K = net.port_stiffness(["x", "tip"])
    first = TwoPort.rhomboid(**p1).series(5)
    T = tp.cascade(first.transmission(), TwoPort.rhomboid(**p2).transmission(),
                   tp.lever_transmission(Q[0, 0], Q[1, 1], Q[0, 1]))
    assert rel(TwoPort.from_transmission(T).stiffness_matrix(), K) < 1e-9
    # the plain 3-factor product of (20) is reciprocal (det -1) but gives the wrong mechanism
    naive = (tp.lever_transmission(Q[0, 0], Q[1, 1], Q[0, 1]) @ TwoPort.rhomboid(**p2).transmission()
             @ first.transmission())
    assert rel(TwoPort.from_transmission(naive).stiffness_matrix(), K) > 1e-3


def test_lever_transmission_satisfies_eq13_and_printed_eq19_does_not():
    Q1, Q2, Q3 = 2e-4, 0.4, 5e-3
    f2, ftip = 0.3, -0.05
    x2, xtip = np.array([[Q1, Q3], [Q3, Q2]]) @ [f2, ftip]
    assert np.allclose(tp.lever_transmission(Q1, Q2, Q3) @ [x2, f2], [xtip, ftip], rtol=1e-12)
    assert not np.allclose(tp.lever_transmission_printed(Q1, Q2, Q3) @ [x2, f2], [xtip, ftip], rtol=1e-3)
    assert np.allclose(tp.lever_transmission(Q1, Q2, Q3), TwoPort.from_compliance(Q1, Q2, Q3).transmission(),
                       rtol=1e-12)


def test_lever_compliances_eqs_14_16():
    C_A = (1.0, 2.0, 3.0, 4.0)
    C_B = (5.0, 6.0, 7.0, 8.0, 9.0)
    E, I = 2.0, (1.0, 10.0, 100.0)
    Q1, Q2, Q3 = tp.lever_compliances(C_A, C_B, E, I)
    assert Q1 == pytest.approx(2 / 4 + 4 / 400)
    assert Q3 == pytest.approx(1 / 4 + 3 / 400)
    assert Q2 == pytest.approx(5 / 4 + 7 / 40 + 8 / 400)


def test_limits_rigid_and_uncoupled():
    # rigid beams: free-output kinematic ratio -s3/s2 -> a ; input stiffness with free output -> k_J/a^2... small
    a = 4.0
    s1, s2, s3 = tp.rhomboid_s_parameters(1e14, 1e14, 10.0, a)
    assert -s3 / s2 == pytest.approx(a, rel=1e-9)
    # zero coupling: a = 0 -> s3 = 0, input = k_BI in series with k_J, output = k_BO
    s1, s2, s3 = tp.rhomboid_s_parameters(3e6, 2e5, 1e6, 0.0)
    assert s3 == 0.0
    assert s1 == pytest.approx(3e6 * 1e6 / 4e6)
    assert s2 == pytest.approx(2e5)
    with pytest.raises(ValueError, match="s3 == 0"):
        tp.stiffness_to_transmission(s1, s2, s3)


def test_reciprocity_network_symmetric():
    p1, p2 = rand_rhomboid(), rand_rhomboid()
    K = nested_network(p1, p2, n1=3).port_stiffness(["x", "z"])
    assert K[0, 1] == pytest.approx(K[1, 0], rel=1e-9)
    assert np.all(np.linalg.eigvalsh(0.5 * (K + K.T)) > 0)


def test_series_rejects_bad_n():
    with pytest.raises(ValueError, match="positive integer"):
        tp.series_identical(1.0, 1.0, -1.0, 0)
