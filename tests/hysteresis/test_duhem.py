"""The generic Duhem H(q) model (``kind = "duhem"``): non-congruent minor loops, recovery, selection."""
import json

import numpy as np
import pytest

from selfsense.hysteresis.models import DuhemH, PreisachH, h_from_dict, make_model
from selfsense.hysteresis.models.select import select_h_model

DT = 1e-3
QREF = 3e-4


def _drive(n=8000, seed=0):
    """Charge [C] from the relaxed state: a major cycle, then cycles between drawn levels (minor loops at
    different heights), each ramp a half cosine."""
    rng = np.random.default_rng(seed)
    levels = np.concatenate([[0.0, 1.0, 0.0], rng.uniform(0.0, 1.0, 13)])
    seg = n // (len(levels) - 1)
    out = [a + (b - a) * 0.5 * (1 - np.cos(np.pi * np.arange(seg) / seg)) for a, b in zip(levels[:-1], levels[1:])]
    return QREF * np.concatenate(out)


def _saturating_duhem(q, k=60.0, vs=8.0):
    """A saturating Duhem truth written here (not the estimator's polynomial class): on a rising input
    dv/du = k (1 - v / vs), on a falling one dv/du = k (1 + v / vs) (u = q / QREF, exponential approach to +-vs);
    plus a reversible 30 u. Its minor loops are not congruent (a loop near saturation is flatter)."""
    u = q / QREF
    v = np.zeros_like(u)
    for i in range(1, u.size):
        du = u[i] - u[i - 1]
        v[i] = v[i - 1] + k * (1 - np.sign(du) * v[i - 1] / vs) * du
    return v + 30.0 * u


def _path(levels, n=400):
    r = 0.5 * (1 - np.cos(np.pi * np.arange(n) / n))
    return QREF * np.concatenate([a + (b - a) * r for a, b in zip(levels[:-1], levels[1:])] + [[levels[-1]]])


def test_saturating_duhem_truth_has_non_congruent_minor_loops():
    """The test truth itself: the rise from 0.4 to 0.6 QREF after a reversal at 0.6 and after one at 1.0 differs by
    > 10 %. In a Preisach-class model (PI, Preisach grid, RI) both rises are equal (congruent minor loops, Mayergoyz):
    the relays switched on the way up from 0.4 are the same in both histories."""
    a, b = _path([0.0, 0.6, 0.4, 0.6]), _path([0.0, 1.0, 0.4, 0.6])
    va, vb = _saturating_duhem(a), _saturating_duhem(b)
    rise = lambda v: v[-1] - v[-401]
    assert abs(rise(va) - rise(vb)) > 0.1 * rise(va)
    p = PreisachH(n_grid=10, creep=False).fit(_drive(seed=0), _saturating_duhem(_drive(seed=0)), DT)
    assert rise(p.predict(a)) == pytest.approx(rise(p.predict(b)), rel=1e-6)


def test_duhem_recovers_non_congruent_loops_out_of_sample_where_preisach_cannot():
    """Fitted on one drive, scored on another (other levels): the Duhem model reproduces the saturating truth within
    1 % of its range; a 12 x 12 Preisach grid with plays, fitted the same way, is at least 3 x worse."""
    q1, q2 = _drive(seed=1), _drive(seed=2)
    v1, v2 = _saturating_duhem(q1), _saturating_duhem(q2)
    m = DuhemH(degree=3, creep=False).fit(q1, v1, DT)
    e = np.sqrt(np.mean((m.predict(q2) - v2) ** 2))
    p = PreisachH(n_grid=12, n_play=10, ridge=1e-6, creep=False).fit(q1, v1, DT)
    ep = np.sqrt(np.mean((p.predict(q2) - v2) ** 2))
    assert e < 0.01 * np.ptp(v2), e
    assert ep > 3 * e, (e, ep)


def test_duhem_recovers_a_known_parameter_set():
    """Data made by a DuhemH with known coefficients (degree 2, offset, 5 mV noise) on one drive: the fit on it
    predicts another drive within 0.5 % of the range, and the recovered slope of the ascending branches of H (the
    map's g_+(u, v) plus the linear term's weight, which share the common slope) matches the known one within 5 % of
    its range at the states the data visit."""
    true = DuhemH(degree=2, creep=False)
    true.q_lo_, true.q_span_, true.v_lo_, true.v_span_, true.dt_ = 0.0, QREF, -14.0, 34.0, DT
    true.coef_ = np.array([20.0, -8.0, 1.0, 3.0, 2.0, 0.0, 30.0, 6.0, 1.0, -2.0, 1.0, 0.0])
    true.lin_coef_ = np.array([2.0])
    q1, q2 = _drive(seed=3), _drive(seed=4)
    rng = np.random.default_rng(5)
    v1 = true.predict(q1) + 0.005 * rng.standard_normal(q1.size)
    fit = DuhemH(degree=2, creep=False).fit(q1, v1, DT)
    v2 = true.predict(q2)
    assert np.sqrt(np.mean((fit.predict(q2) - v2) ** 2)) < 0.005 * np.ptp(v2)
    # slope field of the ascending branches at visited states, in V per unit of normalised charge
    from selfsense.hysteresis.models._duhem import duhem_terms

    def g_up(m, u, v):
        phi, dphi = np.empty(6), np.empty(6)
        uu = (u * QREF - m.q_lo_) / m.q_span_
        duhem_terms(2 * uu - 1, 2 * (v - m.v_lo_) / m.v_span_ - 1, 2, phi, dphi)
        a = m.lin_coef_[1] if m.lin_coef_.size > 1 else 0.0   # the linear term [offset, u] (creep=False)
        return (phi @ m.coef_[:6] + a) * QREF / m.q_span_

    u1 = q1 / QREF
    state = true._run(true._u(q1), true.coef_)[0]
    fit_state = fit._run(fit._u(q1), fit.coef_)[0]
    rising = np.flatnonzero(np.diff(u1) > 1e-4)[::50]
    gt = np.array([g_up(true, u1[i], state[i]) for i in rising])
    gf = np.array([g_up(fit, u1[i], fit_state[i]) for i in rising])
    assert np.sqrt(np.mean((gf - gt) ** 2)) < 0.05 * np.ptp(gt)


def test_a_start_from_an_earlier_fit_is_kept_where_it_fits_the_rows_better():
    """``fit(..., starts=...)``: the earlier fit whose parameters fit the rows best is a third start of the search,
    and the lowest objective wins. With a search cut to one evaluation the two own starts stay far from the truth;
    the earlier fit's parameters as a start give its fit back (within 1 %); a start of the wrong length or with a
    NaN is ignored (the same fit, bit for bit, as without it)."""
    true = DuhemH(degree=2, creep=False)
    true.q_lo_, true.q_span_, true.v_lo_, true.v_span_, true.dt_ = 0.0, QREF, -14.0, 34.0, DT
    true.coef_ = np.array([20.0, -8.0, 1.0, 3.0, 2.0, 0.0, 30.0, 6.0, 1.0, -2.0, 1.0, 0.0])
    true.lin_coef_ = np.array([2.0])
    q = _drive(seed=3)
    v = true.predict(q) + 0.005 * np.random.default_rng(5).standard_normal(q.size)
    good = DuhemH(degree=2, creep=False).fit(q, v, DT)
    short = DuhemH(degree=2, creep=False, max_nfev=1).fit(q, v, DT)
    warm = DuhemH(degree=2, creep=False, max_nfev=1).fit(q, v, DT, starts=[np.zeros(3), good.coef_])
    assert short.fit_report_["rms_v"] > 5 * good.fit_report_["rms_v"]
    assert warm.fit_report_["rms_v"] < 1.01 * good.fit_report_["rms_v"]
    junk = DuhemH(degree=2, creep=False, max_nfev=1).fit(q, v, DT, starts=[np.zeros(3), np.full(12, np.nan)])
    assert junk.coef_.tobytes() == short.coef_.tobytes()


def test_duhem_round_trips_through_json_and_keeps_joint_columns():
    """to_dict / from_dict (through JSON) predicts the same; an extra column (a force reference) is identified
    jointly (coefficient within 5 %); a row mask restricts the objective."""
    q = _drive(seed=6)
    f = np.where(np.arange(q.size) > q.size // 2, 0.3, 0.0) * np.sin(np.arange(q.size) * 0.01) ** 2
    v = _saturating_duhem(q) - 12.0 * f
    m = make_model("duhem", degree=3).fit([q], [v], DT, extra=[-f[:, None]])
    assert m.extra_coef_[0] == pytest.approx(12.0, rel=0.05)   # measured: 11.69
    m2 = h_from_dict(json.loads(json.dumps(m.to_dict())))
    np.testing.assert_allclose(m2.predict(q), m.predict(q), rtol=0, atol=1e-9 * np.ptp(v))
    assert m2.predict(q[::2], 2 * DT).shape == q[::2].shape
    mask = np.arange(q.size) < q.size // 2
    half = make_model("duhem", degree=3).fit([q], [v], DT, extra=[-f[:, None]], row_mask=[mask])
    assert half.fit_report_["n_samples"] < 0.55 * m.fit_report_["n_samples"]
    with pytest.raises(ValueError, match="degree"):
        DuhemH(degree=0)


def test_selection_chooses_duhem_only_where_it_wins():
    """Blocked CV over two trials: on saturating Duhem data the Duhem model is selected over PI and Preisach; on
    congruent PI data it is not."""
    from selfsense.hysteresis.operators import play_operator

    qs = [_drive(6000, seed=7), _drive(6000, seed=8)]
    cands = (("linear", {}), ("pi", {"n_play": 10, "ridge": 1e-6}), ("preisach", {"n_grid": 8, "n_play": 6}),
             ("duhem", {"degree": 3}))
    res = select_h_model(qs, [_saturating_duhem(q) for q in qs], DT, candidates=cands)
    assert res.model.kind == "duhem"
    ys = [40 * q / QREF + 5 * play_operator(q / QREF, [0.1])[:, 0] - 3 * play_operator(q / QREF, [0.3])[:, 0]
          for q in qs]
    res = select_h_model(qs, ys, DT, candidates=cands)
    assert res.model.kind in ("pi", "preisach")


def test_a_non_convex_model_must_win_by_more_than_one_standard_error(monkeypatch):
    """The one-standard-error rule of the selection: a Duhem CV mean lower than the Preisach one by less than the
    standard error of the paired fold differences selects the Preisach model; a clear win selects the Duhem."""
    import selfsense.hysteresis.models.select as S

    folds = {"linear": [3.0] * 5, "preisach": [0.40, 0.45, 0.50, 0.42, 0.48]}
    monkeypatch.setattr(S, "_cv_linear", lambda model, *a, **k: folds[model.kind])
    monkeypatch.setattr(S, "_cv_masked", lambda model, *a, **k: folds["duhem"])
    q = _drive(3000, seed=9)
    v = _saturating_duhem(q)
    cands = (("linear", {}), ("preisach", {"n_grid": 6}), ("duhem", {"degree": 2}))
    folds["duhem"] = [0.30, 0.55, 0.35, 0.52, 0.48]     # mean 0.440 < 0.450, paired differences too noisy
    assert select_h_model([q], [v], DT, candidates=cands).model.kind == "preisach"
    folds["duhem"] = [0.10, 0.12, 0.11, 0.09, 0.13]     # a clear win
    assert select_h_model([q], [v], DT, candidates=cands).model.kind == "duhem"


def test_default_candidates_include_a_creep_free_duhem_for_long_creep_free_records():
    """A 300 s record (two segments) of a Duhem truth with a slowly modulated amplitude and no creep: with the creep
    bank the Duhem fit trades the slow creep columns against its state (blocked CV about 0.8 V, measured); the
    creep-free candidate of DEFAULT_CANDIDATES fits it to < 0.1 V and is selected."""
    from selfsense.hysteresis.models._duhem import duhem_run, duhem_state
    from selfsense.hysteresis.models.select import DEFAULT_CANDIDATES

    n, dt = 60_000, 5e-3
    t = np.arange(n) * dt
    c = np.zeros(20)
    c[[0, 1, 10, 11]] = 30.0, -10.0, 30.0, 10.0
    rng = np.random.default_rng(0)
    qs, ys = [], []
    for i in range(2):
        u = 0.5 * (1 - np.cos(2 * np.pi * 0.5 * t)) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.013 * t + i))
        qs.append(QREF * u)
        ys.append(duhem_run(u, c, 3, -5.0, 10.0, 2e-3, -50.0, 50.0, 1, False, duhem_state())[0] + 20 * u
                  + 0.01 * rng.standard_normal(n))
    cands = tuple(x for x in DEFAULT_CANDIDATES if x[0] in ("linear", "pi", "duhem"))
    assert ("duhem", {"degree": 3, "ridge": 1e-7, "creep": False}) in DEFAULT_CANDIDATES
    res = select_h_model(qs, ys, dt, candidates=cands)
    assert res.model.kind == "duhem" and not res.model.creep
    assert min(r["cv_rms_mean_v"] for r in res.table) < 0.1


def test_map_output_has_the_same_bits_with_and_without_its_sensitivities():
    """The fit takes each residual from the map's run that also computes the sensitivities (the Jacobian is kept for
    the trust-region loop's next Jacobian call): the map's output must not depend on whether they are computed."""
    from selfsense.hysteresis.models._duhem import duhem_run, duhem_state, n_terms

    rng = np.random.default_rng(0)
    u = _drive(seed=2) / QREF
    for deg in (2, 3):
        c = rng.normal(size=2 * n_terms(deg)) * 3.0
        for stride in (1, 3):
            # a narrow output range: the clipping (where the sensitivities restart) is visited too
            args = (u, c, deg, -1.0, 2.0, 2e-3, -1.5, 1.5, stride)
            v_plain, _ = duhem_run(*args, False, duhem_state())
            v_sens, J = duhem_run(*args, True, duhem_state())
            assert v_plain.tobytes() == v_sens.tobytes()
            assert J.shape == (v_plain.size, c.size) and np.any(J != 0)


def test_fit_is_the_same_when_the_kept_jacobian_cannot_be_used(monkeypatch):
    """A Jacobian asked for at another point than the last residual's is computed afresh: the same fit, bit for bit,
    as with the kept one (here the trust-region loop is made to evaluate the residual elsewhere before each
    Jacobian call)."""
    import scipy.optimize as so

    q = _drive(seed=3)
    v = _saturating_duhem(q)
    kept = DuhemH(degree=2).fit(q, v, DT)
    least_squares = so.least_squares

    def elsewhere_first(fun, x0, jac=None, **kw):
        def jac_after_another_residual(x, *a):
            fun(np.zeros_like(x))
            return jac(x, *a)
        return least_squares(fun, x0, jac=jac_after_another_residual, **kw)

    monkeypatch.setattr(so, "least_squares", elsewhere_first)
    fresh = DuhemH(degree=2).fit(q, v, DT)
    assert json.dumps(fresh.to_dict()) == json.dumps(kept.to_dict())


def test_equation_error_start_equals_the_increments_one_at_a_time():
    """The equation-error start builds the rows of all increments at once, with the operations of
    ``duhem_terms`` in its order: the same start, bit for bit, as one increment at a time (the loop it replaced)."""
    from selfsense.hysteresis.models import ridge_lstsq
    from selfsense.hysteresis.models._duhem import duhem_terms, n_terms
    from selfsense.hysteresis.models.duhem import _directions

    m = DuhemH(degree=3)
    us = [_drive(seed=s) / QREF for s in (4, 5)]
    ve = [np.cumsum(np.abs(np.diff(u, prepend=u[0]))) * 0.5 - u for u in us]
    masks = [np.arange(u.size) % 7 != 3 for u in us]
    lo, hi = min(float(v.min()) for v in ve), max(float(v.max()) for v in ve)
    m.v_lo_, m.v_span_ = lo - 0.05 * (hi - lo), 1.1 * (hi - lo)

    nb = n_terms(m.degree)
    rowsA, rowsb = [], []
    phi, dphi = np.empty(nb), np.empty(nb)
    for u, v, msk in zip(us, ve, masks):
        s = _directions(u, m.eps)
        k = max(1, int(u.size // 3000))
        i0 = np.arange(0, u.size - k, k)
        i1 = i0 + k
        cs = np.concatenate([[0], np.cumsum(s != 1)])
        ok = msk[i0] & msk[i1] & ((cs[i1] - cs[i0] == 0) | (cs[i1] - cs[i0] == k))
        for a, b in zip(i0[ok], i1[ok]):
            du = u[b] - u[a]
            if du == 0:
                continue
            x = min(max(u[a] + u[b] - 1.0, -1.5), 1.5)
            w = min(max((v[a] + v[b] - 2 * m.v_lo_) / m.v_span_ - 1.0, -1.5), 1.5)
            duhem_terms(x, w, m.degree, phi, dphi)
            row = np.zeros(2 * nb)
            off = 0 if s[a] > 0 else nb
            row[off:off + nb] = phi * du
            rowsA.append(row)
            rowsb.append(v[b] - v[a])
    A = np.asarray(rowsA)
    assert len(rowsA) > 100 and np.any(A[:, :nb] != 0) and np.any(A[:, nb:] != 0)
    ref = ridge_lstsq(A, np.asarray(rowsb), np.ones(A.shape[1], bool), 1e-8)
    assert m._equation_error(us, ve, masks).tobytes() == ref.tobytes()


def test_hold_rows_join_the_map_search():
    """Sine calibration, holds of another trial (V and Q only): the Duhem map and its creep bank identified jointly
    on both predict the relaxation of a third trial's holds, where fitting the map on the sine first and the creep
    bank on the holds after it leaves the hold error at a good part of the creep (the map keeps the loop width that
    the sine gave the creep)."""
    from selfsense.hysteresis.models._grid import relaxation_bank
    from selfsense.hysteresis.models.holds import HoldSet, hold_residual
    from selfsense.hysteresis.operators import play_operator

    dt, qref, tau, c_creep = 2e-3, 3e-4, 0.3, 9.0

    def truth(q):
        u = q / qref
        P = play_operator(u, [0.1, 0.3])
        return 60.0 * u + 6.0 * P[:, 0] + 3.0 * P[:, 1] - c_creep * relaxation_bank(u, dt, [tau])[:, 0]

    def holdset(levels, hold_s=3.0, ramp_s=0.2):
        q, holds, cur = [np.zeros(int(0.5 / dt))], [], 0.0
        for lv in levels:
            q.append(np.linspace(cur, lv * qref, int(ramp_s / dt)))
            a = sum(len(x) for x in q)
            q.append(np.full(int(hold_s / dt), lv * qref))
            holds.append((a, a + int(hold_s / dt)))
            cur = lv * qref
        q = np.concatenate(q)
        return HoldSet(qs=[q], ys=[truth(q)], holds=[holds], names=["ops"])

    t = np.arange(int(4.0 / dt)) * dt
    q = qref * 0.5 * (1 - np.cos(2 * np.pi * 1.0 * t))
    y = truth(q)
    fit_holds, test_holds = holdset([0.8, 0.2, 0.6]), holdset([0.9, 0.4, 0.1])

    def hold_rms(m):
        r, _ = hold_residual(m, test_holds, dt, 10**9)
        return float(np.sqrt(np.mean(r ** 2)))

    after = DuhemH().fit(q, y, dt, holds=fit_holds)   # the map on the sine, then the linear part on the holds
    joint = DuhemH(hold_nfev=8).fit(q, y, dt, holds=fit_holds)
    creep_swing = c_creep * 0.5   # V after a half-range step
    assert hold_rms(joint) < 0.05 * creep_swing
    assert hold_rms(joint) < 0.2 * hold_rms(after)
    assert np.sqrt(np.mean((joint.predict(q, dt) - y) ** 2)) < 0.01 * np.ptp(y)
    assert joint.fit_report_["n_hold_rows"] > 0


def test_the_joint_hold_candidate_is_left_out_without_holds_unless_held_alone():
    """Without hold rows the joint-hold form (``hold_nfev``) is its map-first twin: in a list with that twin it is left
    out of the selection (no second CV of the same fit), and a list that holds it alone (the chain's member searches
    pass the selected form so) still fits it, as that twin, bit for bit."""
    from selfsense.hysteresis.models.select import DEFAULT_CANDIDATES, select_h_model

    joint = ("duhem", {"degree": 3, "ridge": 1e-7, "hold_nfev": 8})
    plain = ("duhem", {"degree": 3, "ridge": 1e-7})
    assert joint in DEFAULT_CANDIDATES and plain in DEFAULT_CANDIDATES
    assert DuhemH(hold_nfev=8).label() != DuhemH().label() and "joint holds" in DuhemH(hold_nfev=8).label()
    with pytest.raises(ValueError, match="hold_nfev"):
        DuhemH(hold_nfev=-1)
    dt = 1e-3
    t = np.arange(3000) * dt
    q = 1e-4 * np.sin(2 * np.pi * 1.0 * t) * (1 + 0.5 * np.sin(2 * np.pi * 0.13 * t))
    u = q / 1e-4
    y = 40.0 * u + 3.0 * np.tanh(4 * u) + 2.0 * np.sign(np.gradient(u)) * (1 - u ** 2)
    both = select_h_model([q], [y], dt, candidates=(("linear", {}), plain, joint))
    assert [r["label"] for r in both.table] == ["linear(ridge=0)", DuhemH().label()]
    alone = select_h_model([q], [y], dt, candidates=(("linear", {}), joint))
    assert [r["label"] for r in alone.table] == ["linear(ridge=0)", DuhemH(hold_nfev=8).label()]
    assert alone.table[1]["cv_rms_v"] == both.table[1]["cv_rms_v"]
    if alone.model.kind == "duhem":
        assert alone.model.coef_.tobytes() == both.model.coef_.tobytes()
        assert DuhemH.from_dict(alone.model.to_dict()).hold_nfev == 8


def test_the_registry_names_a_forms_hold_search_and_its_twin_without_it():
    """``searches_holds`` / ``without_hold_search`` read the hold-search parameters from the form's class (the Duhem
    map's ``hold_nfev``), not from the caller: every form of the default list that searches the holds has its twin
    in the list, and a form of a class without such parameters is its own twin."""
    from selfsense.hysteresis.models import searches_holds, without_hold_search
    from selfsense.hysteresis.models.select import DEFAULT_CANDIDATES

    joint = ("duhem", {"degree": 3, "ridge": 1e-7, "hold_nfev": 8})
    assert searches_holds(joint) and not searches_holds(("duhem", {"degree": 3, "hold_nfev": 0}))
    assert without_hold_search(joint) == ("duhem", {"degree": 3, "ridge": 1e-7})
    # a parameter of that name means nothing to a class that does not declare it
    assert not searches_holds(("preisach", {"n_grid": 12, "hold_nfev": 8}))
    assert without_hold_search(("preisach", {"n_grid": 12})) == ("preisach", {"n_grid": 12})
    held = [c for c in DEFAULT_CANDIDATES if searches_holds(c)]
    assert held and all(without_hold_search(c) in DEFAULT_CANDIDATES for c in held)
