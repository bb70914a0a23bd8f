"""Effect library: protocol compliance, structural augmentations fix their own effect on the toy device."""
import numpy as np
import pytest

from selfsense.gap.data import Case
from selfsense.gap.diagnose import Evaluator
from selfsense.gap.library import LIBRARY, effect
from selfsense.gap.model import FastSensingEstimator
from selfsense.gap.toysim import simulate_case


@pytest.fixture(scope="module")
def null_case():
    return Case(*simulate_case({}, 3, 3.0, 400.0))


def test_every_augmentation_follows_the_protocol(null_case):
    for e in LIBRARY:
        aug = e.augmentation()
        assert aug.name.startswith(e.name)
        est = FastSensingEstimator(rig=null_case.rig, augmentations=(aug,)).fit(null_case.trials, null_case.meta)
        out = est.estimate(null_case.trials["val_free"])
        assert list(out.columns[:3]) == ["t", "dx_hat", "f_hat"]
        assert np.isfinite(out[["dx_hat", "f_hat"]].to_numpy()).all()


def test_nominal_fast_estimator_is_accurate_without_effects(null_case):
    ev = Evaluator(null_case)(frozenset())
    assert ev.error["displacement"] < 5.0 and ev.error["force"] < 5.0   # % of range


@pytest.mark.parametrize("name", ["slow.creep", "slow.leakage", "hysteresis.one_sided"])
def test_augmentation_shrinks_its_own_effect(name):
    gen = {"hysteresis.one_sided": "hysteresis.one_sided"}.get(name, name)
    case = Case(*simulate_case({gen: 15.0}, 5, 3.0, 400.0))
    ev = Evaluator(case)
    before = ev(frozenset()).score
    after = ev(frozenset([name])).score
    assert after < before   # refit on calibration trials, evaluated on validation trials


def test_unknown_effect_name_is_reported():
    with pytest.raises(KeyError, match="unknown effect 'slow.nope'"):
        effect("slow.nope")


def test_diagnosis_is_deterministic():
    from selfsense.gap.diagnose import diagnose

    case = Case(*simulate_case({"slow.creep": 12.0}, 8, 3.0, 400.0))
    a = diagnose(case, n_boot=4, with_budget=False, ci_boot=10, seed=3)
    b = diagnose(Case(*simulate_case({"slow.creep": 12.0}, 8, 3.0, 400.0)), n_boot=4, with_budget=False,
                 ci_boot=10, seed=3)
    assert a.attribution.equals(b.attribution)
    assert a.shrink.equals(b.shrink)
    assert a.verdict["effects"] == b.verdict["effects"]
