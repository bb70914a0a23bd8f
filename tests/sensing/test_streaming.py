"""SelfSensingStream and the chunked ``selfsense estimate`` CLI against the batch pipeline.

Reference: ``selfsense.stages.ingest`` (raw log -> V, q; thesis 000_18d138f03f1777c3.txt eqs. 56-57) followed by
``SelfSensingEstimator.estimate`` (eqs. 27, 42, 52 and the Fig. 24 post-processing). The streaming estimator must
reproduce it on any split of the samples: to 1e-12 of the signal range for the thesis' modified PI, to 1e-9 for
every other model kind (H evaluated at the stream's sample time, the batch at the trial's median period);
correctness only, no timing.
"""
from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from selfsense import io as sio
from selfsense import stages
from selfsense.hysteresis.pi import ModifiedPI
from selfsense.sensing import SelfSensingEstimator, SensingConfig
from selfsense.sensing.estimator import GaugedH
from selfsense.hysteresis.models import REGISTRY
from selfsense.sensing.streaming import HStream, SelfSensingStream, StreamError, stream_kinds

ROOT = Path(__file__).resolve().parents[2]

RIG = {
    "dataset": "ds", "sample_rate_hz": 1000.0, "shunt_resistance_ohm": 1000.0, "amplifier_gain": 15.0,
    "inamp_gain": 10.0, "n_actuators": 5,
    "reference": {"laser_m_per_v": 2.0e-3, "load_cell_n_per_v": 0.1},
    "actuator_catalog": {"free_displacement_m": 10.0e-6, "blocked_force_n": 240.0, "stiffness_n_per_m": 24.0e6,
                         "capacitance_f": 0.25e-6, "max_voltage_v": 150.0},
    "tip_free_displacement_m": 6.3e-3,
}
TRIALS = [  # trial, role, tip, reference, signal
    ("free_cal", "calibration", "free", "displacement", "sine"),
    ("blocked_cal", "calibration", "blocked", "force", "sine"),
    ("obj_val", "validation", "object", "force", "mixed"),
    ("free_val", "validation", "free", "displacement", "steps"),
]


def _play(x, r):
    z, out = 0.0, np.empty_like(x)
    for k, xk in enumerate(x):
        z = max(xk - r, min(xk + r, z))
        out[k] = z
    return out


def make_log(tip, reference, signal, n=1600, fs=1000.0, seed=0, n_relay=150, rig=RIG):
    """Raw DAQ log with a hysteretic charge-voltage relation (a play operator in q) and in-amp offset/noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    tt = np.clip(t - n_relay / fs, 0.0, None)
    if signal == "steps":
        u = 8.0 * (np.floor(tt * 1.5) % 2 == 0) * (tt > 0.1)
        k = int(0.3 * fs)
        u = np.convolve(u, np.ones(k) / k, mode="full")[:n]
    elif signal == "mixed":
        u = 3.5 * (1 - np.cos(2 * np.pi * 1.1 * tt)) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.5 * tt) ** 2)
    else:
        u = 3.5 * (1 - np.cos(2 * np.pi * 1.0 * tt))
    u[:n_relay] = 0.0
    Vc = rig["amplifier_gain"] * u
    C = rig["n_actuators"] * rig["actuator_catalog"]["capacitance_f"]
    q = C * (Vc + 0.3 * _play(Vc, 15.0))
    Vs = rig["shunt_resistance_ohm"] * np.gradient(q, t)
    v_shunt = rig["inamp_gain"] * Vs + 3e-4 + 1e-3 * rng.standard_normal(n)
    frac = (Vc - Vs) / rig["actuator_catalog"]["max_voltage_v"]
    dx = {"free": rig["tip_free_displacement_m"] * frac, "blocked": np.zeros(n)}.get(
        tip, np.minimum(rig["tip_free_displacement_m"] * frac, 2.0e-3))
    f = {"free": np.zeros(n), "blocked": 0.1 * frac}.get(
        tip, 0.1 * np.clip(frac - 2.0e-3 / rig["tip_free_displacement_m"], 0, None))
    laser = dx / 2 / rig["reference"]["laser_m_per_v"] + 1e-3 * rng.standard_normal(n)
    load = f / rig["reference"]["load_cell_n_per_v"] + 1e-3 * rng.standard_normal(n)
    (laser if reference == "force" else load)[:] = np.nan
    relay = np.zeros(n)
    relay[:n_relay] = 1.0
    return pd.DataFrame({"t": t, "u_cmd": u, "v_shunt": v_shunt, "laser": laser, "load_cell": load, "relay": relay})


def make_dataset(root: Path, name="ds") -> Path:
    d = Path(root) / name
    d.mkdir(parents=True, exist_ok=True)
    rig = copy.deepcopy(RIG)
    rig["dataset"] = name
    (d / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    lines = ["trial,file,role,tip,object_mm,reference,signal"]
    for k, (tr, role, tip, ref, sig) in enumerate(TRIALS):
        lines.append(f"{tr},{tr}.parquet,{role},{tip},{'2.0' if tip == 'object' else ''},{ref},{sig}")
        make_log(tip, ref, sig, seed=k).to_parquet(d / f"{tr}.parquet", index=False)
    (d / "trials.csv").write_text("\n".join(lines) + "\n")
    return d


def _fit(d: Path, tmp: Path, **cfg):
    meta = sio.load_trials(d).set_index("trial")
    sigs = {t: stages.ingest(d, t, tmp / f"{t}.parquet") for t in meta.index}
    # the streaming kernel runs the modified PI of the thesis identification (registry models: batch estimation)
    # the creep member is off here: on these 1.6-s trials of a device without creep its identifiable lags (0.3-3 s)
    # are nearly collinear with each other and with Q and V_p; forced on, the unregularised fit trades them with terms
    # some 1e6 times the range that cancel, and the stream meets the batch only to the rounding of those terms
    # (test_stream_tip_creep.py checks the member at that tolerance)
    cfg = {"h_model": "modified_pi", "h_identification": "thesis", "drift": "off", "dc_offset": True,
           "tip_creep": "off", **cfg}
    est = SelfSensingEstimator(config=SensingConfig(**cfg), rig=sio.load_rig(d)).fit(sigs, meta)
    return est, sigs


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("stream")
    d = make_dataset(tmp)
    est, sigs = _fit(d, tmp)
    return d, est, sigs


def _raw(d: Path, trial: str) -> pd.DataFrame:
    return pd.read_parquet(d / f"{trial}.parquet")


def _assert_close(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    rng = max(float(np.ptp(b)), 1e-300)
    err = float(np.max(np.abs(a - b))) / rng
    assert err <= 1e-12, f"{what}: max |stream - batch| = {err:.3g} of range (need <= 1e-12)"


def _check_equal(stream: SelfSensingStream, est, raw: pd.DataFrame, sig: pd.DataFrame, blocks=None):
    batch = est.estimate(sig)
    stream.reset()
    n = len(raw)
    cuts = [0, n] if blocks is None else [0, *blocks, n]
    parts = [stream.process(raw["u_cmd"].to_numpy()[a:b], raw["v_shunt"].to_numpy()[a:b],
                            raw["relay"].to_numpy()[a:b], t=raw["t"].to_numpy()[a:b], full=True)
             for a, b in zip(cuts[:-1], cuts[1:])]
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    # V is bit-identical; q too up to the in-amp offset (running sum vs NumPy's pairwise mean of the relay segment)
    np.testing.assert_array_equal(out["V"], sig["V"].to_numpy())
    np.testing.assert_allclose(out["q"], sig["q"].to_numpy(), rtol=0, atol=1e-14 * np.ptp(sig["q"].to_numpy()))
    for col in ("V_H", "V_p", "dx_raw", "f_raw", "dx_hat", "f_hat"):
        _assert_close(out[col], batch[col].to_numpy(), col)
    return out, batch


def test_stream_equals_batch_all_trials(fitted):
    d, est, sigs = fitted
    stream = SelfSensingStream(est)
    clipped = 0
    for trial, sig in sigs.items():
        out, batch = _check_equal(stream, est, _raw(d, trial), sig)
        # non-trivial: the estimates move, the relay segment gives exactly 0, limiting is active
        assert np.ptp(batch["dx_hat"]) > 0 or np.ptp(batch["f_hat"]) > 0
        assert np.all(out["dx_hat"][:150] == 0.0) and np.all(out["f_hat"][:150] == 0.0)
        lo, hi = est.ranges_["dx"]
        assert out["dx_hat"].min() >= lo and out["dx_hat"].max() <= hi
        # limiting is active: estimates sit exactly at a limit (after the sliding DC offset), in stream and batch
        act = _raw(d, trial)["relay"].to_numpy() < 0.5
        flo, fhi = est.ranges_["f"]
        at_dx = act & ((out["dx_hat"] == lo) | (out["dx_hat"] == hi))
        at_f = act & ((out["f_hat"] == flo) | (out["f_hat"] == fhi))
        np.testing.assert_array_equal(batch["dx_hat"].to_numpy()[at_dx], out["dx_hat"][at_dx])
        np.testing.assert_array_equal(batch["f_hat"].to_numpy()[at_f], out["f_hat"][at_f])
        clipped += int(at_dx.sum()) + int(at_f.sum())
    assert clipped > 0, "limiting never clipped: the test would pass with limiting off"


def test_stream_arbitrary_blocks_and_steps_equal_one_block(fitted):
    d, est, sigs = fitted
    raw = _raw(d, "obj_val")
    s = SelfSensingStream(est)
    whole = s.process(raw["u_cmd"], raw["v_shunt"], raw["relay"], t=raw["t"])
    # split inside the relay segment, at the relay edge, and in the middle of the drive
    s.reset()
    split = [s.process(raw["u_cmd"][a:b], raw["v_shunt"][a:b], raw["relay"][a:b], t=raw["t"][a:b])
             for a, b in ((0, 70), (70, 150), (150, 151), (151, 997), (997, len(raw)))]
    for j in range(2):
        np.testing.assert_array_equal(np.concatenate([p[j] for p in split]), whole[j])
    # per-sample step == block: a sample goes through the kernels of a block, bit for bit
    s.reset()
    steps = np.array([s.step(u, v, r, t=tk) for tk, u, v, r in
                      raw[["t", "u_cmd", "v_shunt", "relay"]].itertuples(index=False)])
    np.testing.assert_array_equal(steps[:, 0], whole[0])
    np.testing.assert_array_equal(steps[:, 1], whole[1])
    assert s.n_samples == len(raw)
    assert s.offset_v == pytest.approx(np.mean(raw["v_shunt"][:150] / RIG["inamp_gain"]), rel=1e-12)


def test_stream_with_creep_and_two_sided_superposition(fitted):
    """A hand-made H with strong creep, negative superposition thresholds, z_H0 and offset exercises every branch."""
    d, est, sigs = fitted
    e2 = SelfSensingEstimator.from_dict(est.to_dict(), est.rig)
    qmax = float(np.max(np.abs(sigs["free_cal"]["q"])))
    rng = np.random.default_rng(3)
    r_H = np.arange(6) / 6 * qmax
    G = ModifiedPI.with_log_creep(
        r_H=r_H, w_H=rng.uniform(0.1, 1.0, 6) * 1e6, r_S=[0.0, 20.0, 60.0, -10.0], w_S=[1.0, 0.3, -0.2, 0.5],
        dt=1e-3, r_K=r_H, w_K=rng.uniform(0.5, 2.0, 6) * 1e6, m=4, z_H0=0.1 * qmax, offset=3.0)
    e2.hysteresis_ = GaugedH(G, sign=-1.0, c=3.0e5)  # the estimator's gauge H = sign * (G[Q] - c Q)
    e2.config.dc_offset_force = True
    stream = SelfSensingStream(e2)
    for trial in ("free_val", "obj_val"):
        out, batch = _check_equal(stream, e2, _raw(d, trial), sigs[trial], blocks=[100, 151, 800])
        assert np.ptp(batch["V_H"]) > 1.0  # the operator really acts


def test_stream_from_json_and_dt_mode(fitted, tmp_path):
    d, est, sigs = fitted
    p = tmp_path / "sensing.json"
    p.write_text(json.dumps(est.to_dict()))
    raw = _raw(d, "free_val")
    s_t = SelfSensingStream.from_json(p, d)
    a = s_t.process(raw["u_cmd"], raw["v_shunt"], raw["relay"], t=raw["t"])
    s_dt = SelfSensingStream.from_json(p, d, dt=1e-3)  # uniform grid: same up to t-rounding of the time steps
    b = s_dt.process(raw["u_cmd"], raw["v_shunt"], raw["relay"])
    np.testing.assert_allclose(b[0], a[0], rtol=0, atol=1e-9 * np.ptp(a[0]))
    with pytest.raises(ValueError, match="pass t or construct the stream with dt"):
        s_t.step(0.0, 0.0, 1.0)


def test_stream_errors(fitted):
    d, est, sigs = fitted
    s = SelfSensingStream(est, dt=1e-3)
    with pytest.raises(StreamError, match="start with its relay segment"):
        s.process(np.zeros(3), np.zeros(3), np.zeros(3))
    assert s.n_samples == 0  # a rejected block leaves the state untouched
    with pytest.raises(StreamError, match="only 0 and 1"):
        s.step(0.0, 0.0, relay=0.5)
    with pytest.raises(StreamError, match="strictly increasing"):
        s.reset()
        s.process(np.zeros(3), np.zeros(3), np.ones(3), t=[0.0, 1e-3, 1e-3])
    # a given offset needs no relay segment and matches the batch with the same fixed offset
    raw = _raw(d, "obj_val")
    s2 = SelfSensingStream(est, offset=2.5e-5)
    dx, f = s2.process(raw["u_cmd"][150:], raw["v_shunt"][150:], raw["relay"][150:], t=raw["t"][150:])
    from selfsense.io.dataset import to_si
    from selfsense.signals import prepare_trial

    rig = sio.load_rig(d)
    si = to_si(raw.iloc[150:].reset_index(drop=True), rig, "force")
    batch = est.estimate(prepare_trial(si, rig, offset=2.5e-5))
    _assert_close(dx, batch["dx_hat"].to_numpy(), "dx_hat (fixed offset)")
    _assert_close(f, batch["f_hat"].to_numpy(), "f_hat (fixed offset)")


def test_cli_chunked_equals_batch(fitted, tmp_path):
    from selfsense.cli.estimate import main

    d, est, sigs = fitted
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict()))
    raw = _raw(d, "obj_val")
    log = tmp_path / "log.parquet"
    raw.to_parquet(log, index=False, row_group_size=400)
    out = tmp_path / "out.parquet"
    assert main(["--model", str(model), "--dataset", str(d), "--log", str(log), "--out", str(out),
                 "--chunk", "333", "--full"]) == 0
    got = pd.read_parquet(out)
    batch = est.estimate(sigs["obj_val"])
    np.testing.assert_array_equal(got["t"].to_numpy(), raw["t"].to_numpy())
    for col in ("dx_hat", "f_hat", "V_H", "q"):
        _assert_close(got[col].to_numpy(), batch[col].to_numpy(), f"cli {col}")
    assert not list(tmp_path.glob("*.tmp*")), "temporary file left behind"
    # a bad log leaves no output behind and reports the problem
    bad = raw.drop(columns=["v_shunt"])
    bad.to_parquet(tmp_path / "bad.parquet", index=False)
    out2 = tmp_path / "out2.parquet"
    from selfsense.cli import main as selfsense_main

    assert selfsense_main(["estimate", "--model", str(model), "--dataset", str(d), "--log",
                           str(tmp_path / "bad.parquet"), "--out", str(out2)]) == 2
    assert not out2.exists()


@pytest.mark.skipif(not (ROOT / "data" / "raw" / "sample").exists(), reason="data/raw/sample not present yet")
def test_stream_equals_batch_on_bundled_sample(tmp_path):
    d = ROOT / "data" / "raw" / "sample"
    meta = sio.load_trials(d).set_index("trial")
    est, sigs = _fit(d, tmp_path)
    stream = SelfSensingStream(est)
    for trial in meta.index[:3]:
        raw = sio.read_log(d / meta.loc[trial, "file"])
        _check_equal(stream, est, raw, sigs[trial], blocks=[len(raw) // 3])


@pytest.mark.skipif(not (ROOT / "data" / "raw" / "sample").exists(), reason="data/raw/sample not present yet")
def test_default_model_streams_through_selfsense_estimate(tmp_path):
    """The model the pipeline selects by default (``h_model: auto``, here with ``drift: off``) streams: `selfsense
    estimate` feeds the log chunk by chunk and equals the batch estimate within 1e-9 of range."""
    from selfsense.cli.estimate import estimate_log, streamable

    d = ROOT / "data" / "raw" / "sample"
    meta = sio.load_trials(d).set_index("trial")
    sigs = {t: stages.ingest(d, t, tmp_path / f"{t}.parquet") for t in meta.index}
    est = SelfSensingEstimator(config=SensingConfig(drift="off"), rig=sio.load_rig(d)).fit(sigs, meta)
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict(), default=float))
    assert streamable(model)
    assert est.hysteresis_.kind in REGISTRY and est.hysteresis_.kind != "modified_pi"   # the registry's selection
    t = "val_disp_large"
    estimate_log(model, d, d / meta.loc[t, "file"], tmp_path / "out.parquet", chunk=777, progress=False)
    got = pd.read_parquet(tmp_path / "out.parquet")
    ref = est.estimate(sigs[t])
    for col in ("dx_hat", "f_hat"):
        err = float(np.max(np.abs(got[col].to_numpy() - ref[col].to_numpy()))) / float(np.ptp(ref[col].to_numpy()))
        assert err <= 1e-9, (col, err)


@pytest.mark.parametrize("fmt", ["csv", "scope_csv", "mat", "tdms"])
def test_cli_reads_every_log_format(fitted, tmp_path, fmt):
    """`selfsense estimate` reads the formats the pipeline reads (CSV with extra channels or a scope preamble,
    MAT, TDMS) and gives the same estimates as from Parquet."""
    from selfsense.cli import main

    d, est, sigs = fitted
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict()))
    raw = _raw(d, "obj_val")
    ref_log = tmp_path / "log.parquet"
    raw.to_parquet(ref_log, index=False)
    ref_out = tmp_path / "ref.parquet"
    assert main(["estimate", "--model", str(model), "--dataset", str(d), "--log", str(ref_log),
                 "--out", str(ref_out), "--chunk", "400"]) == 0
    if fmt == "csv":
        log = tmp_path / "log.csv"
        raw.assign(aux_channel=1.0).to_csv(log, index=False, float_format="%.17g")
    elif fmt == "scope_csv":
        log = tmp_path / "scope.csv"
        body = raw.to_csv(index=False, float_format="%.17g")
        log.write_text("Instrument,scope\nDate,today\n" + body)
    elif fmt == "mat":
        import scipy.io

        log = tmp_path / "log.mat"
        scipy.io.savemat(log, {c: raw[c].to_numpy() for c in raw.columns})
    else:
        from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

        log = tmp_path / "log.tdms"
        objs = [RootObject({}), GroupObject("g")] + [ChannelObject("g", c, raw[c].to_numpy()) for c in raw.columns]
        with TdmsWriter(log) as w:
            w.write_segment(objs)
    out = tmp_path / "out.parquet"
    assert main(["estimate", "--model", str(model), "--dataset", str(d), "--log", str(log), "--out", str(out),
                 "--chunk", "333"]) == 0
    got, ref = pd.read_parquet(out), pd.read_parquet(ref_out)
    assert len(got) == len(raw)
    for col in ("t", "dx_hat", "f_hat"):
        _assert_close(got[col].to_numpy(), ref[col].to_numpy(), f"{fmt} {col}")


def test_selfsense_stream_piped_line_by_line_gives_the_batch_result(fitted, tmp_path):
    """`selfsense stream` in a child process, the log written into its stdin one line at a time and each estimate
    read back before the next line is sent (what a DAQ program piping into it sees): equal to the batch estimate."""
    import subprocess
    import sys

    d, est, sigs = fitted
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict()))
    raw = _raw(d, "obj_val")
    proc = subprocess.Popen([sys.executable, "-m", "selfsense", "stream", "--model", str(model), "--dataset", str(d)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1)
    proc.stdin.write("t,u_cmd,v_shunt,relay\n")
    proc.stdin.flush()
    assert proc.stdout.readline().strip() == "t,dx_hat,f_hat"
    rows = []
    for t, u, v, r in raw[["t", "u_cmd", "v_shunt", "relay"]].itertuples(index=False):
        proc.stdin.write(f"{t!r},{u!r},{v!r},{r!r}\n")
        proc.stdin.flush()
        rows.append([float(x) for x in proc.stdout.readline().split(",")])   # answered before the next line
    proc.stdin.close()
    assert proc.wait(timeout=60) == 0, proc.stderr.read()
    got = np.array(rows)
    batch = est.estimate(sigs["obj_val"])
    np.testing.assert_array_equal(got[:, 0], raw["t"].to_numpy())
    _assert_close(got[:, 1], batch["dx_hat"].to_numpy(), "selfsense stream dx_hat")
    _assert_close(got[:, 2], batch["f_hat"].to_numpy(), "selfsense stream f_hat")


def test_selfsense_stream_errors_name_the_line_and_the_model(fitted, tmp_path, capsys):
    from selfsense.cli import main as selfsense_main

    d, est, sigs = fitted
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict()))
    log = tmp_path / "log.csv"
    log.write_text("t,u_cmd,v_shunt,relay\n0.0,0.0,0.001,1\n0.001,0.0,oops,1\n")
    assert selfsense_main(["stream", "--model", str(model), "--dataset", str(d), "--input", str(log)]) == 2
    err = capsys.readouterr().err
    assert "line 3" in err and "oops" in err
    # a model with the offset-drift member (fitted over whole trials) is refused at once, naming file and member
    d2 = est.to_dict()
    d2["offset_drift"] = True
    m2 = tmp_path / "drifting.json"
    m2.write_text(json.dumps(d2))
    assert selfsense_main(["stream", "--model", str(m2), "--dataset", str(d), "--input", str(log)]) == 2
    err = capsys.readouterr().err
    assert "drifting.json" in err and "offset-drift member" in err
    # ... and streams with --drift causal (the drift fitted on the rest segments seen so far)
    ok = tmp_path / "ok.csv"
    ok.write_text("t,u_cmd,v_shunt,relay\n0.0,0.0,0.001,1\n0.001,0.0,0.001,1\n0.002,0.5,0.002,0\n")
    assert selfsense_main(["stream", "--model", str(m2), "--dataset", str(d), "--input", str(ok),
                           "--drift", "causal"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[0] == "t,dx_hat,f_hat" and len(out) == 4


def test_selfsense_stream_follows_a_file_that_is_still_being_written(fitted, tmp_path):
    import signal
    import subprocess
    import sys

    d, est, sigs = fitted
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict()))
    raw = _raw(d, "obj_val")
    lines = [f"{t!r},{u!r},{v!r},{r!r}\n" for t, u, v, r in raw[["t", "u_cmd", "v_shunt", "relay"]]
             .itertuples(index=False)]
    log = tmp_path / "growing.csv"
    log.write_text("t,u_cmd,v_shunt,relay\n" + "".join(lines[:300]))
    # SIGINT at its default in the child, as under a terminal: a test runner started in the background by a
    # non-interactive shell inherits SIGINT ignored, and Python then installs no KeyboardInterrupt handler
    proc = subprocess.Popen([sys.executable, "-m", "selfsense", "stream", "--model", str(model), "--dataset", str(d),
                             "--input", str(log), "--follow"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, bufsize=1, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    got = [proc.stdout.readline() for _ in range(301)]          # header + the 300 samples already there
    with log.open("a") as fh:                                   # the DAQ program writes on
        fh.write("".join(lines[300:]))
    got += [proc.stdout.readline() for _ in range(len(lines) - 300)]
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=60) == 0, proc.stderr.read()
    rows = np.array([[float(x) for x in g.split(",")] for g in got[1:]])
    batch = est.estimate(sigs["obj_val"])
    _assert_close(rows[:, 1], batch["dx_hat"].to_numpy(), "followed dx_hat")


# ---- every model kind (real-time self-sensing with the model the pipeline selects) -------------------------------
TOL = 1e-9

CASES = {  # name -> estimator config (the synthetic dataset of test_streaming: a play-operator H(q))
    "linear": {"h_model": "linear", "h_identification": "joint"},
    "pi": {"h_model": "pi", "h_identification": "joint"},
    "preisach": {"h_model": "preisach", "h_identification": "joint"},
    "preisach (reversible)": {"h_model": "preisach", "h_identification": "joint"},   # H replaced in fitted_kinds
    "ri": {"h_model": "ri", "h_identification": "joint"},
    "duhem": {"h_model": "duhem", "h_identification": "joint"},
    "modified_pi": {"h_model": "modified_pi", "h_identification": "joint"},
    "modified_pi (thesis)": {"h_model": "modified_pi", "h_identification": "thesis"},
    "RICreepH": {"h_model": "ri", "h_identification": "thesis"},
}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("kinds")
    return make_dataset(tmp), tmp


@pytest.fixture(scope="module")
def fitted_kinds(data):
    d, tmp = data
    out = {}
    for name, cfg in CASES.items():
        est, sigs = _fit(d, tmp, dc_offset=False, **cfg)
        out[name] = est
    # h_model 'linear' still lets the selection keep a PI when the straight line is worse: set the line itself
    from selfsense.hysteresis.models import LinearH, PreisachH

    cal = sigs["free_cal"]
    out["linear"].hysteresis_ = LinearH().fit(cal["q"].to_numpy(), cal["V"].to_numpy(), 1e-3)
    # a Preisach model with plays and its reversible part (PreisachH n_rev: ramps of Q at fixed knots)
    rev = out["preisach (reversible)"]
    rev.hysteresis_ = PreisachH(n_grid=8, n_play=5, n_rev=12, ridge=1e-4).fit(cal["q"].to_numpy(),
                                                                              cal["V"].to_numpy(), 1e-3)
    assert np.ptp(rev.hysteresis_.coef_[36 + 5:36 + 5 + 11]) > 0, "the reversible part is not exercised"
    # a model JSON written before the thesis identification became the registry's ModifiedPIH holds a GaugedH
    legacy = SelfSensingEstimator.from_dict(out["modified_pi (thesis)"].to_dict(), out["pi"].rig)
    h = legacy.hysteresis_
    legacy.hysteresis_ = GaugedH(h.inner_, h.sign_, h.c_)
    legacy = SelfSensingEstimator.from_dict(legacy.to_dict(), legacy.rig)   # through its JSON form
    assert type(legacy.hysteresis_).__name__ == "GaugedH"
    out["GaugedH"] = legacy
    return out, sigs


def _range_err(a, b):
    b = np.asarray(b, float)
    return float(np.max(np.abs(np.asarray(a, float) - b))) / max(float(np.ptp(b)), 1e-300)


def _kind_of(est):
    h = est.hysteresis_
    return h.kind if hasattr(h, "kind") and hasattr(h, "predict") else type(h).__name__


def test_every_stream_kind_is_covered(fitted_kinds):
    """The cases cover every kind the stream knows, and every registry kind (a new kind must join the test)."""
    ests, _ = fitted_kinds
    got = {_kind_of(e) for e in ests.values()}
    assert set(REGISTRY) <= got, f"registry kinds without a streaming test: {set(REGISTRY) - got}"
    assert got == set(stream_kinds()) - {"RIModel"}, got


@pytest.mark.parametrize("name", [*CASES, "GaugedH"])
def test_stream_equals_batch_every_kind(fitted_kinds, data, name):
    ests, sigs = fitted_kinds
    d, _ = data
    est = ests[name]
    # the leakage and rest-offset members on every kind (a hand-set conductance: the synthetic device has none)
    est = SelfSensingEstimator.from_dict(est.to_dict(), est.rig)
    est.leakage_s_ = 2.0e-9
    est.coef_["dx0"] = 1.0e-5
    est.config.dc_offset = True
    s = SelfSensingStream(est)
    for trial in ("free_val", "obj_val"):
        raw = _raw(d, trial)
        batch = est.estimate(sigs[trial])
        cols = [raw[c].to_numpy() for c in ("u_cmd", "v_shunt", "relay", "t")]
        s.reset()
        cuts = [0, 1, 150, 151, 777, len(raw)]
        parts = [s.process(*[c[a:b] for c in cols[:3]], t=cols[3][a:b], full=True) for a, b in zip(cuts, cuts[1:])]
        out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        assert np.ptp(batch["V_H"]) > 0, "H does nothing: the test would not see a wrong operator state"
        for col in ("V_H", "V_p", "dx_raw", "f_raw", "dx_hat", "f_hat"):
            assert _range_err(out[col], batch[col]) <= TOL, (name, trial, col, _range_err(out[col], batch[col]))
        # sample by sample: the same code as a block
        s.reset()
        k = 400
        steps = np.array([s.step(*[c[i] for c in cols[:3]], t=cols[3][i]) for i in range(k)])
        np.testing.assert_array_equal(steps[:, 0], out["dx_hat"][:k])
        np.testing.assert_array_equal(steps[:, 1], out["f_hat"][:k])


def _step(s, cols, k, relay=None, t_of=None):
    """``s.step`` on sample k of cols = (u_cmd, v_shunt, relay, t or None), with another relay value or the time of
    sample ``t_of``."""
    u, v, r, t = cols
    return s.step(u[k], v[k], r[k] if relay is None else relay, None if t is None else t[k if t_of is None else t_of])


@pytest.mark.parametrize("name", [*CASES, "GaugedH"])
def test_step_is_the_block_path_every_kind(fitted_kinds, data, name):
    """step() gives the bits of process() on the whole trial for every kind, with time stamps and on the
    constructor's dt, across a get_state / set_state detour, after rejected samples and interleaved with a block.

    For Kuhnen's operator step() and process() run separately compiled copies of the same kernel
    (``hysteresis._kernels.gamma_kernel``, compiled with reassociation allowed): equal bits on a given build rest on
    the compiler optimising both copies alike, which this test checks (it fails, rather than a tolerance hiding it, if
    a numba or LLVM version ever vectorises them differently)."""
    ests, _ = fitted_kinds
    d, _ = data
    raw = _raw(d, "obj_val")
    u, v, r, t = (raw[c].to_numpy() for c in ("u_cmd", "v_shunt", "relay", "t"))
    n = len(raw)
    for kw, tt in (({}, t), ({"dt": float(np.median(np.diff(t)))}, None)):
        cols = (u, v, r, tt)
        s = SelfSensingStream(ests[name], **kw)
        whole = s.process(u, v, r, tt)
        s.reset()
        out = [_step(s, cols, k) for k in range(500)]
        saved = s.get_state()
        for k in range(500, 520):
            _step(s, cols, k)
        s.set_state(saved)
        out += [_step(s, cols, k) for k in range(500, 700)]
        with pytest.raises(StreamError):
            _step(s, cols, 700, relay=0.5)
        if tt is not None:
            with pytest.raises(StreamError):
                _step(s, cols, 700, t_of=699)
        out += [_step(s, cols, k) for k in range(700, 1000)]
        out += list(zip(*s.process(u[1000:1200], v[1000:1200], r[1000:1200], None if tt is None else tt[1000:1200])))
        out += [_step(s, cols, k) for k in range(1200, n)]
        out = np.array(out)
        assert s.n_samples == n
        assert np.ptp(whole[0]) > 0 and np.ptp(whole[1]) > 0
        np.testing.assert_array_equal(out[:, 0], whole[0], err_msg=f"{name} {kw}: dx_hat")
        np.testing.assert_array_equal(out[:, 1], whole[1], err_msg=f"{name} {kw}: f_hat")


@pytest.mark.parametrize("name", ["preisach", "duhem", "RICreepH", "GaugedH"])
def test_state_round_trip_resumes_exactly(fitted_kinds, data, name):
    """get_state / set_state: a stream resumed from a saved state continues exactly (checkpointing a controller)."""
    ests, sigs = fitted_kinds
    d, _ = data
    s = SelfSensingStream(ests[name])
    raw = _raw(d, "obj_val")
    u, v, r, t = (raw[c].to_numpy() for c in ("u_cmd", "v_shunt", "relay", "t"))
    whole = s.process(u, v, r, t)
    s.reset()
    s.process(u[:900], v[:900], r[:900], t[:900])
    saved = s.get_state()
    s.process(u[900:1000], v[900:1000], r[900:1000], t[900:1000])   # moves on ...
    s.set_state(saved)                                             # ... and back
    tail = s.process(u[900:], v[900:], r[900:], t[900:])
    np.testing.assert_array_equal(tail[0], whole[0][900:])
    np.testing.assert_array_equal(tail[1], whole[1][900:])


@pytest.mark.parametrize("name", [n for n in CASES if CASES[n]["h_identification"] == "joint"])
def test_h_stream_is_predict_every_registry_kind(fitted_kinds, name):
    """HStream on blocks and single samples, across a get_state / set_state detour, gives the bits of the registry
    model's predict on the whole record (the stream's compiled H and predict's kernels agree)."""
    ests, sigs = fitted_kinds
    m = ests[name].hysteresis_
    q = sigs["obj_val"]["q"].to_numpy()
    dt = 1e-3
    h = HStream(m, dt)
    whole = m.predict(q, dt)
    out = [h.process(q[:1]), h.process(q[1:150])]
    out += [h.process(q[k:k + 1]) for k in range(150, 400)]
    saved = h.get_state()
    h.process(q[400:450])
    h.set_state(saved)
    out.append(h.process(q[400:]))
    assert np.ptp(whole) > 0
    np.testing.assert_array_equal(np.concatenate(out), whole)


def test_offset_drift_member_is_refused_by_name(fitted_kinds):
    ests, _ = fitted_kinds
    est = SelfSensingEstimator.from_dict(ests["pi"].to_dict(), ests["pi"].rig)
    est.offset_drift_ = True
    with pytest.raises(NotImplementedError, match="offset-drift member"):
        SelfSensingStream(est)


def test_crafted_model_json_errors(fitted_kinds, data, tmp_path):
    """A model JSON of a wrong kind, a wrong shape or a missing key: a ValueError naming the file."""
    ests, _ = fitted_kinds
    d, _ = data
    good = ests["preisach"].to_dict()
    bad_kind = json.loads(json.dumps(good))
    bad_kind["hysteresis"]["params"]["kind"] = "tanh_net"
    bad_shape = json.loads(json.dumps(good))
    bad_shape["hysteresis"]["params"]["coef"] = bad_shape["hysteresis"]["params"]["coef"][:7]
    missing = json.loads(json.dumps(good))
    del missing["coef"]
    for name, dd, msg in (("kind", bad_kind, "unknown kind 'tanh_net'"), ("shape", bad_shape, "coef"),
                          ("missing", missing, "missing key 'coef'")):
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps(dd))
        with pytest.raises(ValueError, match=msg) as e:
            SelfSensingStream.from_json(p, d).process(np.zeros(3), np.zeros(3), np.ones(3), t=[0.0, 1e-3, 2e-3])
        assert str(p) in str(e.value)


def test_hstream_rejects_unknown_model():
    with pytest.raises(NotImplementedError, match="cannot stream"):
        HStream(object(), 1e-3)
    assert "preisach" in stream_kinds() and "GaugedH" in stream_kinds()


def test_causal_offset_drift_member_streams_and_recovers_most_of_the_batch_gain(tmp_path):
    """A Preisach device with a 10 uV/s in-amp offset drift and the offset-drift member switched on (fitted over whole
    trials in batch; the default calibration decides it beside the creep member and here drops it). ``drift='causal'`` fits the same ramp on the rest segments seen so far: any
    split into blocks gives the same bits, the fit is updated during the trial, and on the free-tip displacement
    validation trial the causal estimate recovers most of what the batch member gains over no drift compensation."""
    from selfsense.signals import prepare_trial
    from selfsense.sim.families import draw_device
    from selfsense.sim.simulate import simulate_dataset

    sc = draw_device("preisach", 21, "clean")
    sc["trials"] = [dict(t, duration=min(t["duration"], 14)) for t in sc["trials"]]
    sc["effects"].update({"offset_drift": 10.0, "preload": 0.0})
    d = tmp_path / sc["name"]
    simulate_dataset(sc, out_dir=d, truth_dir=tmp_path / (sc["name"] + ".truth"), contributions=False)
    rig = sio.load_rig(d)
    meta = sio.load_trials(d).set_index("trial")
    sigs = {t: prepare_trial(sio.trial_signals(d, t, rig=rig), rig) for t in meta.index}
    est = SelfSensingEstimator(config=SensingConfig(), rig=rig, members={"offset_drift": "on"}).fit(sigs, meta)
    assert est.offset_drift_, "the offset-drift member forced on is not carried"
    with pytest.raises(NotImplementedError, match="drift='causal'"):
        SelfSensingStream(est)
    none = SelfSensingEstimator.from_dict(est.to_dict(), est.rig)
    none.offset_drift_ = False
    t = "val_disp_free_mixed"
    raw = sio.read_log(d / meta.loc[t, "file"])
    cols = [raw[c].to_numpy() for c in ("u_cmd", "v_shunt", "relay", "t")]
    s = SelfSensingStream(est, drift="causal")
    whole = s.process(*cols[:3], t=cols[3])[0]
    assert s.drift.coefficients != (0.0, 0.0), "the causal drift fit never updated"
    s.reset()
    cuts = [0, 1, 500, 501, 4321, len(raw)]
    split = np.concatenate([s.process(*[c[a:b] for c in cols[:3]], t=cols[3][a:b])[0] for a, b in zip(cuts, cuts[1:])])
    np.testing.assert_array_equal(split, whole)
    ref = sigs[t]["dx_ref"].to_numpy()
    ok = np.isfinite(ref)

    def err(x):
        return float(np.mean(np.abs(x[ok] - ref[ok])))

    e_batch, e_none = err(est.estimate(sigs[t])["dx_hat"].to_numpy()), err(none.estimate(sigs[t])["dx_hat"].to_numpy())
    e_causal = err(whole)
    assert e_batch < e_none, "the batch drift member does not help here: the test would not measure anything"
    assert e_causal < e_none - 0.5 * (e_none - e_batch), (e_batch, e_causal, e_none)


def _bad_nan(raw, tmp_path):
    raw = raw.copy()
    raw.loc[1000, "v_shunt"] = np.nan
    p = tmp_path / "nan.parquet"
    raw.to_parquet(p, index=False)
    return p, ("nan.parquet", "'v_shunt'", "row 1001", "finite")


def _bad_text(raw, tmp_path):
    p = tmp_path / "text.csv"
    lines = raw.to_csv(index=False, float_format="%.17g").splitlines()
    cells = lines[901].split(",")            # data row 901
    cells[list(raw.columns).index("u_cmd")] = "abc"
    lines[901] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    return p, ("text.csv", "'u_cmd'", "row 901", "'abc'")


def _bad_time(raw, tmp_path):
    raw = raw.copy()
    t = raw["t"].to_numpy().copy()
    t[400], t[399] = t[399], t[400]          # across the first block boundary (--chunk 400)
    raw["t"] = t
    p = tmp_path / "time.parquet"
    raw.to_parquet(p, index=False)
    return p, ("time.parquet", "'t'", "row 401", "decreasing")


def _bad_relay(raw, tmp_path):
    raw = raw.assign(relay=raw["relay"] * 5.0)    # a 0 / 5 V relay line logged as it is
    p = tmp_path / "relay.parquet"
    raw.to_parquet(p, index=False)
    return p, ("relay.parquet", "'relay'", "row 1:", "0 or 1")


@pytest.mark.parametrize("make", [_bad_nan, _bad_text, _bad_time, _bad_relay],
                         ids=["nan", "text-cell", "time-across-blocks", "relay-0-5V"])
def test_cli_estimate_refuses_bad_samples_naming_file_column_and_row(fitted, tmp_path, capsys, make):
    """`selfsense estimate` checks every block it streams as the data contract checks a whole log: a NaN (which
    the charge integral would carry into every later sample), a text cell and a time step backwards (also across a
    block boundary) end with one line naming the file, the column and the file-wide row, exit 2, and no output."""
    from selfsense.cli import main

    d, est, sigs = fitted
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict()))
    log, frags = make(_raw(d, "obj_val"), tmp_path)
    out = tmp_path / "out.parquet"
    assert main(["estimate", "--model", str(model), "--dataset", str(d), "--log", str(log), "--out", str(out),
                 "--chunk", "400"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and all(f in err for f in frags), err
    assert not out.exists()


def test_selfsense_stream_refuses_a_nan_sample(fitted, tmp_path, capsys):
    from selfsense.cli import main as selfsense_main

    d, est, sigs = fitted
    model = tmp_path / "sensing.json"
    model.write_text(json.dumps(est.to_dict()))
    log = tmp_path / "log.csv"
    log.write_text("t,u_cmd,v_shunt,relay\n0.0,0.0,0.001,1\n0.001,0.0,nan,1\n")
    assert selfsense_main(["stream", "--model", str(model), "--dataset", str(d), "--input", str(log)]) == 2
    err = capsys.readouterr().err
    assert "line 3" in err and "finite" in err
