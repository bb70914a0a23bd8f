"""The H(q) selection's major-loop check (docs/method.md 6b): the selected model, run on the measured charge of every
trial, must stay within the range of its own output on the calibration rows; a model that runs away on the minor
loops and holds the calibration never showed is rejected with its numbers and the next best is selected."""
from __future__ import annotations

import numpy as np
import pytest

from selfsense.hysteresis.models import REGISTRY, PlayH, make_model
from selfsense.hysteresis.models.select import ENVELOPE_TOL, envelope_excursion, select_h_model

DT = 2e-3


def _major_loop():
    """A decaying sine from the relaxed state (the thesis' free-tip calibration drive) and a loop of the play type."""
    t = np.arange(0.0, 8.0, DT)
    q = 0.5 * (1 - np.cos(2 * np.pi * 0.5 * t)) * np.exp(-0.15 * t)
    y = 0.5 * q + 0.2 * np.sign(np.gradient(q)) * (1 - np.exp(-3 * np.abs(q)))
    return t, q, y


def _mixed_drive(top: float = 1.0):
    """Holds at several levels with small sines on top (minor loops), all inside [0, top]."""
    t = np.arange(0.0, 12.0, DT)
    level = np.interp(t, [0, 1, 3, 4, 6, 7, 9, 10, 12], [0, top, top, 0.3 * top, 0.3 * top, 0.7 * top,
                                                          0.7 * top, 0.1 * top, 0.1 * top])
    wiggle = 0.08 * top * np.sin(2 * np.pi * 2.0 * t) * ((t > 4.5) & (t < 6.0) | (t > 7.5) & (t < 9.0))
    return level + wiggle


class WanderH:
    """A play operator that fits the calibration sine well and whose state creeps by a fixed rate whenever the
    input is held (a state that wanders where the calibration never was: a hold)."""
    kind = "test_wander"
    joint_extra = True
    convex = True

    def __init__(self, **kw):
        self.extra_coef_ = np.zeros(0)
        self.inner = PlayH(n_play=30, ridge=1e-12, creep=False)

    def label(self):
        return self.kind

    def to_dict(self):
        return {"kind": self.kind}

    def fit(self, qs, ys, dt, extra=None, row_mask=None, holds=None, **kw):
        self.inner.fit(list(qs), list(ys), dt)
        return self

    def predict(self, q, dt=None):
        p = self.inner.predict(q, dt)
        held = np.abs(np.gradient(q)) < 1e-7
        return p - 0.5 * np.cumsum(held) * (dt or DT)


def test_play_operator_keeps_minor_loops_and_holds_inside_its_major_loop():
    """A PI operator (plays, positive weights here) has the wiping-out property: on a drive of holds and minor loops
    inside the calibrated charge range its output stays in the range of its major loop."""
    _, q, y = _major_loop()
    m = make_model("pi", n_play=10, ridge=1e-6, creep=False).fit([q], [y], DT)
    env = envelope_excursion(m, [q], [("mixed", _mixed_drive(q.max()))], DT)
    assert env["excursion"] <= 0.02
    lo, hi = env["range_v"]
    assert lo <= float(np.min(m.predict(q, DT))) + 1e-12 and hi >= float(np.max(m.predict(q, DT))) - 1e-12


def test_charge_beyond_the_calibrated_range_is_allowed_along_the_slope():
    """A straight line driven 30 % beyond the calibrated charge goes 30 % beyond its range: no excursion is counted;
    the same output on a probe inside the charge range is an excursion of 0.3."""
    _, q, y = _major_loop()
    lin = make_model("linear").fit([q], [0.7 * q], DT)
    beyond = np.linspace(0.0, 1.3 * q.max(), 500)
    assert envelope_excursion(lin, [q], [("beyond", beyond)], DT)["excursion"] == pytest.approx(0.0, abs=1e-6)

    class Scaled:   # the same output without the charge going beyond: an excursion
        def predict(self, qq, dt=None):
            return lin.predict(qq, dt) * (1.3 if len(qq) == 500 else 1.0)
    inside = np.linspace(0.0, q.max(), 500)
    assert envelope_excursion(Scaled(), [q], [("inside", inside)], DT)["excursion"] == pytest.approx(0.3, rel=1e-3)


def test_non_finite_output_is_an_infinite_excursion():
    class NaNOnProbe:
        def predict(self, qq, dt=None):
            return np.full(len(qq), np.nan) if len(qq) == 7 else np.asarray(qq, float)
    _, q, _ = _major_loop()
    env = envelope_excursion(NaNOnProbe(), [q], [("short", np.linspace(0, 1, 7))], DT)
    assert env["excursion"] == np.inf and env["trial"] == "short"


def test_selection_rejects_a_runaway_model_and_selects_the_next(monkeypatch):
    monkeypatch.setitem(REGISTRY, WanderH.kind, WanderH)
    _, q, y = _major_loop()
    cands = (("linear", {}), ("pi", {"n_play": 6, "ridge": 1e-6, "creep": False}), ("test_wander", {}))
    # without probes the wandering model wins the blocked CV (the calibration sine has no hold)
    sel0 = select_h_model([q], [y], DT, candidates=cands, n_blocks=5)
    assert sel0.model.kind == "test_wander" and sel0.envelope is None
    probes = [("val_mixed", _mixed_drive(q.max())), ("cal", q)]
    sel = select_h_model([q], [y], DT, candidates=cands, n_blocks=5, probes=probes)
    rows = {r["kind"]: r for r in sel.table}
    assert sel.model.kind == "pi" and rows["pi"]["selected"] and not rows["test_wander"]["selected"]
    st = rows["test_wander"]["status"]
    assert st.startswith("rejected: leaves its own major loop on the measured charge of trial val_mixed")
    assert f"at most {ENVELOPE_TOL:g} of the range" in st
    assert [e["label"] for e in sel.envelope] == ["test_wander", "pi(n_play=6, ridge=1e-06)"]
    assert sel.envelope[0]["excursion"] > ENVELOPE_TOL >= sel.envelope[1]["excursion"]
    assert any("test_wander" in w and "not selected" in w for w in sel.warnings)
    # the CV numbers of the rejected row stay on record
    assert np.all(np.isfinite(rows["test_wander"]["cv_rms_v"]))


def test_selection_with_probes_inside_the_loop_is_unchanged(monkeypatch):
    """Probes that the selected model keeps inside its major loop change nothing: the same model, bit for bit."""
    _, q, y = _major_loop()
    cands = (("linear", {}), ("pi", {"n_play": 4, "ridge": 1e-3, "creep": False}),
             ("pi", {"n_play": 10, "ridge": 1e-6, "creep": False}))
    a = select_h_model([q], [y], DT, candidates=cands, n_blocks=5)
    b = select_h_model([q], [y], DT, candidates=cands, n_blocks=5, probes=[("mixed", _mixed_drive(q.max()))])
    assert a.model.label() == b.model.label()
    assert np.array_equal(a.model.predict(q, DT), b.model.predict(q, DT))
    assert len(b.envelope) == 1 and b.envelope[0]["excursion"] <= ENVELOPE_TOL


class PlainPlayH(WanderH):
    """Plays without the wandering state, under a kind of its own (the PI baseline kind is never pruned)."""
    kind = "test_play"

    def __init__(self, **kw):
        super().__init__(**kw)
        self.inner = PlayH(n_play=3, ridge=1e-6, creep=False)

    def predict(self, q, dt=None):
        return self.inner.predict(q, dt)


def test_candidates_pruned_against_a_rejected_model_are_cross_validated_again(monkeypatch):
    """With pruning (the gap recalibrations' selection), a candidate stopped because the wandering model's CV was
    lower must come back once that model is rejected: the selection is the same as without pruning."""
    monkeypatch.setitem(REGISTRY, WanderH.kind, WanderH)
    monkeypatch.setitem(REGISTRY, PlainPlayH.kind, PlainPlayH)
    _, q, y = _major_loop()
    cands = (("linear", {}), ("test_wander", {}), ("test_play", {}))
    probes = [("val_mixed", _mixed_drive(q.max()))]
    pruned = select_h_model([q], [y], DT, candidates=cands, n_blocks=5, prune=True)
    assert pruned.model.kind == "test_wander"
    assert any(r["status"].startswith("pruned") for r in pruned.table)   # the PI was stopped against it
    full = select_h_model([q], [y], DT, candidates=cands, n_blocks=5, probes=probes)
    got = select_h_model([q], [y], DT, candidates=cands, n_blocks=5, prune=True, probes=probes)
    assert got.model.label() == full.model.label() == "test_play"
    assert np.array_equal(got.model.predict(q, DT), full.model.predict(q, DT))
    assert not any(r["status"].startswith("pruned") for r in got.table)


def test_a_configured_kind_that_leaves_its_loop_is_kept_with_a_warning():
    """A model the configuration names is not rejected: the check reports it and warns, naming the trial."""
    from selfsense.hysteresis.models.select import configured_envelope

    _, q, y = _major_loop()
    wander = WanderH().fit([q], [y], DT)
    env, warn = configured_envelope(wander, [q], [("val_mixed", _mixed_drive(q.max()))], DT, ["cal"])
    assert env["excursion"] > ENVELOPE_TOL and env["trial"] == "val_mixed" and env["label"] == "test_wander"
    assert warn is not None and "configured test_wander" in warn and "val_mixed" in warn and "kept" in warn
    pi = make_model("pi", n_play=10, ridge=1e-6, creep=False).fit([q], [y], DT)
    env, warn = configured_envelope(pi, [q], [("val_mixed", _mixed_drive(q.max()))], DT, ["cal"])
    assert warn is None and env["excursion"] <= ENVELOPE_TOL


def test_an_infinite_excursion_is_written_as_null_in_the_model_file():
    """A candidate whose output is not finite has an infinite excursion; the model's JSON (which refuses NaN/inf)
    records it as null instead of failing the calibration."""
    import json

    from selfsense.io.atomic import dumps_json
    from selfsense.sensing.estimator import _json_safe_report

    rep = {"hysteresis": {"selection": [], "envelope": [
        {"excursion": float("inf"), "trial": "val_mixed", "range_v": [0.0, float("nan")], "h_v": None, "label": "x"},
        {"excursion": 0.1, "trial": "cal", "range_v": [0.0, 1.0], "h_v": [0.0, 1.1], "label": "pi"}]}}
    with pytest.raises(ValueError, match="NaN/inf"):
        dumps_json(rep)
    got = json.loads(dumps_json(_json_safe_report(rep)))["hysteresis"]["envelope"]
    assert got[0]["excursion"] is None and got[0]["trial"] == "val_mixed" and got[1]["excursion"] == 0.1
    assert got[0]["range_v"] == [0.0, None] and got[1]["h_v"] == [0.0, 1.1]
