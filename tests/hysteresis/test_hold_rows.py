"""Reference-free hold rows of the H(q) fit (selfsense.hysteresis.models.holds): the creep that a sine-only
calibration never excites is identified from the holds of other trials, using their V and Q only."""
import numpy as np
import pytest

from selfsense.hysteresis.models import PlayH
from selfsense.hysteresis.models._grid import (
    preisach_grid_features,
    preisach_grid_rows,
    relaxation_bank,
)
from selfsense.hysteresis.models.holds import HoldSet, hold_design, hold_residual
from selfsense.hysteresis.models.select import select_h_model
from selfsense.hysteresis.operators import play_operator

DT = 2e-3
QREF = 3e-4
TAU = 8.0      # creep time constant of the truth [s]: far longer than the calibration sine


def _truth(q):
    """H [V] with a play hysteresis and a creep that relaxes with TAU after every change of q."""
    u = q / QREF
    P = play_operator(u, [0.1, 0.3])
    return 60.0 * u + 6.0 * P[:, 0] + 3.0 * P[:, 1] - 9.0 * relaxation_bank(u, DT, [TAU])[:, 0]


def _sine(T=3.0):
    t = np.arange(int(T / DT)) * DT
    return QREF * 0.5 * (1 - np.cos(2 * np.pi * 1.0 * t))


def _steps(levels, hold_s=12.0, ramp_s=0.2):
    """Ramps to each level, then a hold; returns q and the hold index ranges."""
    q, holds, cur = [np.zeros(int(0.5 / DT))], [], 0.0
    for lv in levels:
        n_r = int(ramp_s / DT)
        q.append(np.linspace(cur, lv * QREF, n_r))
        a = sum(len(x) for x in q)
        q.append(np.full(int(hold_s / DT), lv * QREF))
        holds.append((a, a + int(hold_s / DT)))
        cur = lv * QREF
    return np.concatenate(q), holds


def _holdset(levels):
    q, hs = _steps(levels)
    return HoldSet(qs=[q], ys=[_truth(q)], holds=[hs], names=["ops"])


def _hold_rms(model, holds):
    r, _ = hold_residual(model, holds, DT, 10**9)   # every hold sample, weight 1
    return float(np.sqrt(np.mean(r ** 2)))


def test_hold_rows_identify_the_creep_a_sine_calibration_misses():
    """Fitted on a 3 s sine alone, the creep bank mispredicts the relaxation in holds of a later trial; with the
    hold rows of another trial (V and Q only, different levels) it predicts them within a fraction of the creep."""
    q = _sine()
    y = _truth(q)
    fit_holds, test_holds = _holdset([0.8, 0.2, 0.6]), _holdset([0.9, 0.4, 0.1])
    creep_scale = 9.0 * 0.5   # V: the creep term's swing after a half-range step
    plain = PlayH(n_play=6, ridge=1e-8).fit(q, y, DT)
    held = PlayH(n_play=6, ridge=1e-8).fit(q, y, DT, holds=fit_holds)
    e_plain, e_held = _hold_rms(plain, test_holds), _hold_rms(held, test_holds)
    assert e_held < 0.1 * creep_scale
    assert e_held < 0.3 * e_plain
    # the calibration sine is still fitted
    assert np.sqrt(np.mean((held.predict(q, DT) - y) ** 2)) < 0.05 * np.ptp(y)
    assert held.fit_report_["n_hold_rows"] > 0


def test_hold_rows_constrain_changes_only_never_the_level():
    """Shifting a hold trial's H target by a constant (its level is not observed reference-free) changes nothing."""
    q = _sine()
    y = _truth(q)
    hs = _holdset([0.8, 0.2, 0.6])
    shifted = HoldSet(qs=hs.qs, ys=[hs.ys[0] + 7.5], holds=hs.holds, names=hs.names)
    a = PlayH(n_play=6, ridge=1e-8).fit(q, y, DT, holds=hs)
    b = PlayH(n_play=6, ridge=1e-8).fit(q, y, DT, holds=shifted)
    np.testing.assert_allclose(a.coef_, b.coef_, rtol=1e-9, atol=1e-12)


def test_hold_rows_are_weighted_as_samples_and_padded_to_extra_columns():
    """Thinned hold rows carry the weight of the samples they stand for; extra (joint) columns are zero on them."""
    m = PlayH(n_play=4, ridge=1e-8).prepare([_sine()], DT)
    hs = _holdset([0.8, 0.2])
    n = hs.n_samples()
    X1, y1, id1 = hold_design(m, hs, DT, n_cal_rows=n, n_cols=m.design(_sine(), DT)[0].shape[1] + 2)
    X4, y4, _ = hold_design(m, hs, DT, n_cal_rows=n // 4, n_cols=X1.shape[1])
    assert len(y4) < len(y1) / 3
    assert np.allclose(X1[:, -2:], 0.0)
    # the weighted sums of squares agree (same rows, thinned and up-weighted)
    assert np.sum(y4 ** 2) == pytest.approx(np.sum(y1 ** 2), rel=0.05)
    assert set(np.unique(id1)) == {0, 1}


def test_selection_scores_every_candidate_on_the_holds():
    """With hold rows, a creep-free candidate that fits the sine as well loses to the one that predicts the holds."""
    q = _sine()
    y = _truth(q)
    cands = (("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-8, "creep": False}), ("pi", {"n_play": 6, "ridge": 1e-8}))
    sel = select_h_model([q], [y], DT, candidates=cands, n_blocks=3, holds=_holdset([0.8, 0.2, 0.6]))
    assert sel.model.kind == "pi" and sel.model.creep
    no_creep = next(r for r in sel.table if r["kind"] == "pi" and not r["params"].get("creep", True))
    assert no_creep["cv_rms_mean_v"] > next(r for r in sel.table if r["selected"])["cv_rms_mean_v"]


def _full_design_rows(m, hs, n_cal, n_cols):
    """hold_design's rows built from each trial's whole design matrix (the construction before ``design_rows``)."""
    from selfsense.hysteresis.models.holds import difference_rows

    return difference_rows(hs, n_cal, n_cols, lambda i, s: (m.design(hs.qs[i], DT, s)[0], None))


@pytest.mark.parametrize("kind, params", [("preisach", {"n_grid": 12, "n_play": 4}), ("preisach", {"n_grid": 7}),
                                          ("pi", {"n_play": 6})])
def test_hold_design_builds_only_the_hold_rows_with_the_same_bits(kind, params):
    """The hold rows are built from each trial's design at the rows the holds read (``design_rows``; a Preisach grid
    runs its state over every sample and writes those rows only): bit for bit the rows of the whole design matrix,
    with and without thinning, with and without hold-only columns."""
    from selfsense.hysteresis.models import make_model

    rng = np.random.default_rng(5)
    q1, h1 = _steps([0.4, 0.9, 0.2], hold_s=3.0)
    q2 = QREF * np.cumsum(rng.standard_normal(4000)) / 60.0
    qs, holds = [q1, q2, _sine()], [h1, [(300, 900), (1500, 1510), (2500, 3999)], []]
    m = make_model(kind, **params).prepare(np.concatenate(qs), DT)
    for extras in (None, [np.column_stack([np.arange(len(q)) * DT, (np.arange(len(q)) * DT) ** 2]) for q in qs]):
        hs = HoldSet(qs=qs, ys=[_truth(q) for q in qs], holds=holds, names=["a", "b", "c"], extras=extras)
        for n_cal in (10 ** 6, 900):   # stride 1, and hold rows thinned to every k-th sample
            got = hold_design(m, hs, DT, n_cal, m.n_columns() + 2)
            ref = _full_design_rows(m, hs, n_cal, m.n_columns() + 2)
            for a, b in zip(got, ref):
                assert a.shape == b.shape and a.dtype == b.dtype
                assert np.array_equal(a.view(np.uint8), b.view(np.uint8))


def test_preisach_grid_rows_are_the_rows_of_the_whole_feature_matrix():
    """preisach_grid_rows: any sorted set of grid rows (runs, isolated rows, the first and the last) has the bits of
    the same rows of preisach_grid_features, at any stride; rows that are not sorted and distinct are refused."""
    rng = np.random.default_rng(9)
    u = np.clip(0.5 + np.cumsum(rng.standard_normal(6000)) * 0.02, -0.1, 1.1)
    for n, stride in ((5, 1), (9, 3), (16, 1)):
        full = preisach_grid_features(u, 0.0, 1.0, n, stride)
        R = full.shape[0]
        rows = np.unique(np.concatenate([[0, R - 1], np.arange(R // 3, R // 3 + 200), rng.integers(0, R, 40)]))
        got = preisach_grid_rows(u, 0.0, 1.0, n, stride, rows)
        assert np.array_equal(got.view(np.uint8), full[rows].view(np.uint8))
    with pytest.raises(ValueError, match="sorted"):
        preisach_grid_rows(u, 0.0, 1.0, 5, 1, np.array([3, 2]))
