"""The load link's creep member (selfsense.chain.creep) in :class:`SelfSensingStream`: the bank of first-order lags
on Q and V_p, ``s = K beta`` added to the tip displacement and ``kappa s`` to the force (thesis
``000_18d138f03f1777c3.txt`` eqs. 46, 52 + the bank), carried sample by sample with its lags from rest, against the
batch ``SelfSensingEstimator.estimate`` on the synthetic dataset of test_streaming (a play-operator H(q), the thesis'
modified PI).

Forced on (``members={"tip_creep": "on"}``) on these 1.6-s trials of a device without creep, the bank keeps the lags
the trials can identify (0.3, 1 and 3 s: ``chain.creep.identifiable_taus``, at most 3x the longest trial; the 10- and
30-s lags, nearly the columns Q and V_p themselves, once gave terms 1e10 times the range). Those lags are still
nearly collinear with each other and with Q and V_p here, and the unregularised fit trades them against A1, A2: the
terms of ``dx_raw`` are some 1e6 times its range and cancel. The stream equals the batch there to the rounding of those
terms (1e-12 of their size, the test_streaming tolerance taken relative to what is summed). With a bank of a
physical size (hand-set: 30 % of the elastic strain) the stream equals the batch to 1e-12 of the signal range, the
tolerance of the other members; a bank of zeros gives the stream without the member bit for bit.
"""
from __future__ import annotations

import json
from itertools import pairwise

import numpy as np
import pytest
from test_streaming import _raw, make_dataset

from selfsense import io as sio
from selfsense import stages
from selfsense.chain.creep import CREEP_TAUS_S
from selfsense.sensing import SelfSensingEstimator, SensingConfig
from selfsense.sensing.estimator import _trial_dt
from selfsense.sensing.streaming import SelfSensingStream

TOL = 1e-12   # test_streaming's tolerance for the thesis' modified PI
COLS = ("V_H", "V_p", "dx_raw", "f_raw", "dx_hat", "f_hat")
CONFIG = {"h_model": "modified_pi", "h_identification": "thesis", "drift": "off", "dc_offset": True}


def _copy(est) -> SelfSensingEstimator:
    return SelfSensingEstimator.from_dict(json.loads(json.dumps(est.to_dict())), est.rig)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tip_creep")
    d = make_dataset(tmp)
    meta = sio.load_trials(d).set_index("trial")
    sigs = {t: stages.ingest(d, t, tmp / f"{t}.parquet") for t in meta.index}
    rig = sio.load_rig(d)

    def fit(mode):
        return SelfSensingEstimator(config=SensingConfig(**CONFIG), rig=rig, members={"tip_creep": mode}).fit(sigs, meta)

    forced = fit("on")
    assert forced.tip_creep_["applied"] and forced.tip_creep_["source"] == "forced"
    assert len(forced.tip_creep_["beta"]) == 2 * len(forced.tip_creep_["taus_s"])
    assert forced.tip_creep_["taus_s"] == [0.3, 1.0, 3.0]    # the lags 1.6-s trials identify (<= 4.8 s)
    # a bank of a physical size on the chain fitted without it: the creep strain 30 % of the elastic strain
    # A1 Q + A2 V_p at equilibrium, shared by the lags, carried to the force row as the mechanism's B21 / A1
    hand = _copy(fit("off"))
    c, n = hand.coef_, len(CREEP_TAUS_S)
    hand.tip_creep_ = {"mode": "on", "applied": True, "source": "forced", "taus_s": list(CREEP_TAUS_S),
                       "beta": [b for _ in range(n) for b in (0.3 * c["A1"] / n, 0.3 * c["A2"] / n)],
                       "kappa": c["B21"] / c["A1"]}
    return d, sigs, forced, hand


def _stream(est, d, trial, cuts=(1, 150, 151, 777), **kw) -> dict:
    """The stream on the raw log of ``trial`` fed in blocks split at ``cuts`` (inside the relay segment, at its
    edge and in the drive)."""
    raw = _raw(d, trial)
    cols = [raw[c].to_numpy() for c in ("u_cmd", "v_shunt", "relay", "t")]
    s = SelfSensingStream(est, **kw)
    edges = [0, *cuts, len(raw)]
    parts = [s.process(*[c[a:b] for c in cols[:3]], t=cols[3][a:b], full=True) for a, b in pairwise(edges)]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _range_err(a, b) -> float:
    b = np.asarray(b, float)
    return float(np.max(np.abs(np.asarray(a, float) - b))) / max(float(np.ptp(b)), 1e-300)


def _term_sizes(est, sig) -> tuple[float, float]:
    """The largest size over the trial of the terms summed into dx_raw and f_raw: |A1 Q| + |A2 V_p| + |dx0| +
    sum |beta_j K_j| and |B21 Q| + |B22 V_p| + |kappa| sum |beta_j K_j| (the batch's regressors)."""
    X = est._regressors(est._with_links(sig))
    c, cr = est.coef_, est.tip_creep_
    bank = np.abs(X[:, 2:] * np.asarray(cr["beta"])).sum(axis=1)
    sd = np.abs(c["A1"] * X[:, 0]) + np.abs(c["A2"] * X[:, 1]) + abs(c.get("dx0", 0.0)) + bank
    sf = np.abs(c["B21"] * X[:, 0]) + np.abs(c["B22"] * X[:, 1]) + abs(cr["kappa"]) * bank
    return float(sd.max()), float(sf.max())


def test_hand_set_bank_streams_as_the_batch(data):
    """A bank of a physical size: stream == batch to 1e-12 of the range on every trial and every output, the
    member moves the estimates, a sample at a time is the same code as a block."""
    d, sigs, _, est = data
    off = _copy(est)
    off.tip_creep_["applied"] = False
    for trial, sig in sigs.items():
        batch = est.estimate(sig)
        out = _stream(est, d, trial)
        for col in COLS:
            assert _range_err(out[col], batch[col]) <= TOL, (trial, col, _range_err(out[col], batch[col]))
        # non-trivial: the member moves dx_raw and f_raw by a good part of their range
        without = off.estimate(sig)
        assert _range_err(without["dx_raw"], batch["dx_raw"]) > 0.05
        assert _range_err(without["f_raw"], batch["f_raw"]) > 0.05
        assert np.all(out["dx_raw"][:150] == 0.0) and np.all(out["f_raw"][:150] == 0.0)   # the relay short
    raw = _raw(d, "obj_val")
    s = SelfSensingStream(est)
    whole = s.process(raw["u_cmd"], raw["v_shunt"], raw["relay"], t=raw["t"])
    s.reset()
    k = 400
    steps = np.array([s.step(u, v, r, t=tk) for tk, u, v, r in
                      raw[["t", "u_cmd", "v_shunt", "relay"]].iloc[:k].itertuples(index=False)])
    np.testing.assert_array_equal(steps[:, 0], whole[0][:k])
    np.testing.assert_array_equal(steps[:, 1], whole[1][:k])


def test_forced_on_fit_streams_as_the_batch(data):
    """The member as the estimator fits it when forced on: stream == batch to the rounding of the summed terms
    (module docstring), V_H and V_p to 1e-12 of their range; the same at the trial's own sample period."""
    d, sigs, est, _ = data
    for trial, sig in sigs.items():
        batch = est.estimate(sig)
        sd, sf = _term_sizes(est, sig)
        for kw in ({}, {"dt": _trial_dt(sig)}):
            out = _stream(est, d, trial, **kw)
            for col in ("V_H", "V_p"):
                assert _range_err(out[col], batch[col]) <= TOL, (trial, col, kw)
            for col, size in (("dx_raw", sd), ("dx_hat", sd), ("f_raw", sf), ("f_hat", sf)):
                err = float(np.max(np.abs(out[col] - batch[col].to_numpy()))) / size
                assert err <= TOL, (trial, col, kw, err)


def test_zero_bank_is_the_stream_without_the_member(data):
    """beta = 0: the stream of the chain without the member, bit for bit (the lags run, their sum is 0)."""
    d, _, est, _ = data
    zero, off = _copy(est), _copy(est)
    zero.tip_creep_["beta"] = [0.0] * len(zero.tip_creep_["beta"])
    off.tip_creep_ = {"mode": "off", "applied": False}
    for trial in ("free_val", "obj_val"):
        a, b = _stream(zero, d, trial), _stream(off, d, trial)
        for col in COLS:
            np.testing.assert_array_equal(a[col], b[col], err_msg=f"{trial} {col}")
    # the member's state: two lags per tau after the fixed back state, none without it
    assert SelfSensingStream(zero).get_state()["back"].shape == (2 + 2 * len(est.tip_creep_["taus_s"]),)
    assert SelfSensingStream(off).get_state()["back"].shape == (2,)


def test_state_round_trip_carries_the_lags(data):
    d, _, _, est = data
    raw = _raw(d, "obj_val")
    u, v, r, t = (raw[c].to_numpy() for c in ("u_cmd", "v_shunt", "relay", "t"))
    s = SelfSensingStream(est)
    whole = s.process(u, v, r, t)
    s.reset()
    s.process(u[:900], v[:900], r[:900], t[:900])
    saved = s.get_state()
    assert np.any(saved["back"][2:] != 0.0), "the lags never moved"
    s.process(u[900:1000], v[900:1000], r[900:1000], t[900:1000])
    s.set_state(saved)
    tail = s.process(u[900:], v[900:], r[900:], t[900:])
    np.testing.assert_array_equal(tail[0], whole[0][900:])
    np.testing.assert_array_equal(tail[1], whole[1][900:])
    with pytest.raises(ValueError, match="back"):
        s.set_state({**saved, "back": np.zeros(2)})


def test_member_needs_a_sample_period(data):
    """Without a sample period (none given, the H model holds none) the member cannot set its lags: a clear
    ValueError; given one, the stream runs."""
    _, _, _, est = data
    e = _copy(est)
    e.hysteresis_.dt_ = float("nan")
    with pytest.raises(ValueError, match="creep member .*pass dt"):
        SelfSensingStream(e)
    SelfSensingStream(e, dt=1e-3)
