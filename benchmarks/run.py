#!/usr/bin/env python
"""selfsense speed and memory benchmarks; writes a Markdown report and its figures as JSON.

    python benchmarks/run.py [--quick] --out benchmarks/RESULTS.md

Every figure is measured in this run, on one core (NUMBA/OMP/MKL/OpenBLAS threads = 1, process pinned to one
CPU; the Snakemake run of (d) gets 2 cores), as an absolute value and as a ratio against a straightforward
NumPy reference measured in the same run:

(a) modified PI operator with creep (15 play, 15 superposition, 15 x 4 creep; thesis 000_18d138f03f1777c3.txt
    eq. 42): hysteresis package kernel (ModifiedPI.apply) vs a NumPy reference vectorised across operators with a
    Python loop over samples (run on fewer samples).
(b) SelfSensingStream: per-sample step [us] and block mode [samples/s], equality to the batch pipeline; per model
    kind (every H model the pipeline can select, fitted on data/raw/sample) and for the default model on
    data/raw/tweezer_sim: cost per sample in blocks of 1 (step), 100 and a whole trial.
(c) QP calibration (fit_modified_pi) on a 60,000-sample trial: Gram assembly and solve.
(d) the Snakemake pipeline on data/raw/tweezer_sim, cold, --cores 2, as benchmarks/pipeline_speed.py measures it,
    with the Table 3 and the modes table of that run.
(e) the stage-wise gap diagnostic's blind cases per second (selfsense.gap.blind).
(f) peak RSS of the chunked CLI on a 36-million-sample (1 h at 10 kHz) log.
(g) scaling: time vs trial length and vs number of trials, with a linear fit.
"""
from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import _synth  # noqa: E402

ALL_CPUS = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []


def pin_one_core():
    if ALL_CPUS:
        os.sched_setaffinity(0, {ALL_CPUS[0]})


def _unpin():  # preexec for children that may use several cores (Snakemake)
    if ALL_CPUS:
        os.sched_setaffinity(0, set(ALL_CPUS))


def best_time(fn, repeat=5, min_time=0.0):
    """Best wall time [s] of ``repeat`` calls (each call may loop internally)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def fmt_rate(x):
    return f"{x:,.3g}" if x < 1e3 else f"{x:,.0f}"


def verdict(ok):
    return "met" if ok else "NOT met"


# ------------------------------------------------------------------------------------------------ (a) operator
def numpy_operator_reference(model, x):
    """Straightforward NumPy reference of eq. (42): vectorised across operators, Python loop over samples."""
    rH, wH, p = model.r_H, model.w_H, model.z_H0.copy()
    m = len(model.a_K)
    rC = np.repeat(model.r_K, m)
    wC = np.repeat(model.w_K, m)
    gC = np.tile(-np.expm1(-model.a_K * model.dt), len(model.r_K))
    c = model.Z_K0.reshape(-1).copy()
    rS, wS = model.r_S, model.w_S
    pos, neg, zero = rS > 0, rS < 0, rS == 0
    y = np.empty(len(x))
    xl = None
    for k in range(len(x)):
        xk = x[k]
        p = np.maximum(xk - rH, np.minimum(xk + rH, p))
        if xl is not None:
            c = c + gC * (np.clip(c, xl - rC, xl + rC) - c)
        xl = xk
        u = wH @ p + wC @ c + model.offset
        y[k] = (wS[zero].sum() * u + wS[pos] @ np.maximum(u - rS[pos], 0.0)
                + wS[neg] @ np.minimum(u - rS[neg], 0.0))
    return y


def bench_operator(quick):
    model = _synth.operator(dt=1e-4)
    N = 400_000 if quick else 2_000_000
    Nref = 4_000 if quick else 20_000
    t = np.arange(N) * 1e-4
    x = _synth.Q_MAX * (0.5 - 0.5 * np.cos(2 * np.pi * 0.7 * t)) * (0.7 + 0.3 * np.sin(2 * np.pi * 0.13 * t))
    model.apply(x[:100])  # JIT warm-up (cached)
    t_pkg = best_time(lambda: model.apply(x), repeat=3 if quick else 5)
    y_pkg = model.apply(x)[0]
    t_ref = best_time(lambda: numpy_operator_reference(model, x[:Nref]), repeat=1 if quick else 2)
    y_ref = numpy_operator_reference(model, x[:Nref])
    rng = float(np.ptp(y_pkg))
    err_ref = float(np.max(np.abs(y_ref - y_pkg[:Nref])) / rng)
    r_pkg, r_ref = N / t_pkg, Nref / t_ref
    return {
        "N": N, "Nref": Nref, "rate_pkg": r_pkg, "rate_ref": r_ref, "ratio_pkg": r_pkg / r_ref, "err_ref": err_ref,
        "ok": r_pkg >= 1e7 and r_pkg / r_ref >= 100,
    }


# ------------------------------------------------------------------------------------------------ (b) streaming
def numpy_stream_step_reference(est, raw):
    """NumPy per-sample reference stream (the same chain as SelfSensingStream, operator sums vectorised)."""
    rig = est.rig
    h = est.hysteresis_
    m = h.inner
    rH, wH, p = m.r_H, m.w_H, m.z_H0.copy()
    mm = len(m.a_K)
    rC, wC = np.repeat(m.r_K, mm), np.repeat(m.w_K, mm)
    gC = np.tile(-np.expm1(-m.a_K * m.dt), len(m.r_K))
    c = m.Z_K0.reshape(-1).copy()
    rS, wS = m.r_S, m.w_S
    pos, neg = rS > 0, rS < 0
    w0 = wS[rS == 0].sum()
    co = est.coef_
    zl = est.config.zero_input_v / rig.amplifier_gain
    R, G, I = rig.shunt_resistance_ohm, rig.amplifier_gain, rig.inamp_gain
    t, u_, v_, r_ = (raw[k].to_numpy() for k in ("t", "u_cmd", "v_shunt", "relay"))
    n = len(t)
    dx_out, f_out = np.empty(n), np.empty(n)
    off_sum = off_n = 0.0
    off = None
    csum = base = 0.0
    xl = None
    vs_last = t_last = 0.0
    dc = 0.0
    for k in range(n):
        sh = r_[k] == 1.0
        Vs = v_[k] / I
        V = G * u_[k] - Vs
        if off is None:
            if sh:
                off_sum += Vs
                off_n += 1
            else:
                off = off_sum / off_n
        inc = 0.0
        if k and not sh:
            inc = 0.5 * ((Vs - off) / R + (vs_last - off) / R) * (t[k] - t_last)
        csum += inc
        if sh:
            base, q = csum, 0.0
        else:
            q = csum - base
        t_last, vs_last = t[k], Vs
        p = np.maximum(q - rH, np.minimum(q + rH, p))
        if xl is not None:
            c = c + gC * (np.clip(c, xl - rC, xl + rC) - c)
        xl = q
        uu = wH @ p + wC @ c + m.offset
        g = w0 * uu + wS[pos] @ np.maximum(uu - rS[pos], 0.0) + wS[neg] @ np.minimum(uu - rS[neg], 0.0)
        VH = h.sign * (g - h.c * q)
        Vp = V - VH
        dxr = 0.0 if sh else co["A1"] * q + co["A2"] * Vp
        fr = 0.0 if sh else co["B21"] * q + co["B22"] * Vp
        if abs(u_[k]) <= zl:
            dc = dxr
        dx_out[k] = min(max(dxr - dc, est.ranges_["dx"][0]), est.ranges_["dx"][1])
        f_out[k] = min(max(fr, est.ranges_["f"][0]), est.ranges_["f"][1])
    return dx_out, f_out


def bench_stream(quick):
    from selfsense.sensing.streaming import SelfSensingStream

    est = _synth.estimator(dt=1e-4)
    N = 1_000_000 if quick else 4_000_000
    Nstep = 100_000 if quick else 400_000
    Nref = 5_000 if quick else 20_000
    raw = _synth.raw_log(N)
    s = SelfSensingStream(est)
    s.process(raw["u_cmd"][:10], raw["v_shunt"][:10], raw["relay"][:10], t=raw["t"][:10])  # warm-up
    u, v, r, t = (raw[k].to_numpy() for k in ("u_cmd", "v_shunt", "relay", "t"))

    def block():
        s.reset()
        return s.process(u, v, r, t=t)

    t_block = best_time(block, repeat=3 if quick else 5)
    dx, f = block()
    # the batch pipeline (stages.ingest -> estimator.estimate), NumPy + the hysteresis package kernel
    t_batch = best_time(lambda: _synth.batch_estimate(est, raw), repeat=2 if quick else 3)
    b = _synth.batch_estimate(est, raw)
    err_dx = float(np.max(np.abs(dx - b["dx_hat"].to_numpy())) / np.ptp(b["dx_hat"].to_numpy()))
    err_f = float(np.max(np.abs(f - b["f_hat"].to_numpy())) / np.ptp(b["f_hat"].to_numpy()))
    # per-sample: the public method from Python, and the bare jitted kernel call (no method/argument handling)
    ul, vl, rl, tl = (a[:Nstep].tolist() for a in (u, v, r, t))

    def steps():
        s.reset()
        st = s.step
        for k in range(Nstep):
            st(ul[k], vl[k], rl[k], tl[k])

    t_step = best_time(steps, repeat=3) / Nstep
    s.reset()
    st_out = np.array([s.step(ul[k], vl[k], rl[k], tl[k]) for k in range(Nstep)])
    step_eq = float(np.max(np.abs(st_out[:, 0] - dx[:Nstep])) / np.ptp(b["dx_hat"].to_numpy()))
    head = raw.iloc[:Nref]
    t_ref = best_time(lambda: numpy_stream_step_reference(est, head), repeat=1)
    ref_dx, ref_f = numpy_stream_step_reference(est, head)
    err_ref = float(np.max(np.abs(ref_dx - dx[:Nref])) / np.ptp(b["dx_hat"].to_numpy()))
    t_ref_step = t_ref / Nref
    return {
        "N": N, "Nstep": Nstep, "Nref": Nref, "rate_block": N / t_block, "rate_batch": N / t_batch,
        "step_us": t_step * 1e6, "ref_step_us": t_ref_step * 1e6,
        "err_dx": err_dx, "err_f": err_f, "step_eq": step_eq, "err_ref": err_ref,
        "ok": t_step <= 10e-6 and N / t_block >= 1e6 and max(err_dx, err_f) <= 1e-12,
        "kinds": bench_stream_kinds(quick),
    }


STREAM_KINDS = (  # label, estimator configuration (fitted on data/raw/sample, drift off so that the model streams)
    ("linear", {"h_model": "linear", "h_identification": "joint"}),
    ("pi", {"h_model": "pi", "h_identification": "joint"}),
    ("preisach", {"h_model": "preisach", "h_identification": "joint"}),
    ("ri", {"h_model": "ri", "h_identification": "joint"}),
    ("duhem", {"h_model": "duhem", "h_identification": "joint"}),
    ("modified_pi", {"h_model": "modified_pi", "h_identification": "joint"}),
    ("modified_pi (thesis identification)", {"h_model": "modified_pi", "h_identification": "thesis"}),
    ("RICreepH (thesis RI)", {"h_model": "ri", "h_identification": "thesis"}),
)


C_BENCH_DRIVER = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "selfsense_estimator.h"
int main(int argc, char **argv) {
    long n = 0, cap = 1 << 16, k, rep, reps = argc > 1 ? atol(argv[1]) : 20;
    double *u = malloc(cap * sizeof *u), *v = malloc(cap * sizeof *v), dx, f, sink = 0.0, best = 1e300, ns;
    int *r = malloc(cap * sizeof *r);
    struct timespec a, b;
    ss_state s;
    while (scanf("%lf,%lf,%d", &u[n], &v[n], &r[n]) == 3) {
        if (++n == cap) { cap *= 2; u = realloc(u, cap * sizeof *u); v = realloc(v, cap * sizeof *v);
                          r = realloc(r, cap * sizeof *r); }
    }
    for (rep = 0; rep < reps; rep++) {
        ss_init(&s);
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (k = 0; k < n; k++) { if (ss_step(&s, u[k], v[k], r[k], &dx, &f)) return 3; sink += dx + f; }
        clock_gettime(CLOCK_MONOTONIC, &b);
        ns = ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / n;
        if (ns < best) best = ns;
    }
    printf("%.4f %ld %.17g\n", best, n, sink);
    return 0;
}
"""


def _c_cost(est, dataset, raw, sig, work: Path, name: str, repeat: int):
    """ns per sample of the exported C (cc -O2, best of ``repeat`` passes over the trial) and its max deviation
    from the batch estimate (of range); None when there is no C compiler."""
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        return None
    from selfsense.sensing.export_c import export_c

    od = work / name
    od.mkdir(parents=True, exist_ok=True)
    model = od / "model.json"
    model.write_text(json.dumps(est.to_dict()))
    dt = float(np.median(np.diff(raw["t"].to_numpy())))
    _, c = export_c(model, dataset, od, dt=dt)
    (od / "bench.c").write_text(C_BENCH_DRIVER)
    (od / "check.c").write_text(C_BENCH_DRIVER.replace('printf("%.4f %ld %.17g\\n", best, n, sink);', "")
                                .replace("sink += dx + f;", 'sink += dx + f; if (rep == 0) printf("%.17g,%.17g\\n", dx, f);'))
    for drv in ("bench", "check"):
        subprocess.run([cc, "-std=c99", "-O2", "-o", str(od / drv), str(od / f"{drv}.c"), str(c), "-I", str(od), "-lm"],
                       check=True, capture_output=True)
    inp = "".join(f"{u!r},{v!r},{int(r)}\n" for u, v, r in raw[["u_cmd", "v_shunt", "relay"]].itertuples(index=False))
    out = subprocess.run([str(od / "bench"), str(max(repeat, 5))], input=inp, capture_output=True, text=True, check=True)
    ns = float(out.stdout.split()[0])
    chk = subprocess.run([str(od / "check"), "1"], input=inp, capture_output=True, text=True, check=True)
    got = np.array([[float(x) for x in line.split(",")] for line in chk.stdout.split()])
    b = est.estimate(sig)
    err = max(float(np.max(np.abs(got[:, j] - b[col].to_numpy())) / max(np.ptp(b[col].to_numpy()), 1e-300))
              for j, col in enumerate(("dx_hat", "f_hat")))
    return {"c_ns": ns, "c_err": err}


def _stream_costs(est, raw, sig, repeat):
    """us per sample of SelfSensingStream in blocks of 1 (step), 100 and the whole trial; max |stream - batch| of
    range over dx and f."""
    from selfsense.sensing.streaming import SelfSensingStream

    s = SelfSensingStream(est)
    u, v, r, t = (np.ascontiguousarray(raw[k].to_numpy(dtype=float)) for k in ("u_cmd", "v_shunt", "relay", "t"))
    n = len(u)
    s.process(u[:10], v[:10], r[:10], t[:10])   # JIT warm-up

    def blocks(B, m=n):
        s.reset()
        for a in range(0, m, B):
            s.process(u[a:a + B], v[a:a + B], r[a:a + B], t[a:a + B])

    n1 = min(n, 5000)
    out = {"n": n, "us_whole": best_time(lambda: blocks(n), repeat) / n * 1e6,
           "us_100": best_time(lambda: blocks(100), repeat) / n * 1e6,
           "us_step": best_time(lambda: blocks(1, n1), 1) / n1 * 1e6}
    s.reset()
    dx, f = s.process(u, v, r, t)
    b = est.estimate(sig)
    out["err"] = max(float(np.max(np.abs(dx - b["dx_hat"].to_numpy())) / max(np.ptp(b["dx_hat"].to_numpy()), 1e-300)),
                     float(np.max(np.abs(f - b["f_hat"].to_numpy())) / max(np.ptp(b["f_hat"].to_numpy()), 1e-300)))
    h = est.hysteresis_
    out["model"] = h.label() if hasattr(h, "label") else type(h).__name__
    return out


def bench_stream_kinds(quick):
    """Per model kind on data/raw/sample, and the pipeline's default model on data/raw/tweezer_sim."""
    import yaml

    from selfsense import io as sio
    from selfsense import stages
    from selfsense.sensing import SelfSensingEstimator, SensingConfig

    repeat = 2 if quick else 3
    rows = []
    with tempfile.TemporaryDirectory(prefix="selfsense_bench_kinds_") as td:
        d = ROOT / "data" / "raw" / "sample"
        meta = sio.load_trials(d).set_index("trial")
        sigs = {t: stages.ingest(d, t, Path(td) / f"{t}.parquet") for t in meta.index}
        val = next(t for t in meta.index if meta.loc[t, "role"] == "validation")
        raw = sio.read_log(d / meta.loc[val, "file"])
        for label, cfg in STREAM_KINDS:
            est = SelfSensingEstimator(config=SensingConfig(drift="off", **cfg), rig=sio.load_rig(d)).fit(sigs, meta)
            if label == "linear":   # h_model 'linear' lets the selection keep a PI: stream the straight line itself
                from selfsense.hysteresis.models import LinearH

                c0 = meta.index[(meta["role"] == "calibration") & (meta["tip"] == "free")][0]
                est.hysteresis_ = LinearH().fit(sigs[c0]["q"].to_numpy(), sigs[c0]["V"].to_numpy(),
                                                float(np.median(np.diff(sigs[c0]["t"].to_numpy()))))
            row = {"label": label, "dataset": "sample", "trial": val, **_stream_costs(est, raw, sigs[val], repeat)}
            row.update(_c_cost(est, d, raw, sigs[val], Path(td) / "c", label.split(" ")[0], repeat) or {})
            rows.append(row)
        # the default model of the pipeline on the bundled virtual tweezer (config.yaml's calibration keys)
        d = ROOT / "data" / "raw" / "tweezer_sim"
        meta = sio.load_trials(d).set_index("trial")
        sigs = {t: stages.ingest(d, t, Path(td) / f"tw_{t}.parquet") for t in meta.index}
        cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
        est = SelfSensingEstimator(config=stages.sensing_config(cfg), rig=sio.load_rig(d)).fit(sigs, meta)
        val = next(t for t in meta.index if meta.loc[t, "role"] == "validation")
        if est.offset_drift_:
            rows.append({"label": "default (h_model: auto)", "dataset": "tweezer_sim", "trial": val,
                         "note": "the default adopts the offset-drift member here: estimated in batch"})
        else:
            raw = sio.read_log(d / meta.loc[val, "file"])
            row = {"label": "default (h_model: auto)", "dataset": "tweezer_sim", "trial": val,
                   **_stream_costs(est, raw, sigs[val], repeat)}
            row.update(_c_cost(est, d, raw, sigs[val], Path(td) / "c", "default", repeat) or {})
            rows.append(row)
    return rows


# ------------------------------------------------------------------------------------------------ (c) QP fit
def bench_qp(quick):
    from selfsense.hysteresis import identify
    from selfsense.hysteresis.operators import creep_operator, log_creep_eigenvalues

    N = 60_000
    dt = 1e-3
    model = _synth.operator(dt=dt)
    t = np.arange(N) * dt
    x = _synth.Q_MAX * (0.5 - 0.5 * np.cos(2 * np.pi * 0.5 * t)) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.05 * t))
    y = model(x) + 0.05 * np.random.default_rng(1).standard_normal(N)
    identify.fit_modified_pi(x[:2000], y[:2000], dt)  # warm-up (cvxpy import, JIT)
    t0 = time.perf_counter()
    fitted, rep = identify.fit_modified_pi(x, y, dt)
    t_total = time.perf_counter() - t0

    # the same steps as fit_modified_pi, timed separately (regressors + triangular factor, then the QP solve)
    def gram():
        sx, sy = np.max(np.abs(x)), np.max(np.abs(y))
        xs, ys = x / sx, y / sy
        r_Hs = np.arange(15) / 15
        lo, hi = ys.min(), ys.max()
        r_Ss = np.r_[0.0, lo + (hi - lo) * np.arange(1, 15) / 15]
        a_K = log_creep_eigenvalues(4, dt)
        bank = creep_operator(xs, r_Hs, a_K, dt).sum(axis=2)
        Q = identify._regressors(xs, ys, r_Hs, 0.0, r_Ss, bank, False)
        # the QP is posed on the factor R of Q = Q_ R (fit_modified_pi), not on the Gram matrix
        return np.linalg.qr(Q, mode="r") / np.sqrt(N), r_Hs, r_Ss, ys, a_K

    t_gram = best_time(gram, repeat=3)
    P, r_Hs, r_Ss, ys, a_K = gram()
    t0 = time.perf_counter()
    identify._solve_qp(P, 15, 15, 15, r_Hs, r_Ss, ys.min(), ys.max(), len(a_K), 1e-6, False, "range",
                       "CLARABEL", None)
    t_solve = time.perf_counter() - t0
    # NumPy reference of the regressor/Gram step: operators by the plain-Python reference module
    from selfsense.hysteresis import reference as ref

    n_small = 2_000 if quick else 6_000
    t0 = time.perf_counter()
    xs_small = x[:n_small] / np.max(np.abs(x))
    ref.play_operator(xs_small, r_Hs) if hasattr(ref, "play_operator") else None
    if hasattr(ref, "creep_operator"):
        ref.creep_operator(xs_small, r_Hs, a_K, dt)
    t_ref_small = time.perf_counter() - t0
    return {"N": N, "t_total": t_total, "t_gram": t_gram, "t_solve": t_solve, "rms_pct": rep.rms_pct,
            "status": rep.status, "ref_gram_est": t_ref_small * N / n_small, "n_small": n_small,
            "ok": t_total <= 1.0}


# ------------------------------------------------------------------------------------------------ (d) pipeline
def _table_rows(md: Path) -> list[list[str]]:
    """The body rows of the first Markdown table in ``md`` (cells stripped, bold markers removed)."""
    rows = []
    for line in md.read_text().splitlines():
        if line.startswith("|"):
            if not set(line.strip()) <= set("|-: "):
                rows.append([c.strip().strip("*").strip() for c in line.strip().strip("|").split("|")])
        elif rows:
            break
    return rows[1:]


def bench_pipeline(quick):
    """The cold pipeline on tweezer_sim, measured exactly as ``benchmarks/pipeline_speed.py`` measures it (one
    definition of "pipeline time"), plus the Table 3 and the modes table that run wrote."""
    if quick:
        return {"available": False, "why": "skipped in --quick mode (a cold run takes longer than the quick budget); "
                                           "run without --quick"}
    ds = ROOT / "data" / "raw" / "tweezer_sim"
    if not ds.exists():
        return {"available": False, "why": f"{ds.relative_to(ROOT)} does not exist in this checkout"}
    sys.path.insert(0, str(HERE))
    import pipeline_speed

    work = Path(tempfile.mkdtemp(prefix="selfsense_bench_pipe_"))
    try:
        r = pipeline_speed.run("tweezer_sim", 2, False, work)
        tables = work / "results" / "tweezer_sim" / "tables"
        t3 = {row[0]: row for row in _table_rows(tables / "table3.md")}
        modes = _table_rows(tables / "modes.md")
        return {"available": True, "snakemake_s": r["snakemake_s"], "wall_s": r["wall_s"], "load": r["load"],
                "rules": r["rules"], "table3_md": (tables / "table3.md").read_text(),
                "modes_md": (tables / "modes.md").read_text(), "table3_rows": t3, "modes_rows": modes,
                "slurm_probe_s": r.get("slurm_probe_s"), "probe_skipped": r.get("probe_skipped"),
                "ok": r["wall_s"] <= 15.0}
    finally:
        shutil.rmtree(work, ignore_errors=True)


# ------------------------------------------------------------------------------------------------ (e) gap
def bench_gap(quick):
    """The stage-wise gap diagnostic's blind campaign (``selfsense gap blind``): simulated cases per second on one
    core (each case: simulate a device with sealed effects, compute the stage residuals, diagnose)."""
    from selfsense.gap import blind

    n = 4 if quick else 16
    t0 = time.perf_counter()
    recs = [blind.run_case(i, 7) for i in range(n)]
    dt = time.perf_counter() - t0
    return {"available": True, "entry": f"selfsense.gap.blind.run_case(i, seed=7) for i < {n}", "n": len(recs),
            "seconds": dt, "rate": len(recs) / dt}


# ------------------------------------------------------------------------------------------------ (f) memory
def bench_memory(quick, tmp: Path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    import yaml

    n_total = 3_600_000 if quick else 36_000_000
    chunk = 1_000_000
    ds = tmp / "bench"
    ds.mkdir()
    (ds / "rig.yaml").write_text(yaml.safe_dump(_synth.RIG, sort_keys=False))
    est = _synth.estimator(dt=1e-4)
    (tmp / "sensing.json").write_text(json.dumps(est.to_dict()))
    log = tmp / "long.parquet"
    t0 = time.perf_counter()
    writer = None
    for start in range(0, n_total, chunk):
        df = _synth.raw_log(min(chunk, n_total - start), start=start)
        tab = pa.Table.from_pandas(df, preserve_index=False)
        if writer is None:
            writer = pq.ParquetWriter(str(log), tab.schema, compression="zstd")
        writer.write_table(tab)
    writer.close()
    t_gen = time.perf_counter() - t0
    out = tmp / "long_est.parquet"
    code = ("import resource, subprocess, sys, time; t0 = time.perf_counter(); "
            "rc = subprocess.run(sys.argv[1:]).returncode; dt = time.perf_counter() - t0; "
            "print(rc, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, dt)")
    cmd = [sys.executable, "-m", "selfsense", "estimate", "--model", str(tmp / "sensing.json"), "--dataset", str(ds),
           "--log", str(log), "--out", str(out), "--chunk", str(chunk)]
    proc = subprocess.run([sys.executable, "-c", code, *cmd], capture_output=True, text=True)
    rc, maxrss_kb, secs = proc.stdout.split()
    n_out = pq.ParquetFile(str(out)).metadata.num_rows if out.exists() else 0
    # spot check: the first 200,000 output samples equal the batch pipeline on the same samples
    head = _synth.raw_log(200_000)
    b = _synth.batch_estimate(est, head)
    got = pq.ParquetFile(str(out)).read_row_group(0).to_pandas().iloc[:200_000] if n_out else None
    err = (float(np.max(np.abs(got["dx_hat"].to_numpy() - b["dx_hat"].to_numpy())) / np.ptp(b["dx_hat"].to_numpy()))
           if got is not None else float("nan"))
    rss_gb = int(maxrss_kb) * 1024 / 1e9
    return {"n": n_total, "rc": int(rc), "rss_gb": rss_gb, "seconds": float(secs), "t_gen": t_gen,
            "n_out": n_out, "log_mb": log.stat().st_size / 1e6, "err_head": err, "stderr": proc.stderr[-1500:],
            "ok": int(rc) == 0 and rss_gb < 2.0 and n_out == n_total}


# ------------------------------------------------------------------------------------------------ (g) scaling
def linfit(n, t):
    n, t = np.asarray(n, float), np.asarray(t, float)
    A = np.column_stack([np.ones_like(n), n])
    (a, b), *_ = np.linalg.lstsq(A, t, rcond=None)
    pred = a + b * n
    r2 = 1 - np.sum((t - pred) ** 2) / np.sum((t - t.mean()) ** 2)
    return a, b, r2, float(np.max(np.abs(t - pred) / t))


def bench_scaling(quick):
    from selfsense.sensing.streaming import SelfSensingStream

    est = _synth.estimator(dt=1e-4)
    lengths = [10_000, 30_000, 100_000, 300_000] + ([] if quick else [1_000_000])
    if quick:
        lengths.append(1_000_000)
    raw_all = _synth.raw_log(max(lengths))
    s = SelfSensingStream(est)
    rows_len = []
    for n in lengths:
        raw = raw_all.iloc[:n]
        u, v, r, t = (raw[k].to_numpy() for k in ("u_cmd", "v_shunt", "relay", "t"))

        def run():
            s.reset()
            s.process(u, v, r, t=t)

        ts = best_time(run, repeat=5 if n < 300_000 else 3)
        tb = best_time(lambda: _synth.batch_estimate(est, raw), repeat=3 if n < 300_000 else 1)
        rows_len.append((n, ts, tb))
    counts = [1, 2, 4, 8] + ([] if quick else [16])
    n_each = 100_000
    trials = [_synth.raw_log(n_each, seed=j) for j in range(max(counts))]
    rows_cnt = []
    for m in counts:
        def run_m():
            for raw in trials[:m]:
                s.reset()
                s.process(raw["u_cmd"].to_numpy(), raw["v_shunt"].to_numpy(), raw["relay"].to_numpy(),
                          t=raw["t"].to_numpy())

        rows_cnt.append((m, best_time(run_m, repeat=3)))
    fit_len = linfit([r[0] for r in rows_len], [r[1] for r in rows_len])
    fit_len_b = linfit([r[0] for r in rows_len], [r[2] for r in rows_len])
    fit_cnt = linfit([r[0] for r in rows_cnt], [r[1] for r in rows_cnt])
    return {"len": rows_len, "cnt": rows_cnt, "n_each": n_each, "fit_len": fit_len, "fit_len_b": fit_len_b,
            "fit_cnt": fit_cnt}


# ------------------------------------------------------------------------------------------------ report
def machine():
    import numba

    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    uname = subprocess.run(["uname", "-a"], capture_output=True, text=True).stdout.strip()
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else ["?"]
    return {"load": " ".join(load), "uname": uname, "cpu": cpu, "n_cpus": os.cpu_count(), "python": platform.python_version(),
            "numba": numba.__version__, "numpy": np.__version__,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}


def render(res, quick, argv, total):
    M = res["machine"]
    L = ["# selfsense benchmark results", "",
         f"Command: `python benchmarks/run.py {' '.join(argv)}` ({'quick' if quick else 'full'} mode, "
         f"{total:.0f} s in total).", "",
         f"- Machine: `{M['uname']}`", f"- CPU: {M['cpu']} ({M['n_cpus']} logical CPUs visible)",
         f"- Python {M['python']}, numba {M['numba']}, numpy {M['numpy']}; date {M['date']}",
         f"- Load average (1/5/15 min) at the start: {M['load']}; at the end: {res.get('load_end', '?')}. The machine is "
         "shared with other work, so rates vary between runs (contention for the 2 CPUs).",
         "- One core: NUMBA_NUM_THREADS = OMP/MKL/OpenBLAS threads = 1, process pinned to one CPU "
         "(the Snakemake run of (d) gets 2 cores). Times are the best of several repeats unless noted.", ""]
    a = res["a"]
    L += ["## Summary", "", "| # | figure | measured | NumPy reference | ratio | target | status |",
          "|---|---|---|---|---|---|---|"]
    L.append(f"| a | modified PI operator, ModifiedPI.apply (hysteresis kernel) | {fmt_rate(a['rate_pkg'])} samples/s | "
             f"{fmt_rate(a['rate_ref'])} samples/s | {a['ratio_pkg']:.0f}x | >= 1e7 /s and >= 100x | "
             f"{verdict(a['ok'])} |")
    b = res["b"]
    L.append(f"| b | stream per-sample `step()` (thesis modified PI) | {b['step_us']:.2f} us/sample | "
             f"{b['ref_step_us']:.1f} us/sample | {b['ref_step_us'] / b['step_us']:.1f}x | <= 10 us | "
             f"{verdict(b['step_us'] <= 10)} |")
    dft = next((k for k in b.get("kinds", []) if k["label"].startswith("default") and "us_100" in k), None)
    if dft is not None:
        L.append(f"| b | stream, default model on tweezer_sim ({dft['model']}), blocks of 100 samples | "
                 f"{dft['us_100']:.2f} us/sample (whole trial {dft['us_whole']:.2f}, step {dft['us_step']:.1f}) | "
                 f"| | <= 1 us | {verdict(dft['us_100'] <= 1.0)} |")
        if "c_ns" in dft:
            L.append(f"| b | generated C (`selfsense export-c`, cc -O2), default model on tweezer_sim | "
                     f"{dft['c_ns'] / 1e3:.3f} us/sample (max err {dft['c_err']:.0e} of range) | | | <= 0.2 us | "
                     f"{verdict(dft['c_ns'] <= 200)} |")
    L.append(f"| b | stream block `process()` | {fmt_rate(b['rate_block'])} samples/s | "
             f"{fmt_rate(b['rate_batch'])} samples/s (batch pipeline) | {b['rate_block'] / b['rate_batch']:.1f}x | "
             f">= 1e6 /s | {verdict(b['rate_block'] >= 1e6)} |")
    L.append(f"| b | stream == batch | max err {max(b['err_dx'], b['err_f']):.1e} of range | | | <= 1e-12 | "
             f"{verdict(max(b['err_dx'], b['err_f']) <= 1e-12)} |")
    c = res["c"]
    L.append(f"| c | QP calibration, 60,000 samples (fit_modified_pi) | {c['t_total']:.2f} s (Gram {c['t_gram']:.2f} s"
             f" + solve {c['t_solve']:.2f} s) | Gram by plain-Python reference operators ~{c['ref_gram_est']:.0f} s "
             f"(extrapolated) | {c['ref_gram_est'] / max(c['t_gram'], 1e-9):.0f}x (Gram) | <= 1 s | "
             f"{verdict(c['ok'])} |")
    d = res["d"]
    if d.get("available"):
        L.append(f"| d | pipeline on tweezer_sim, cold, --cores 2, numba cache warm | {d['wall_s']:.1f} s wall "
                 f"({d['snakemake_s']:.1f} s by Snakemake's clock) | | | <= 15 s wall | {verdict(d['ok'])} |")
    else:
        L.append(f"| d | pipeline on tweezer_sim | not run: {d['why']} | | | <= 15 s wall | not measured |")
    e = res["e"]
    if e.get("available"):
        L.append(f"| e | gap diagnostic, blind cases (stage-wise) | {e['rate']:.2f} cases/s/core | | | | measured |")
    else:
        L.append(f"| e | gap diagnostic, blind cases | not available: {e['why']} | | | | not measured |")
    f = res["f"]
    L.append(f"| f | chunked CLI, {f['n'] / 1e6:.1f} M samples (10 kHz) | peak RSS {f['rss_gb']:.2f} GB, "
             f"{f['seconds']:.1f} s ({f['n'] / f['seconds'] / 1e6:.2f} M samples/s end to end) | | | < 2 GB"
             f"{' (36 M samples)' if f['n'] >= 36_000_000 else ' (quick: 3.6 M samples; full mode runs 36 M)'} | "
             f"{verdict(f['ok'])} |")
    g = res["g"]
    L.append(f"| g | scaling, block stream vs length | R^2 = {g['fit_len'][2]:.5f}, "
             f"{1 / g['fit_len'][1]:.3g} samples/s slope | | | linear | "
             f"{verdict(g['fit_len'][2] > 0.99)} |")
    L += ["", "## Details", "", "### (a) Modified PI operator with creep",
          f"15 play, 15 superposition (one identity, 7 positive, 7 negative thresholds), 15 x 4 creep operators; "
          f"input: {a['N']:,} samples of a modulated raised cosine; NumPy reference on the first {a['Nref']:,} "
          f"samples (per-sample rates compared). Max |difference| / range: NumPy reference vs kernel "
          f"{a['err_ref']:.1e}.", "",
          "### (b) Streaming estimator",
          f"Synthetic 10 kHz raw log (1 s relay segment, then a modulated drive), {b['N']:,} samples; estimator with "
          f"GaugedH(ModifiedPI) as above. Block mode: one `process()` call over the whole log. Per-sample: "
          f"{b['Nstep']:,} `step(u, v, relay, t)` calls from a Python loop: {b['step_us']:.2f} us each (a block of "
          f"one sample through the three links: front kernel, H stream, back kernel). The NumPy per-sample reference (same chain, operator sums vectorised with NumPy) ran "
          f"{b['Nref']:,} samples: {b['ref_step_us']:.1f} us/sample; its max deviation from the stream "
          f"{b['err_ref']:.1e} of range. Stream vs batch pipeline (io.to_si -> signals.prepare_trial -> "
          f"estimator.estimate): dx {b['err_dx']:.1e}, f {b['err_f']:.1e} of range; step() vs process(): "
          f"{b['step_eq']:.1e}.", "",
          "Per model kind (fitted on data/raw/sample with `drift: off`; streamed over one validation trial) and the "
          "pipeline's default model on data/raw/tweezer_sim (config.yaml), us per sample by block size, and the "
          "stream's max deviation from the batch estimate (of range, dx and f):", "",
          "| model | dataset, trial | samples | Python step (block of 1), us | Python blocks of 100, us | "
          "Python whole trial, us | stream vs batch | generated C (cc -O2), us | C vs batch |",
          "|---|---|---|---|---|---|---|---|---|"]
    for k in b.get("kinds", []):
        cc = (f"{k['c_ns'] / 1e3:.3f} | {k['c_err']:.1e}" if "c_ns" in k else "no C compiler | ")
        if "us_100" in k:
            L.append(f"| {k['label']}: {k['model']} | {k['dataset']}, {k['trial']} | {k['n']:,} | {k['us_step']:.1f} | "
                     f"{k['us_100']:.2f} | {k['us_whole']:.2f} | {k['err']:.1e} | {cc} |")
        else:
            L.append(f"| {k['label']} | {k['dataset']}, {k['trial']} | | {k['note']} | | | | | |")
    L += ["",
          "### (c) QP calibration",
          f"fit_modified_pi on {c['N']:,} samples (15 play, 15 superposition, 15 x 4 creep, Clarabel): total "
          f"{c['t_total']:.3f} s, status {c['status']}, fit rms {c['rms_pct']:.3f} % of range. Split (same steps "
          f"re-run separately): regressors + Gram matrix {c['t_gram']:.3f} s, QP solve {c['t_solve']:.3f} s "
          f"(incl. cvxpy problem construction). The reference estimate times the plain-Python operator module "
          f"(selfsense.hysteresis.reference) on {c['n_small']:,} samples, scaled linearly to {c['N']:,}.", ""]
    L += ["### (d) Pipeline"]
    if d.get("available"):
        sys.path.insert(0, str(HERE))
        import pipeline_speed

        L += ["`python benchmarks/pipeline_speed.py` in a fresh temporary working directory (every result computed "
              "again):", "", pipeline_speed.markdown({"dataset": "tweezer_sim", "cores": 2, "numba_cold": False,
                                                      "snakemake_s": d["snakemake_s"], "wall_s": d["wall_s"],
                                                      "load": d["load"], "rules": d["rules"],
                                                      "slurm_probe_s": d.get("slurm_probe_s"),
                                                      "probe_skipped": d.get("probe_skipped")}),
              "Table 3 of that run (`results/tweezer_sim/tables/table3.md`):", "", d["table3_md"].strip(), "",
              "H(q) identifications and calibration modes of that run (`results/tweezer_sim/tables/modes.md`):", "",
              d["modes_md"].strip()]
    else:
        L.append(f"Not run: {d['why']}.")
    L += ["", "### (e) Gap diagnostic", (f"{e['entry']}: {e['n']} cases in {e['seconds']:.2f} s = "
                                          f"{e['rate']:.2f} cases/s/core." if e.get("available")
                                         else f"Not available: {e['why']}."), ""]
    L += ["### (f) Memory",
          f"Synthetic log of {f['n']:,} samples (t, u_cmd, v_shunt, relay; {f['log_mb']:.0f} MB zstd Parquet, "
          f"generated chunk-wise in {f['t_gen']:.1f} s). `python -m selfsense estimate --chunk 1000000` in a child "
          f"process: return code {f['rc']}, {f['n_out']:,} rows written, {f['seconds']:.1f} s, peak RSS "
          f"(getrusage(RUSAGE_CHILDREN).ru_maxrss) {f['rss_gb']:.3f} GB. First 200,000 output samples vs the batch "
          f"pipeline: max err {f['err_head']:.1e} of range.", ""]
    L += ["### (g) Scaling", "", "Trial length (block stream and batch pipeline on the same samples):", "",
          "| samples | stream [s] | stream [samples/s] | batch pipeline [s] |", "|---|---|---|---|"]
    for n, ts, tb in g["len"]:
        L.append(f"| {n:,} | {ts:.4f} | {fmt_rate(n / ts)} | {tb:.4f} |")
    a0, b0, r2, mr = g["fit_len"]
    a1, b1, r21, mr1 = g["fit_len_b"]
    L += ["", f"Linear fit stream: t = {a0 * 1e3:.3f} ms + N x {b0 * 1e9:.1f} ns, R^2 = {r2:.5f}, max relative "
              f"residual {mr:.2f}. Batch: t = {a1 * 1e3:.2f} ms + N x {b1 * 1e9:.1f} ns, R^2 = {r21:.5f}.", "",
          f"Number of trials ({g['n_each']:,} samples each, stream reset between trials):", "",
          "| trials | time [s] |", "|---|---|"]
    for m, tm in g["cnt"]:
        L.append(f"| {m} | {tm:.4f} |")
    a2, b2, r22, mr2 = g["fit_cnt"]
    L += ["", f"Linear fit: t = {a2 * 1e3:.3f} ms + trials x {b2 * 1e3:.2f} ms, R^2 = {r22:.5f}, max relative "
              f"residual {mr2:.2f}.", ""]
    return "\n".join(L)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes (< 2 min)")
    ap.add_argument("--out", default=str(HERE / "RESULTS.md"))
    ap.add_argument("--only", default="abcdefg", help="subset of the sections, e.g. 'ab'")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    res = {"machine": machine()}
    tmp = Path(tempfile.mkdtemp(prefix="selfsense_bench_"))
    try:
        steps = [("a", bench_operator), ("b", bench_stream), ("c", bench_qp), ("g", bench_scaling)]
        pin_one_core()
        for key, fn in steps:
            if key in args.only:
                t0 = time.perf_counter()
                res[key] = fn(args.quick)
                print(f"[{key}] {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        _unpin()
        for key, fn in (("e", bench_gap), ("f", lambda q: bench_memory(q, tmp)), ("d", bench_pipeline)):
            if key in args.only:
                if key == "e":
                    pin_one_core()
                t0 = time.perf_counter()
                res[key] = fn(args.quick)
                _unpin()
                print(f"[{key}] {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    total = time.perf_counter() - t_start
    if Path("/proc/loadavg").exists():
        res["load_end"] = " ".join(Path("/proc/loadavg").read_text().split()[:3])
    if set("abcdefg") <= set(args.only):
        text = render(res, args.quick, argv, total)
        Path(args.out).write_text(text + "\n")
        # the machine-readable figures beside the table: benchmarks/figures.py builds the README's and the docs'
        # figure tables from them (one source for every number)
        res["command"] = "python benchmarks/run.py " + " ".join(argv)
        res["quick"] = bool(args.quick)
        # without the captured stderr of the child processes (temporary paths of this run, not figures)
        res_json = {k: ({kk: vv for kk, vv in v.items() if kk != "stderr"} if isinstance(v, dict) else v)
                    for k, v in res.items()}
        Path(args.out).with_suffix(".json").write_text(json.dumps(res_json, indent=1, sort_keys=True, default=str)
                                                       + "\n")
        print(text)
    else:
        print(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
