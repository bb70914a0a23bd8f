"""RI + creep H(q) model (third seed eqs. 8-16 with thesis eqs. 38-41): recovery, joint fitting, serialisation."""
import json

import numpy as np
import pytest

from selfsense.hysteresis.ri import RIModel, diagonal_constraint_basis
from selfsense.hysteresis.operators import log_creep_eigenvalues
from selfsense.sensing.hmodels import RICreepH, fit_ri_creep

DT = 1e-3


def _drive(n, amps, seed):
    t = np.arange(n) * DT
    env = np.interp(t, np.linspace(0, t[-1], len(amps)), amps)
    return 3e-4 * env * 0.5 * (1 - np.cos(2 * np.pi * 0.5 * t))


@pytest.fixture(scope="module")
def truth():
    rng = np.random.default_rng(3)
    T = diagonal_constraint_basis()
    ri = RIModel(b=[0.0, -80.0, 5.0, -3.0, 1.0], p=T @ (rng.normal(size=T.shape[1]) * 2.0), input_scale=3.3e-4)
    r_K = np.arange(4) / 5 * 3e-4
    a_K = log_creep_eigenvalues(4, DT)
    w_K = rng.uniform(0, 3e3, size=(4, 4))
    return RICreepH(ri, r_K, a_K, w_K, c=-2e4, dt=DT)


def test_joint_fit_recovers_a_model_of_its_own_class(truth):
    q1 = _drive(8000, [1.0, 0.4, 0.9, 0.6], 0)
    q2 = _drive(8000, [0.5, 1.0, 0.3, 0.8], 1)
    model, rep = fit_ri_creep([(q1, truth(q1)), (q2, truth(q2))], DT, n_thresholds=4, n_creep=4)
    q3 = _drive(6000, [0.7, 0.95, 0.45], 2)  # unseen input history
    err = model(q3) - truth(q3)
    assert np.sqrt(np.mean(err**2)) < 1e-3 * np.ptp(truth(q3))
    assert rep["n_segments"] == 2


def test_joint_fit_is_not_the_same_as_fitting_one_trial(truth):
    """Both trials' samples enter the least squares: fitting on one trial only must differ."""
    q1 = _drive(5000, [1.0, 0.4], 0)
    q2 = _drive(5000, [0.5, 1.0], 1)
    rng = np.random.default_rng(0)
    y1 = truth(q1) + rng.normal(0, 0.5, q1.size)
    y2 = truth(q2) + rng.normal(0, 0.5, q2.size)
    a, _ = fit_ri_creep([(q1, y1), (q2, y2)], DT, n_thresholds=4, n_creep=4)
    b, _ = fit_ri_creep([(q1, y1)], DT, n_thresholds=4, n_creep=4)
    assert not np.allclose(a(q2), b(q2))


def test_json_round_trip_is_exact(truth):
    q = _drive(3000, [1.0, 0.5], 0)
    model, _ = fit_ri_creep([(q, truth(q))], DT, n_thresholds=3, n_creep=3)
    back = RICreepH.from_dict(json.loads(json.dumps(model.to_dict())))
    np.testing.assert_array_equal(back(q), model(q))


def test_fit_rejects_data_without_charge():
    with pytest.raises(ValueError, match="never rises above 0"):
        fit_ri_creep([(np.zeros(100), np.zeros(100))], DT)
