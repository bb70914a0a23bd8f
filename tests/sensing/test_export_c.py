"""``selfsense export-c``: the generated C99 estimator against the batch pipeline and the Python stream, for every
model kind the estimator can hold (issue: real-time self-sensing with the model the pipeline selects).

Every kind is fitted on the bundled sample dataset (``data/raw/sample``, ``drift: off`` so that the model carries no
offset-drift member), exported, compiled with the system C compiler (``cc``; the tests skip with the reason when
there is none) with ``-std=c99 -O2 -Wall -Wextra -pedantic -Werror`` and run on the raw samples of every bundled
trial; batch == stream == C within 1e-9 of the signal range. One more model carries the load link's creep member
(selfsense.chain.creep) beside every other member: its lags' states and its tables (a, beta, kappa) in the C code.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from selfsense.sensing import SelfSensingEstimator
from selfsense.sensing.estimator import GaugedH, _rig_params
from selfsense.sensing.export_c import ExportError, export_c
from selfsense.sensing.streaming import SelfSensingStream
from selfsense.signals import relay_offset

from selfsense import io as sio
from selfsense import stages

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"

TOL = 1e-9
CC = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (cc, gcc or clang) on PATH")

DRIVER = r"""
#include <stdio.h>
#include "selfsense_estimator.h"
int main(void) {
    ss_state s; double u, v, dx, f; int r, st; long k = 0;
    ss_init(&s);
    while (scanf("%lf,%lf,%d", &u, &v, &r) == 3) {
        st = ss_step(&s, u, v, r, &dx, &f);
        if (st != SS_OK) { fprintf(stderr, "sample %ld: status %d\n", k, st); return 10 + st; }
        printf("%.17g,%.17g\n", dx, f);
        k++;
    }
    return 0;
}
"""

KINDS = {
    "default (auto)": {},
    "linear": {"h_model": "pi", "h_identification": "joint"},   # H replaced by the straight line below
    "pi": {"h_model": "pi", "h_identification": "joint"},
    "preisach": {"h_model": "preisach", "h_identification": "joint"},
    # H replaced below by a Preisach model with plays and its reversible part (PreisachH n_rev)
    "preisach (reversible)": {"h_model": "preisach", "h_identification": "joint"},
    "ri": {"h_model": "ri", "h_identification": "joint"},
    "duhem": {"h_model": "duhem", "h_identification": "joint"},
    "modified_pi": {"h_model": "modified_pi", "h_identification": "joint"},
    "modified_pi (thesis)": {"h_model": "modified_pi", "h_identification": "thesis"},
    "RICreepH": {"h_model": "ri", "h_identification": "thesis"},
}


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    from selfsense.hysteresis.models import LinearH, PreisachH
    from selfsense.sensing import SensingConfig

    if not SAMPLE.exists():
        pytest.fail("data/raw/sample is missing: the bundled sample dataset must be committed")
    tmp = tmp_path_factory.mktemp("export_c")
    d = SAMPLE
    meta = sio.load_trials(d).set_index("trial")
    sigs = {t: stages.ingest(d, t, tmp / f"{t}.parquet") for t in meta.index}
    rig = sio.load_rig(d)
    out = {}
    for name, cfg in KINDS.items():
        est = SelfSensingEstimator(config=SensingConfig(drift="off", **cfg), rig=rig).fit(sigs, meta)
        est = SelfSensingEstimator.from_dict(est.to_dict(), est.rig)
        if name == "linear":
            cal = sigs["cal_free"]
            cal = cal[cal["relay"] < 0.5]
            est.hysteresis_ = LinearH().fit(cal["q"].to_numpy(), cal["V"].to_numpy(), 1e-3)
        if name == "preisach (reversible)":
            cal = sigs["cal_free"]
            cal = cal[cal["relay"] < 0.5]
            est.hysteresis_ = PreisachH(n_grid=8, n_play=5, n_rev=12, ridge=1e-4).fit(
                cal["q"].to_numpy(), cal["V"].to_numpy(), 1e-3)
            assert np.ptp(est.hysteresis_.coef_[36 + 5:36 + 5 + 11]) > 0, "the reversible part is not exercised"
        # every member the C code carries: amplifier slew and lag, quantiser, absorption, leakage, stress, rest offset, sliding
        # offset (dx and f), limiting
        est.leakage_s_, est.coef_["dx0"] = 2.0e-9, 1.0e-5
        # the voltage link's lag member: the actuator voltage 0.4 ms behind the command
        est.amplifier_lag_ = {"applied": True, "tau_s": 4.0e-4}
        # the amplifier member's slew limit (chain.amplifier.with_slew) at 70 % of the fastest calibration command
        from selfsense.io.rig import rig_value

        cf = sigs["cal_free"]
        rate = rig_value(rig, "amplifier_gain") * float(np.max(np.abs(np.diff(cf["u_cmd"].to_numpy())
                                                                        / np.diff(cf["t"].to_numpy()))))
        est.amplifier_ = {**est.amplifier_, "applied": False, "slew": {"applied": True, "rate_v_per_s": 0.7 * rate}}
        pr = _rig_params(rig)
        est.absorption_ = {"applied": True, "c_f": 0.02 * pr["n_A"] * pr["C_p"], "tau_s": 1.5}
        # the quantiser member: a threshold midway between two distinct deviations of V_s from the short's mean (no
        # sample sits on it), a current of 1 % of the largest shunt current
        cal = sigs["cal_free"]
        vs, rel = cal["V_s"].to_numpy(), cal["relay"].to_numpy()
        dev = np.unique(np.abs(vs - relay_offset(vs, rel))[rel < 0.5])
        k = len(dev) // 2
        i_max = float(np.max(np.abs(np.diff(cal["q"].to_numpy()) / np.diff(cal["t"].to_numpy()))))
        est.quantiser_ = {"applied": True, "half_step_v": 0.5 * (dev[k] + dev[k + 1]), "i_q_a": 0.01 * i_max}
        # the load link's stress member: H scaled by 1 + s_H f (20 % at the largest calibrated force) and a Q f term,
        # its load solved with a ridge
        fmax = max(est.ranges_["f"][1], 1e-9)
        qmax = float(np.max(np.abs(sigs["cal_free"]["q"].to_numpy())))
        est.stress_ = {"applied": True, "s_h_per_n": 0.2 / fmax, "s_q_v_per_c_n": 1.0 / (qmax * fmax),
                       "a_h_v": 0.5, "a_q_c": 0.3 * qmax, "load_ridge": 0.03}
        est.config.dc_offset = est.config.dc_offset_force = True
        out[name] = est
    h = out["modified_pi (thesis)"].hysteresis_   # a model file written before ModifiedPIH holds a GaugedH
    legacy = SelfSensingEstimator.from_dict(out["modified_pi (thesis)"].to_dict(), out["pi"].rig)
    legacy.hysteresis_ = GaugedH(h.inner_, h.sign_, h.c_)
    out["GaugedH"] = SelfSensingEstimator.from_dict(legacy.to_dict(), legacy.rig)
    assert type(out["GaugedH"].hysteresis_).__name__ == "GaugedH"
    # the load link's creep member (selfsense.chain.creep) beside every other member: a bank of lags on Q and V_p
    # whose strain is 30 % of the elastic strain A1 Q + A2 V_p, carried to the force row as B21 / A1
    from selfsense.chain.creep import CREEP_TAUS_S

    cr = SelfSensingEstimator.from_dict(out["pi"].to_dict(), out["pi"].rig)
    c, n = cr.coef_, len(CREEP_TAUS_S)
    cr.tip_creep_ = {"mode": "on", "applied": True, "source": "forced", "taus_s": list(CREEP_TAUS_S),
                     "beta": [b for _ in range(n) for b in (0.3 * c["A1"] / n, -0.2 * c["A2"] / n)],
                     "kappa": c["B21"] / c["A1"]}
    cr.config.dc_offset = cr.config.dc_offset_force = True
    out["tip_creep"] = SelfSensingEstimator.from_dict(cr.to_dict(), cr.rig)
    return d, sigs, out, tmp


def _build(est, d, tmp: Path, name: str) -> Path:
    model = tmp / f"{name.replace(' ', '_')}.json"
    model.write_text(json.dumps(est.to_dict()))
    od = tmp / f"c_{name.replace(' ', '_').replace('(', '').replace(')', '')}"
    h, c = export_c(model, d, od, dt=1e-3)
    src = c.read_text() + h.read_text()
    assert not any(w in src for w in ("malloc", "calloc", "realloc", "free(")), "the generated code allocates"
    (od / "driver.c").write_text(DRIVER)
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-pedantic", "-Werror", "-o", str(od / "drv"),
                    str(od / "driver.c"), str(c), "-I", str(od), "-lm"], check=True, capture_output=True, text=True)
    return od / "drv"


def _raw(d: Path, trial: str):
    meta = sio.load_trials(d).set_index("trial")
    return sio.read_log(d / meta.loc[trial, "file"])


def _run(exe: Path, raw) -> np.ndarray:
    inp = "".join(f"{u!r},{v!r},{int(r)}\n" for u, v, r in raw[["u_cmd", "v_shunt", "relay"]].itertuples(index=False))
    p = subprocess.run([str(exe)], input=inp, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    return np.array([[float(x) for x in line.split(",")] for line in p.stdout.split()])


def _err(a, ref) -> float:
    """max |a - ref| over the reference's range (a constant reference, e.g. displacement on a blocked trial: over
    its magnitude, or absolute for a reference of zeros)."""
    ref = np.asarray(ref, float)
    scale = float(np.ptp(ref)) or float(np.max(np.abs(ref))) or 1.0
    return float(np.max(np.abs(np.asarray(a) - ref))) / scale


@needs_cc
@pytest.mark.parametrize("name", [*KINDS, "GaugedH", "tip_creep"])
def test_c_equals_batch_and_stream_every_kind(models, name):
    d, sigs, ests, tmp = models
    est = ests[name]
    exe = _build(est, d, tmp, name)
    for trial in sigs:
        raw = _raw(d, trial)
        got = _run(exe, raw)
        batch = est.estimate(sigs[trial])
        stream = SelfSensingStream(est, dt=1e-3).process(raw["u_cmd"], raw["v_shunt"], raw["relay"])
        assert np.ptp(batch["V_H"]) > 0 and max(np.ptp(batch["dx_hat"]), np.ptp(batch["f_hat"])) > 0
        for j, col in enumerate(("dx_hat", "f_hat")):
            assert _err(got[:, j], batch[col]) <= TOL, (name, trial, col, _err(got[:, j], batch[col]))
            assert _err(got[:, j], stream[j]) <= TOL, (name, trial, col, "stream")
    # deterministic: the same samples give the same bytes
    raw = _raw(d, "val_disp_large")
    np.testing.assert_array_equal(_run(exe, raw), _run(exe, raw))


@needs_cc
def test_c_reports_a_stream_without_its_relay_segment(models):
    d, sigs, ests, tmp = models
    exe = _build(ests["pi"], d, tmp, "pi_relay")
    p = subprocess.run([str(exe)], input="0.0,0.0,0\n", capture_output=True, text=True)
    assert p.returncode == 11 and "status 1" in p.stderr   # SS_ERR_NO_RELAY


def test_export_refuses_bad_models_naming_file_and_key(models, tmp_path):
    from selfsense.cli import main as selfsense_main

    d, sigs, ests, _ = models
    good = ests["preisach"].to_dict()
    cases = {}
    bad = json.loads(json.dumps(good))
    bad["hysteresis"]["params"]["kind"] = "tanh_net"
    cases["kind"] = (bad, "unknown kind 'tanh_net'")
    bad = json.loads(json.dumps(good))
    bad["hysteresis"]["params"]["coef"] = bad["hysteresis"]["params"]["coef"][:7]
    cases["shape"] = (bad, "coef must hold")
    bad = json.loads(json.dumps(good))
    del bad["coef"]
    cases["missing"] = (bad, "missing key 'coef'")
    bad = json.loads(json.dumps(good))
    bad["offset_drift"] = True
    cases["drift"] = (bad, "offset-drift member")
    bad = json.loads(json.dumps(good))
    bad["tip_creep"] = {"applied": True, "taus_s": [1.0, 3.0], "beta": [1.0, 2.0, 3.0], "kappa": 0.0}
    cases["creep"] = (bad, "beta must hold 2 coefficients per lag")
    for name, (dd, msg) in cases.items():
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps(dd))
        with pytest.raises(ExportError, match=msg) as e:
            export_c(p, d, tmp_path / f"out_{name}")
        assert str(p) in str(e.value)
        assert not (tmp_path / f"out_{name}").exists(), "a refused model must not leave files behind"
        assert selfsense_main(["export-c", str(p), "--dataset", str(d), "--out", str(tmp_path / "cli")]) == 2
