"""The H(q) model registry: one common check every registered model passes, plus recovery of known parameters."""
import json

import numpy as np
import pytest

from selfsense.hysteresis.models import (REGISTRY, DegenerateFitError, LinearH, PlayH, PreisachH, h_from_dict,
                                         make_model, qr_reduce, ridge_lstsq)
from selfsense.hysteresis.models._grid import preisach_grid_features, relaxation_bank
from selfsense.hysteresis.models.select import _cv_linear, blocked_folds, select_h_model, stacked_design
from selfsense.hysteresis.operators import play_operator

DT = 1e-3
QREF = 3e-4


def _drive(n=6000, seed=0):
    """Charge path [C] with nested minor loops, from the relaxed state q = 0."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    env = np.concatenate([[1.0], rng.uniform(0.3, 1.0, 7)])
    k = np.minimum((t / t[-1] * len(env)).astype(int), len(env) - 1)
    return QREF * env[k] * 0.5 * (1 - np.cos(2 * np.pi * 0.8 * t))


def _fast_kinds():
    return {"linear": {}, "pi": {"n_play": 6}, "preisach": {"n_grid": 6, "n_play": 3}, "ri": {}}


@pytest.mark.parametrize("kind", ["linear", "pi", "preisach", "ri", "modified_pi", "duhem"])
def test_common_model_contract(kind):
    """fit / predict / to_dict / from_dict round trip; prediction from JSON equals the fitted model's; the sample
    time stored is the data's; predict before fit raises."""
    q = _drive()
    P = play_operator(q / QREF, [0.1, 0.25])
    v = 60.0 * q / QREF + 6.0 * P[:, 0] + 3.0 * P[:, 1] + 0.5 * np.tanh(5 * (q / QREF - 0.4))
    kw = _fast_kinds().get(kind, {"n_play": 6, "n_sup": 3, "n_creep": 2} if kind == "modified_pi" else {})
    with pytest.raises(RuntimeError):
        make_model(kind, **kw).predict(q)
    m = make_model(kind, **kw).fit(q, v, DT)
    assert m.kind == kind and m.dt_ == DT
    d = json.loads(json.dumps(m.to_dict()))
    m2 = h_from_dict(d)
    np.testing.assert_allclose(m2.predict(q), m.predict(q), rtol=0, atol=1e-9 * np.ptp(v))
    np.testing.assert_allclose(m(q), m.predict(q))
    # a hysteresis model fits these loops better than a straight line, in sample
    rms = np.sqrt(np.mean((m.predict(q) - v) ** 2))
    lin = np.sqrt(np.mean((LinearH().fit(q, v, DT).predict(q) - v) ** 2))
    assert rms <= lin * (1 + 1e-9)
    if kind != "linear":
        assert rms < 0.5 * lin


def test_registry_lists_the_documented_kinds():
    assert set(REGISTRY) == {"linear", "pi", "preisach", "ri", "modified_pi", "duhem"}
    with pytest.raises(ValueError, match="unknown H model kind"):
        make_model("bogus")
    with pytest.raises(ValueError, match="unknown kind"):
        h_from_dict({"kind": "bogus"})


def test_preisach_grid_features_match_a_brute_force_relay_grid():
    """Cell up-fractions equal those of a fine grid of relays switched one by one (wiping-out, Mayergoyz)."""
    u = np.array([0.0, 0.5, 0.3, 0.8, 0.2, 0.6, 0.45, 0.9, 0.1, 0.05, 0.7])
    n, m = 4, 240
    F = preisach_grid_features(u, 0.0, 1.0, n)
    g = np.linspace(0, 1, m + 1)
    mid = 0.5 * (g[1:] + g[:-1])
    A, B = np.meshgrid(mid, mid, indexing="ij")
    state = np.zeros((m, m), bool)
    prev = 0.0
    h = 1.0 / n
    for k, x in enumerate(u):
        if k == 0 or x > prev:
            state |= A <= x
        elif x < prev:
            state &= ~(B >= x)
        prev = x
        c = 0
        for i in range(n):
            for j in range(i + 1):
                cell = (A >= i * h) & (A < (i + 1) * h) & (B >= j * h) & (B < (j + 1) * h) & (A >= B)
                assert F[k, c] == pytest.approx((state & cell).sum() / cell.sum(), abs=0.02)
                c += 1
    assert np.all((F >= 0) & (F <= 1))


def _forc_drives(n: int):
    """An identification drive whose first-order reversal curves visit every cell of an ``n`` x ``n`` grid, and a
    test drive on another path inside the identified range."""
    knots = [0.0]
    for i in range(1, n + 1):
        for j in range(i):
            knots += [(i - 0.05) / n, (j + 0.5) / n]
    knots += [0.0]
    q1 = QREF * np.concatenate([np.linspace(a, b, 40, endpoint=False) for a, b in zip(knots[:-1], knots[1:])])
    q2 = _drive(seed=2)
    return q1, q2 * 0.9 * q1.max() / q2.max()


def test_preisach_recovers_its_own_density_out_of_sample():
    """Weights of a grid Preisach truth are recovered; prediction on another drive matches to 1e-6 of the range."""
    rng = np.random.default_rng(3)
    n = 6
    w = rng.uniform(-1, 2, n * (n + 1) // 2)
    q1, q2 = _forc_drives(n)
    m = PreisachH(n_grid=n, ridge=0.0, creep=False).fit(q1, np.zeros_like(q1), DT)   # sets the normalisation
    y1 = preisach_grid_features(m._u(q1), 0.0, 1.0, n) @ w + 30.0 * m._u(q1)
    y2 = preisach_grid_features(m._u(q2), 0.0, 1.0, n) @ w + 30.0 * m._u(q2)
    m = PreisachH(n_grid=n, ridge=0.0, creep=False).fit(q1, y1, DT)
    assert np.max(np.abs(m.predict(q2) - y2)) < 1e-6 * np.ptp(y2)


def test_preisach_reversible_part_recovers_a_steep_anhysteretic_curve_out_of_sample():
    """A Preisach density with a reversible part (Mayergoyz ch. 1): a cell grid plus a piecewise-linear function of the
    input with knots at i / n_rev. A truth made of grid cells and such a curve (a steep rise over two knot intervals,
    a thin-loop hysteron's or a Langevin curve's shape) is recovered on another drive to 1e-6 of its range; the same
    grid without the reversible part misses it by more than 2 % of the range there (it can place the rise only at
    its cell size, with the cells' hysteresis)."""
    rng = np.random.default_rng(4)
    n, nr = 6, 24
    w = rng.uniform(-1, 2, n * (n + 1) // 2)
    q1, q2 = _forc_drives(n)
    m = PreisachH(n_grid=n, ridge=0.0, creep=False).fit(q1, np.zeros_like(q1), DT)   # sets the normalisation
    k = np.arange(1, nr) / nr
    wr = np.zeros(nr - 1)
    wr[[10, 11, 12]] = [40.0, 0.0, -40.0]   # a rise of 40 * 2 / nr over two knot intervals at u = 0.42-0.5

    def truth(q):
        u = m._u(q)
        return (preisach_grid_features(u, 0.0, 1.0, n) @ w + 3.0 * u
                + np.maximum(u[:, None] - k[None, :], 0.0) @ wr)

    y1, y2 = truth(q1), truth(q2)
    rev = PreisachH(n_grid=n, n_rev=nr, ridge=0.0, creep=False).fit(q1, y1, DT)
    assert rev.label() == "preisach(n_grid=6, n_play=0, n_rev=24, ridge=0)"
    assert np.max(np.abs(rev.predict(q2) - y2)) < 1e-6 * np.ptp(y2)
    assert np.max(np.abs(h_from_dict(json.loads(json.dumps(rev.to_dict()))).predict(q2) - y2)) < 1e-6 * np.ptp(y2)
    grid = PreisachH(n_grid=n, ridge=0.0, creep=False).fit(q1, y1, DT)
    assert np.max(np.abs(grid.predict(q2) - y2)) > 0.02 * np.ptp(y2)
    with pytest.raises(ValueError, match="n_rev must be 0 or >= 2"):
        PreisachH(n_rev=1)


def test_signed_pi_recovers_saturating_loops_that_nonnegative_weights_cannot_make():
    """Signed play weights (here one negative) are recovered exactly."""
    q = _drive(seed=4)
    u = q / (q.max() * 1.02)
    m0 = PlayH(n_play=5, ridge=0.0, creep=False).fit(q, u, DT)
    r = np.arange(1, 6) / 5
    y = 10 * u - 3.0 * play_operator(u, r)[:, 1] + 1.0 * play_operator(u, r)[:, 3]
    m = PlayH(n_play=5, ridge=0.0, creep=False).fit(q, y, DT)
    assert m0.q_span_ == m.q_span_
    assert np.max(np.abs(m.predict(q) - y)) < 1e-8 * np.ptp(y)
    assert m.coef_[1] == pytest.approx(-3.0, rel=1e-6)


def test_creep_eigenvalues_live_in_seconds():
    """A creep bank evaluated at a thinned sample time is the same model: predictions on
    every 4th sample at dt = 4 ms match the 1 ms predictions to within the discretisation error."""
    q = _drive(8000, seed=5)
    v = 50 * q / QREF + 2.0 * (q / QREF - relaxation_bank(q / QREF, DT, [2.0])[:, 0] * 0 - 0) \
        + 3.0 * relaxation_bank(q / QREF, DT, [2.0])[:, 0]
    m = PlayH(n_play=4, creep=True).fit(q, v, DT)
    full = m.predict(q, DT)[::4]
    thin = m.predict(q[::4], 4 * DT)
    assert np.sqrt(np.mean((full - thin) ** 2)) < 0.02 * np.sqrt(np.mean((full - full.mean()) ** 2))


def test_blocked_folds_partition_every_segment():
    folds = blocked_folds([10, 7], 3)
    assert len(folds) == 3
    total = np.sum(folds, axis=0)
    assert np.all(total == 1)
    assert folds[0][:3].all() and not folds[0][3] and folds[0][10:12].all()
    # rotated: fold k holds out block (k + i) mod n of segment i, still a partition, never the same block twice
    rot = blocked_folds([10, 7, 9], 3, rotate=True)
    assert np.all(np.sum(rot, axis=0) == 1)
    assert rot[0][:3].all() and rot[0][12:14].all() and not rot[0][10]     # block 0 of seg 0, block 1 of seg 1
    assert rot[2][10:12].all() and not rot[2][:3].any()                     # the first block of seg 1 is in fold 2


@pytest.mark.parametrize("model", [PreisachH(n_grid=6, n_play=3, ridge=1e-3),
                                   PlayH(n_play=6, ridge=1e-4, nonneg=True)], ids=lambda m: m.label())
def test_factored_blocked_cv_equals_the_fit_on_the_training_rows(model):
    """The blocked CV solves each fold on the stacked QR factors of its training blocks (qr_reduce): the fold errors
    equal those of the ridge fit on the training rows themselves, penalty, column scaling and bounds included."""
    rng = np.random.default_rng(3)
    qs = [_drive(seed=11), _drive(n=4500, seed=12)]
    u = [q / QREF for q in qs]
    ys = [30 * x + 4 * play_operator(x, [0.2])[:, 0] + 0.05 * rng.standard_normal(len(x)) for x in u]
    extras = [np.column_stack([np.ones(len(q)) * i, (np.arange(len(q)) * DT) ** 2]) for i, q in enumerate(qs)]
    folds = blocked_folds([len(q) for q in qs], 5, rotate=True)
    fast = _cv_linear(model, qs, ys, DT, extras, folds, 2)
    X, y, pen = stacked_design(model, qs, ys, DT, extras, 1)
    keep = np.zeros(len(y), bool)
    keep[::2] = True
    slow = []
    for held in folds:
        w = ridge_lstsq(X[keep & ~held], y[keep & ~held], pen, model.ridge, lower=model._bounds(X.shape[1]))
        slow.append(float(np.sqrt(np.mean((X[keep & held] @ w - y[keep & held]) ** 2))))
    np.testing.assert_allclose(fast, slow, rtol=1e-7)
    # and the factor is an orthogonal reduction: residual norms differ from those of the rows by one constant
    R, n, css = qr_reduce(X[:500], y[:500])
    assert n == 500 and np.allclose(css, np.sum(X[:500] ** 2, axis=0))
    w1, w2 = rng.standard_normal((2, X.shape[1]))
    rows = [np.sum((X[:500] @ w - y[:500]) ** 2) for w in (w1, w2)]
    red = [np.sum((R[:, :-1] @ w - R[:, -1]) ** 2) for w in (w1, w2)]
    assert rows[0] - rows[1] == pytest.approx(red[0] - red[1], rel=1e-8)
    assert red[0] <= rows[0] * (1 + 1e-12)


def test_selection_prefers_hysteresis_and_reports_baselines():
    q1, q2 = _drive(seed=6), _drive(seed=7)
    u = lambda q: q / QREF
    y = [40 * u(q) + 5 * play_operator(u(q), [0.15])[:, 0] for q in (q1, q2)]
    res = select_h_model([q1, q2], y, DT, candidates=(("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-8})))
    labels = {r["kind"]: r for r in res.table}
    assert labels["pi"]["selected"] and not labels["linear"]["selected"]
    assert labels["pi"]["cv_rms_mean_v"] < 0.1 * labels["linear"]["cv_rms_mean_v"]
    assert len(labels["pi"]["cv_rms_v"]) == 5


def test_selection_in_worker_threads_is_bit_identical_and_keeps_the_table_order():
    """cv_workers(n): the candidates are cross-validated n at a time (the non-convex ones first), and the table, its
    order and the selected model are the same bits as one after the other."""
    from selfsense.hysteresis.models.select import cv_workers

    q1, q2 = _drive(seed=6), _drive(seed=7)
    u = lambda q: q / QREF
    y = [40 * u(q) + 5 * play_operator(u(q), [0.15])[:, 0] for q in (q1, q2)]
    cands = (("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-8}), ("preisach", {"n_grid": 6, "n_play": 3}),
             ("duhem", {"degree": 2, "ridge": 1e-7}))
    serial = select_h_model([q1, q2], y, DT, candidates=cands)
    with cv_workers(3):
        par = select_h_model([q1, q2], y, DT, candidates=cands)
    assert json.dumps(par.table) == json.dumps(serial.table)
    assert [r["kind"] for r in par.table] == [k for k, _ in cands]
    assert json.dumps(par.model.to_dict()) == json.dumps(serial.model.to_dict())



def test_folds_of_a_selected_non_convex_fit_in_workers_give_the_serial_bits():
    """With workers, each fold of a candidate fitted fold by fold (Duhem) is a unit of work of its own: the selected
    Duhem model -- whose final fit also starts from its fold fits -- and the table are the bits of the serial
    selection."""
    from selfsense.hysteresis.models.select import cv_workers

    q1, q2 = _drive(seed=6), _drive(seed=7)
    u = lambda q: q / QREF
    y = [40 * u(q) + 5 * play_operator(u(q), [0.15])[:, 0] for q in (q1, q2)]
    cands = (("linear", {}), ("duhem", {"degree": 2, "ridge": 1e-7}))
    serial = select_h_model([q1, q2], y, DT, candidates=cands)
    assert serial.model.kind == "duhem"
    with cv_workers(2):
        par = select_h_model([q1, q2], y, DT, candidates=cands)
    assert json.dumps(par.table) == json.dumps(serial.table)
    assert json.dumps(par.model.to_dict()) == json.dumps(serial.model.to_dict())


def test_a_fold_that_raises_in_a_worker_fails_its_candidate_as_in_the_serial_loop(monkeypatch):
    """A fold fitted in a worker of its own that raises: the candidate's row is the serial row (every fold NaN, the
    status naming the error), and the selection goes on without it."""
    from selfsense.hysteresis.models.duhem import DuhemH
    from selfsense.hysteresis.models.select import cv_workers

    fit = DuhemH.fit

    def fails_on_the_last_block(self, q, v, dt, extra=None, row_mask=None, **kw):
        if row_mask is not None and not np.concatenate([np.atleast_1d(m) for m in row_mask])[-1]:
            raise ValueError("no fit on this fold")
        return fit(self, q, v, dt, extra=extra, row_mask=row_mask, **kw)

    monkeypatch.setattr(DuhemH, "fit", fails_on_the_last_block)
    q1, q2 = _drive(seed=6), _drive(seed=7)
    u = lambda q: q / QREF
    y = [40 * u(q) + 5 * play_operator(u(q), [0.15])[:, 0] for q in (q1, q2)]
    cands = (("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-8}), ("duhem", {"degree": 2, "ridge": 1e-7}))
    serial = select_h_model([q1, q2], y, DT, candidates=cands)
    with cv_workers(2):
        par = select_h_model([q1, q2], y, DT, candidates=cands)
    duhem = next(r for r in par.table if r["kind"] == "duhem")
    assert duhem["status"] == "failed: ValueError: no fit on this fold"
    assert all(np.isnan(r) for r in duhem["cv_rms_v"])
    assert json.dumps(par.table, default=str) == json.dumps(serial.table, default=str)
    assert par.model.kind == serial.model.kind == "pi"

def test_job_log_reaches_the_worker_threads_of_a_job(tmp_path):
    """Output of the threads a job starts with a copy of its context (the selection's workers) goes to the job's
    log, not to the Snakemake process's terminal."""
    import contextvars
    from concurrent.futures import ThreadPoolExecutor

    from selfsense import stages

    log = tmp_path / "job.log"
    with stages.logged(log, exit_on_bad_input=False), ThreadPoolExecutor(2) as pool:
        pool.submit(contextvars.copy_context().run, print, "from a worker thread").result()
    assert "from a worker thread" in log.read_text()


def test_selection_warns_naming_the_trials_when_nothing_beats_a_line():
    rng = np.random.default_rng(8)
    q = _drive(seed=8)
    y = 40 * q / QREF + 0.01 * rng.standard_normal(q.size)
    res = select_h_model([q], [y], DT, candidates=(("linear", {}), ("preisach", {"n_grid": 8, "ridge": 0.0})),
                         trial_names=["cal_free_sine"])
    assert res.model.kind == "linear"
    assert any("cal_free_sine" in w and "straight line" in w for w in res.warnings)


def test_degenerate_data_raise():
    q = np.zeros(100)
    with pytest.raises(DegenerateFitError, match="does not vary"):
        PreisachH().fit(q, q, DT)
    with pytest.raises(DegenerateFitError, match="no candidate"):
        select_h_model([np.zeros(50)], [np.zeros(50)], DT, candidates=(("pi", {}),), trial_names=["t0"])


def test_modified_pi_worse_than_a_line_is_an_error_not_optimal():
    """Saturating loops (one negative play weight) plus a static tanh: Kuhnen's QP reports 'optimal' for a fit worse
    than a straight line; the public fit refuses it."""
    q = _drive()
    P = play_operator(q / QREF, [0.1, 0.25])
    v = 60.0 * q / QREF + 6.0 * P[:, 0] - 3.0 * P[:, 1] + 0.5 * np.tanh(5 * (q / QREF - 0.4))
    with pytest.raises(DegenerateFitError, match="straight line"):
        make_model("modified_pi", n_play=6, n_sup=3, n_creep=2).fit(q, v, DT)


def test_long_records_are_fitted_on_strided_rows_and_predicted_without_the_design(monkeypatch):
    """Above MAX_FIT_ROWS the fit keeps every k-th row (operators still run over every sample, dt unchanged);
    predict builds no design matrix and equals design @ coef."""
    import selfsense.hysteresis.models as M

    q = _drive(6000, seed=9)
    P = play_operator(q / QREF, [0.1, 0.3])
    v = 40 * q / QREF + 5 * P[:, 0] - 2 * P[:, 1]
    full = PreisachH(n_grid=6, n_play=4, ridge=1e-8).fit(q, v, DT)
    monkeypatch.setattr(M, "MAX_FIT_ROWS", 1500)
    assert M.fit_stride([6000]) == 4
    thin = PreisachH(n_grid=6, n_play=4, ridge=1e-8).fit(q, v, DT)
    assert thin.fit_report_["row_stride"] == 4 and thin.dt_ == DT
    X, _ = thin.design(q, DT)
    np.testing.assert_allclose(thin.predict(q), X @ thin.coef_, rtol=0, atol=1e-9)
    assert np.sqrt(np.mean((thin.predict(q) - full.predict(q)) ** 2)) < 0.01 * np.std(v)


def _grid_full_reference(u, lo, hi, n, w):
    """The Preisach grid output with every cell integrated afresh at every sample (the definition the incremental
    kernel must reproduce), plain Python on the same staircase rules."""
    from selfsense.hysteresis.models._grid import _prim

    big = 1e300
    h = (hi - lo) / n
    Ms, ms, out, prev = [], [], np.zeros(len(u)), lo
    for k, xk in enumerate(u):
        x = min(max(xk, lo), hi)
        if k == 0 or x > prev:
            while Ms and Ms[-1] <= x:
                Ms.pop(), ms.pop()
            Ms.append(x), ms.append(big)
        elif x < prev:
            j = next((j for j, m in enumerate(ms) if m >= x), None)
            if j is not None:
                ms[j] = x
                del Ms[j + 1:], ms[j + 1:]
        prev = x
        c = 0
        for i in range(n):
            a0, a1 = lo + i * h, lo + i * h + h
            for jb in range(i + 1):
                b0, b1 = lo + jb * h, lo + jb * h + h
                area = 0.0
                for jj in range(len(Ms)):
                    p1, p0 = Ms[jj], (Ms[jj + 1] if jj + 1 < len(Ms) else -big)
                    if p1 <= a0:
                        break
                    if p0 >= a1:
                        continue
                    top = min(ms[jj], b1)
                    if top > b0:
                        area += _prim.py_func(min(p1, a1), b0, top) - _prim.py_func(max(p0, a0), b0, top)
                out[k] += w[c] * (area / (h * h if jb < i else 0.5 * h * h))
                c += 1
    return out


@pytest.mark.parametrize("seed", range(12))
def test_incremental_preisach_grid_equals_integrating_every_cell(seed):
    """The grid kernel integrates only the cells an input step can change (and sums the output incrementally):
    it must equal the output with every cell integrated afresh at every sample, on random walks, inputs on the
    grid lines (ties), clipping beyond [lo, hi], noise around reversals and jumps; any split into blocks gives
    the same bits."""
    from selfsense.hysteresis.models._grid import grid_state, preisach_grid_output

    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 9))
    N = 600
    kind = seed % 4
    if kind == 0:
        u = np.cumsum(rng.normal(0, 0.04, N))
    elif kind == 1:
        u = np.round(rng.uniform(-0.2, 1.2, N) * n) / n
    elif kind == 2:
        t = np.arange(N)
        u = 0.5 + 0.5 * np.sin(t / 15) * np.exp(-t / N) + 0.01 * rng.normal(size=N)
    else:
        u = rng.uniform(0, 1, N)
    lo, hi = (0.0, 1.0) if seed % 2 else (float(u.min()), float(u.max()) + 1e-3)
    w = rng.normal(size=n * (n + 1) // 2)
    ref = _grid_full_reference(u, lo, hi, n, w)
    got = preisach_grid_output(u, lo, hi, n, w)
    assert np.max(np.abs(got - ref)) <= 1e-12 * max(np.ptp(ref), 1.0)
    st = grid_state(n)
    parts = np.split(u, sorted(set(rng.integers(1, N, 4).tolist())))
    np.testing.assert_array_equal(np.concatenate([preisach_grid_output(p, lo, hi, n, w, st) for p in parts]), got)


def test_tall_rows_are_reduced_blockwise_to_the_same_fit(monkeypatch):
    """ridge_lstsq reduces tall rows to their triangular factor before its pivoted QR (in one block, or block by
    block above two QR blocks: qr_reduce's tall-skinny QR): the same triangular factor up to row signs, and the same
    ridge solution (penalty and column scaling of the rows), as the pivoted QR of all rows; a model's design written
    into a block of a stacked matrix equals the design on its own."""
    import selfsense.hysteresis.models as M

    rng = np.random.default_rng(8)
    X = rng.standard_normal((5000, 12)) * np.logspace(-3, 2, 12)
    X[:, 3] = X[:, 2] + 1e-9 * rng.standard_normal(5000)   # nearly collinear: the rank-revealing solve must agree
    y = X @ rng.standard_normal(12) + 0.1 * rng.standard_normal(5000)
    pen = np.arange(12) % 2 == 0
    monkeypatch.setattr(M, "QR_MIN_ROWS", 10 ** 9)       # no reduction: the pivoted QR of all 5000 rows
    direct = M.ridge_lstsq(X, y, pen, 1e-3)
    monkeypatch.undo()
    one = M.ridge_lstsq(X, y, pen, 1e-3)                # 5000 rows: reduced in one block (below two of 4096)
    np.testing.assert_allclose(one, direct, rtol=1e-8, atol=1e-10)
    monkeypatch.setattr(M, "QR_BLOCK_ROWS", 700)         # now 8 blocks
    blocked = M.ridge_lstsq(X, y, pen, 1e-3)
    np.testing.assert_allclose(blocked, direct, rtol=1e-8, atol=1e-10)
    R_blocked = M.qr_reduce(X, y)[0]
    monkeypatch.setattr(M, "QR_BLOCK_ROWS", 10 ** 9)
    R_direct = M.qr_reduce(X, y)[0]
    np.testing.assert_allclose(np.abs(R_blocked), np.abs(R_direct), rtol=1e-9, atol=1e-9 * np.abs(R_direct).max())
    # the objective, not only the point: a wrong reduction would change the fit residual
    assert np.sum((X @ blocked - y) ** 2) == pytest.approx(np.sum((X @ direct - y) ** 2), rel=1e-12)

    model = PreisachH(n_grid=5, n_play=4, ridge=1e-3, creep=True).prepare(_drive(seed=4), DT)
    q = _drive(n=3001, seed=5)
    alone, _ = model.design(q, DT, 3)
    out = np.full((alone.shape[0] + 4, alone.shape[1] + 2), np.nan)
    model.design(q, DT, 3, out=out[2:-2])
    np.testing.assert_array_equal(out[2:-2, :alone.shape[1]], alone)
    assert np.isnan(out[:2]).all() and np.isnan(out[2:-2, alone.shape[1]:]).all()
    with pytest.raises(ValueError, match="rows"):
        model.design(q, DT, 3, out=np.empty((alone.shape[0] - 1, alone.shape[1])))


def _rows_case():
    """Two calibration segments with an extra (joint) column and a trial of reference-free holds with a hold-only
    column: every kind of row the final fit of a selection stacks."""
    from selfsense.hysteresis.models.holds import HoldSet

    q1, q2, qh = _drive(seed=3), _drive(seed=4), _drive(seed=5)
    u = lambda q: q / QREF
    t = lambda q: np.arange(q.size) * DT
    y = [40 * u(q) + 5 * play_operator(u(q), [0.15])[:, 0] + 0.3 * t(q) for q in (q1, q2)]
    extras = [t(q)[:, None] for q in (q1, q2)]
    holds = HoldSet(qs=[qh], ys=[40 * u(qh) + 5 * play_operator(u(qh), [0.15])[:, 0] + 0.1 * t(qh)],
                    holds=[[(1000, 1400), (3000, 3600), (5000, 5500)]], names=["holds"], extras=[t(qh)[:, None]])
    return [q1, q2], y, extras, holds


def test_selected_model_is_fitted_on_the_rows_of_its_cv_bit_for_bit(monkeypatch):
    """One candidate after the other, the selection keeps the stacked least-squares rows of its best candidate so
    far, and the selected model's final fit solves them as they are (models.FitRows) instead of building them
    again: the same model, bit for bit, as a fit that builds them (extra columns, hold rows, hold-only columns)."""
    from selfsense.hysteresis.models import LinearParamH

    qs, y, extras, holds = _rows_case()
    cands = (("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-8}), ("preisach", {"n_grid": 6, "n_play": 3}))
    given = []
    fit = LinearParamH.fit

    def spy(self, *a, rows=None, **k):
        given.append(rows is not None)
        return fit(self, *a, rows=rows, **k)

    monkeypatch.setattr(LinearParamH, "fit", spy)
    sel = select_h_model(qs, y, DT, extras=extras, candidates=cands, holds=holds)
    assert given == [True]   # the final fit only (the CV solves its folds itself), on the kept rows
    best = next(r for r in sel.table if r["selected"])
    ref = fit(make_model(best["kind"], **best["params"]), qs, y, DT, extra=extras, holds=holds)
    assert ref.coef_.tobytes() == sel.model.coef_.tobytes()
    assert ref.extra_coef_.tobytes() == sel.extra_coef.tobytes()
    assert ref.fit_report_ == sel.model.fit_report_
    assert ref.fit_report_["n_hold_rows"] > 0


def test_held_form_without_cv_is_the_model_the_cv_selects_bit_for_bit():
    """select_h_model(cv=False) (a held form: the straight line and one other form, as the gap diagnostic's
    recalibrations hold it): the form is refitted without the blocked CV -- the same model and extra coefficients,
    bit for bit, as the selection gives where it selects that form (extra columns, hold rows, hold-only columns);
    its table rows carry no fold errors and say the form was held. More than one form is not a held form."""
    from selfsense.hysteresis.models.select import HELD_STATUS

    qs, y, extras, holds = _rows_case()
    form = (("linear", {}), ("preisach", {"n_grid": 6, "n_play": 3}))
    full = select_h_model(qs, y, DT, extras=extras, candidates=form, holds=holds)
    held = select_h_model(qs, y, DT, extras=extras, candidates=form, holds=holds, cv=False)
    assert next(r for r in full.table if r["selected"])["kind"] == "preisach"
    assert held.model.label() == full.model.label()
    assert held.model.coef_.tobytes() == full.model.coef_.tobytes()
    assert held.extra_coef.tobytes() == full.extra_coef.tobytes()
    assert held.model.fit_report_ == full.model.fit_report_
    assert [(r["kind"], r["selected"], r["status"]) for r in held.table] == [
        ("linear", False, HELD_STATUS), ("preisach", True, HELD_STATUS)]
    assert all(not r["cv_rms_v"] and np.isnan(r["cv_rms_mean_v"]) for r in held.table)
    with pytest.raises(ValueError, match="holds one form"):
        select_h_model(qs, y, DT, candidates=form + (("pi", {"n_play": 6}),), cv=False)


def _full_and_pruned(qs, y, extras, cands):
    """The full and the pruned selection of ``cands`` on the same rows, checked to select the same model bit for bit
    (row, coefficients, extra coefficients, warnings); returns both and the selected row."""
    full = select_h_model(qs, y, DT, extras=extras, candidates=cands)
    pruned = select_h_model(qs, y, DT, extras=extras, candidates=cands, prune=True)
    best = next(r for r in full.table if r["selected"])
    assert next(r for r in pruned.table if r["selected"]) == best
    assert pruned.model.coef_.tobytes() == full.model.coef_.tobytes()
    assert pruned.extra_coef.tobytes() == full.extra_coef.tobytes() and pruned.warnings == full.warnings
    return full, pruned, best


def test_pruned_selection_selects_the_same_model_bit_for_bit():
    """select_h_model(prune=True) (the gap diagnostic's recalibrations): a candidate fitted fold by fold (the Duhem
    form, the modified PI) is stopped once its folds done exceed the best convex candidate's mean; the selected model,
    its row and the warnings are those of the full selection, bit for bit, and the stopped rows say so."""
    from selfsense.hysteresis.models.select import PRUNED_STATUS

    qs, y, extras, _ = _rows_case()
    cands = (("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-8}), ("preisach", {"n_grid": 6, "n_play": 3}),
             ("modified_pi", {"n_play": 6, "n_sup": 3, "n_creep": 2}), ("duhem", {"degree": 2, "ridge": 1e-7}))
    full, pruned, best = _full_and_pruned(qs, y, extras, cands)
    stopped = [r for r in pruned.table if r["status"] == PRUNED_STATUS]
    assert {r["kind"] for r in stopped} == {"modified_pi", "duhem"}
    for r in stopped:   # the folds done are the full selection's; they already put its mean above the best's
        done = [v for v in r["cv_rms_v"] if np.isfinite(v)]
        assert 0 < len(done) < 5 and np.isnan(r["cv_rms_mean_v"]) and sum(done) / 5 > best["cv_rms_mean_v"]
        assert done == next(f for f in full.table if f["label"] == r["label"])["cv_rms_v"][:len(done)]
    assert [r for r in pruned.table if r["status"] != PRUNED_STATUS] == [
        r for r in full.table if r["label"] not in {s["label"] for s in stopped}]


def test_held_non_convex_form_takes_the_fold_fits_as_starts_as_the_selection_does(monkeypatch):
    """A held Duhem form (select_h_model(cv=False)) is fitted from the same starting points as after the selection,
    its blocked-CV fold fits among them (select._final_fit): the same model and extra coefficients bit for bit, and
    the final fit was given the five fold fits' parameters in both cases."""
    import selfsense.hysteresis.models.select as S

    qs, y, extras, holds = _rows_case()
    form = (("linear", {}), ("duhem", {"degree": 2, "creep": False}))
    given = []
    final = S._final_fit

    def spy(best, *a, starts=None, **k):
        given.append(None if starts is None else [np.asarray(c).copy() for c in starts])
        return final(best, *a, starts=starts, **k)

    monkeypatch.setattr(S, "_final_fit", spy)
    full = select_h_model(qs, y, DT, extras=extras, candidates=form, holds=holds)
    held = select_h_model(qs, y, DT, extras=extras, candidates=form, holds=holds, cv=False)
    assert full.model.kind == "duhem" and held.model.kind == "duhem"
    assert len(given) == 2 and len(given[0]) == 5
    assert all(a.tobytes() == b.tobytes() for a, b in zip(given[0], given[1]))
    assert held.model.coef_.tobytes() == full.model.coef_.tobytes()
    assert held.extra_coef.tobytes() == full.extra_coef.tobytes()
    assert "_starts" not in full.table[1] and "_starts" not in held.table[1]


def test_fit_refuses_rows_that_are_not_those_of_its_data():
    from selfsense.hysteresis.models import fit_rows

    qs, y, extras, holds = _rows_case()
    m = PlayH(n_play=6).prepare(qs, DT)
    rows = fit_rows(m, qs, y, DT, extras, holds)
    assert rows.n_hold > 0 and rows.n_extra == 1 and rows.hold_id.size == rows.n_hold
    with pytest.raises(ValueError, match="not those of"):
        PlayH(n_play=6).fit([qs[0]], [y[0]], DT, extra=[extras[0]], holds=holds, rows=rows)
    with pytest.raises(ValueError, match="not those of"):
        PlayH(n_play=6).fit(qs, y, DT, rows=rows)   # the same calibration rows, but without holds


def test_one_standard_error_stop_never_stops_a_candidate_the_rule_could_prefer():
    """select._se_beyond (the pruned selection's stop of a non-convex candidate): whenever it says stop, no completion
    of the candidate's other folds (any RMS >= 0) passes the one-standard-error rule of select_h_model against the
    convex candidate; and it stops where the first fold is far above the convex one's (the gap recalibration on
    tweezer_sim: a Duhem fold of 0.086 V against 0.015-0.020 V)."""
    from selfsense.hysteresis.models.select import _se_beyond

    alt = [0.01736, 0.01689, 0.01498, 0.01757, 0.02028]
    assert _se_beyond([0.08586], alt) and not _se_beyond([0.0170], alt)
    rng = np.random.default_rng(3)
    for _ in range(300):
        n = int(rng.integers(2, 7))
        a = list(rng.uniform(0.5, 1.5, n))
        k = int(rng.integers(1, n))
        done = list(rng.uniform(0.0, 2.0, k))
        rest = rng.uniform(0.0, 1.0, (400, n - k)) * np.asarray(a[k:])
        d = np.asarray(a) - np.column_stack([np.tile(done, (len(rest), 1)), rest])
        passes = d.mean(axis=1) > d.std(axis=1, ddof=1) / np.sqrt(n)
        assert not (_se_beyond(done, a) and passes.any())


def test_pruned_selection_stops_a_linear_candidate_on_its_blocks_own_residuals():
    """select_h_model(prune=True): a candidate linear in its parameters whose held-out blocks cannot be fitted, even by
    themselves, to below the best convex candidate's mean is stopped after factoring them (select._cv_linear's bound);
    the selected model is the full selection's bit for bit, and the stopped row's full mean is above the best's."""
    from selfsense.hysteresis.models.select import PRUNED_BLOCKS_STATUS

    qs, y, extras, _ = _rows_case()
    cands = (("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-8}), ("preisach", {"n_grid": 6, "n_play": 3}),
             ("preisach", {"n_grid": 2, "n_play": 0, "creep": False}))
    full, pruned, best = _full_and_pruned(qs, y, extras, cands)
    assert [r["status"] for r in pruned.table][-1] == PRUNED_BLOCKS_STATUS
    assert full.table[-1]["cv_rms_mean_v"] > best["cv_rms_mean_v"]
    assert pruned.table[:-1] == full.table[:-1]


def test_blocked_householder_factor_is_numpys_factor():
    """qr_reduce's triangular factor (LAPACK dgeqrt, panels of QR_PANEL columns) is numpy's Householder factor up to
    rounding, with the same signs, for tall, square and wide blocks and panels wider than the block; an empty block
    gives an empty factor; a NaN propagates instead of being dropped."""
    import selfsense.hysteresis.models as M

    rng = np.random.default_rng(11)
    for shape in ((4096, 157), (300, 40), (40, 40), (7, 30), (1, 5), (50, 1)):
        A = rng.standard_normal(shape) * np.logspace(-2, 3, shape[1])
        R, ref = M._qr_r(A), np.linalg.qr(A, mode="r")
        assert R.shape == ref.shape and np.array_equal(R, np.triu(R)), shape
        np.testing.assert_allclose(R, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    assert M._qr_r(np.zeros((0, 4))).shape == (0, 4) and M._qr_r(np.zeros((3, 0))).shape == (0, 0)
    A = rng.standard_normal((100, 6))
    A[17, 2] = np.nan
    assert np.isnan(M._qr_r(A)).any()


def test_qp_candidate_is_cross_validated_on_records_above_max_fit_rows(monkeypatch):
    """Records longer than MAX_FIT_ROWS (a 5 kHz rig's three 16 s trials): the QP candidate (the thesis' modified PI)
    used to be out of the race ("fitted on up to 200000 samples only"), and h_model: modified_pi then ran another
    kind without a word. Its one free-tip segment is fitted at full rate anyway: it is cross-validated on the same
    contiguous blocks at full rate, with fold errors close to those of the short-record path."""
    import selfsense.hysteresis.models as M

    qs = [_drive(3000, seed=s) for s in (3, 4)]
    ys = []
    for q in qs:
        P = play_operator(q / QREF, [0.1, 0.3])
        ys.append(40 * q / QREF + 5 * P[:, 0] - 2 * P[:, 1] + 0.5 * np.tanh(3 * q / QREF))
    cands = (("linear", {}), ("modified_pi", {"n_play": 6, "n_sup": 3, "n_creep": 2}))
    short = select_h_model(qs, ys, DT, candidates=cands, n_blocks=3).table
    monkeypatch.setattr(M, "MAX_FIT_ROWS", 1500)
    assert M.fit_stride([3000, 3000]) == 4
    long = select_h_model(qs, ys, DT, candidates=cands, n_blocks=3).table
    row = {r["kind"]: r for r in long}["modified_pi"]
    ref = {r["kind"]: r for r in short}["modified_pi"]
    assert row["status"] == "ok" and np.all(np.isfinite(row["cv_rms_v"])), row["status"]
    assert row["selected"]
    np.testing.assert_allclose(row["cv_rms_v"], ref["cv_rms_v"], rtol=0.3)
    # records beyond the QP's full-rate memory cap keep it out of the race, with a status that says why
    import selfsense.hysteresis.models.select as S

    monkeypatch.setattr(S, "QP_MAX_SAMPLES", 5000)
    capped = {r["kind"]: r for r in select_h_model(qs, ys, DT, candidates=cands, n_blocks=3).table}["modified_pi"]
    assert capped["status"].startswith("failed") and "memory" in capped["status"]
