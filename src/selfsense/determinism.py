"""The determinism contract (docs/reproducibility.md): what "the same result" means for selfsense.

* Same machine, same locked environment, same input and config: outputs are **bit-identical** (tested by two
  runs of the real Snakefile, ``tests/pipeline/test_smoke_pipeline.py``).
* Another machine (another CPU's SIMD paths in NumPy's ``exp``/``log``/``sin``, another BLAS kernel, another
  libm): floating-point results may differ in the last bits, and a last-bit difference before the ADC model of
  the simulator (``000_18d138f03f1777c3.txt`` eqs. 56-57, the quantised shunt voltage) can move a sample to the
  adjacent ADC code. Committed artefacts made on another machine are therefore compared with the tolerances
  below, never bit for bit.

Every tolerance here was set from a measured cross-SIMD difference: regenerating ``data/raw/sample`` with
AVX-512 (this project's machine) against the committed files (made without it; the same files are reproduced
bit for bit with ``NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL"``) gives at most 9 of 6,000 DAQ samples one ADC
code apart, truth signals within 1.0e-7 of their range and effect columns within 6.7e-4 of their reference's
range.

* Thread counts: every pipeline job, Snakemake script and ``selfsense`` command runs its linear algebra on one BLAS
  thread (:func:`single_thread_blas`), whatever ``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` say: OpenBLAS
  reductions round differently on one and on two threads, and the iterative H(q) fits carry that into the model.
"""
from __future__ import annotations

import json
import math
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

#: DAQ logs (the pipeline's input): a value may sit at most this many quantisation steps (ADC codes) away ...
DAQ_MAX_CODE_STEPS = 1
#: ... and at most this fraction of a column's samples may differ at all (measured 0.15 %)
DAQ_MAX_FRACTION = 5e-3
#: truth signals: |a - b| <= TRUTH_RTOL * max|b| of the column (measured 1.0e-7)
TRUTH_RTOL = 1e-6
#: truth effect columns (``effect__<name>`` = difference of two simulations, so they carry the rounding of both):
#: |a - b| <= EFFECT_RTOL * max|reference| (``dx_ref`` for ``effect__<name>``, ``q`` for ``effect__<name>__q``;
#: measured 6.7e-4)
EFFECT_RTOL = 5e-3
#: JSON numbers (manifests, campaign records): relative tolerance; integers, strings, booleans and keys exact
JSON_RTOL = 1e-9
#: stage residuals (``rms_nominal``) of a committed campaign case diagnosed again on another machine: relative. The
#: case's DAQ log is simulated again there, and may sit one ADC code away on a few samples (DAQ_MAX_CODE_STEPS,
#: DAQ_MAX_FRACTION), which moves the residual of a stage fitted on that trial by far more than rounding does
#: (measured on an AVX2 machine against records made with AVX-512: 4.9e-6 and 2.3e-6 in the two stages fitted on
#: one case's blocked-tip trials, 5e-11 or less in every other stage of the four cases)
STAGE_RMS_RTOL = 1e-4

#: environment variables a BLAS / OpenMP library reads for its thread count when it is loaded
THREAD_ENV_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
                   "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")
_PIN_LOCK = threading.Lock()


def single_thread_blas() -> None:
    """One thread for every BLAS / OpenMP library of this process, loaded now or later, from any Python thread.

    Results depend on the BLAS thread count (measured on the bundled ``sample`` dataset: the calibrated
    ``model/hysteresis.json`` differs in the last bits between ``OPENBLAS_NUM_THREADS=1`` and ``2``, and the
    non-convex Duhem fit amplifies that to 1e-12 relative in its cross-validation scores). A process may hold
    several OpenBLAS copies (NumPy's, SciPy's, SCS's), loaded at different times, so both are needed:

    * the environment variables :data:`THREAD_ENV_VARS` set to 1, read by every library loaded from now on;
    * ``threadpoolctl`` limits for the libraries already loaded. ``threadpoolctl`` (>= 3.6) applies an OpenBLAS
      limit only from the one Python thread that first set one; a limit asked from another thread while that one
      lives is silently ignored. Where that leaves a library above one thread, its own setter is called directly.

    Idempotent and cheap; called by :class:`selfsense.stages.logged` (every ``run:`` and ``script:`` job) and by
    the ``selfsense`` command.
    """
    with _PIN_LOCK:
        for var in THREAD_ENV_VARS:
            os.environ[var] = "1"
        from threadpoolctl import ThreadpoolController

        ctl = ThreadpoolController()
        ctl.limit(limits=1)
        for lib in ctl.lib_controllers:
            if lib.get_num_threads() not in (None, 1):
                setter = getattr(lib, "_real_set_num_threads", lib.set_num_threads)
                setter(1)


def compare_tree(got: Any, ref: Any, rtol: float = JSON_RTOL, atol: float = 0.0, path: str = "") -> list[str]:
    """Differences between two JSON-like trees: floats within ``rtol``/``atol`` (``math.isclose``), everything
    else (keys, strings, integers, booleans, list lengths) exact. Returns one message per difference."""
    where = path or "<root>"
    if isinstance(got, bool) or isinstance(ref, bool) or got is None or ref is None:
        return [] if got == ref and type(got) is type(ref) else [f"{where}: {got!r} != {ref!r}"]
    if isinstance(got, (int, float)) and isinstance(ref, (int, float)):
        if isinstance(got, int) and isinstance(ref, int):
            return [] if got == ref else [f"{where}: {got} != {ref}"]
        if math.isnan(got) and math.isnan(ref):
            return []
        ok = math.isclose(got, ref, rel_tol=rtol, abs_tol=atol)
        return [] if ok else [f"{where}: {got!r} != {ref!r} (rtol {rtol:g}, atol {atol:g})"]
    if isinstance(got, dict) and isinstance(ref, dict):
        if set(got) != set(ref):
            return [f"{where}: keys {sorted(set(got) ^ set(ref))} differ"]
        return [m for k in ref for m in compare_tree(got[k], ref[k], rtol, atol, f"{path}.{k}" if path else str(k))]
    if isinstance(got, (list, tuple)) and isinstance(ref, (list, tuple)):
        if len(got) != len(ref):
            return [f"{where}: length {len(got)} != {len(ref)}"]
        return [m for i, (a, b) in enumerate(zip(got, ref)) for m in compare_tree(a, b, rtol, atol, f"{path}[{i}]")]
    return [] if got == ref else [f"{where}: {got!r} != {ref!r}"]


def _same_shape(got: pd.DataFrame, ref: pd.DataFrame, name: str) -> list[str]:
    if list(got.columns) != list(ref.columns):
        return [f"{name}: columns {list(got.columns)} != {list(ref.columns)}"]
    if len(got) != len(ref):
        return [f"{name}: {len(got)} rows != {len(ref)}"]
    return []


def _nan_or_kind(a: np.ndarray, b: np.ndarray, label: str) -> list[str]:
    if a.dtype.kind != b.dtype.kind:
        return [f"{label}: dtype {a.dtype} != {b.dtype}"]
    if a.dtype.kind != "f":
        return [] if np.array_equal(a, b) else [f"{label}: non-float values differ"]
    if not np.array_equal(np.isnan(a), np.isnan(b)):
        return [f"{label}: NaN pattern differs"]
    return []


def compare_daq_log(got: pd.DataFrame, ref: pd.DataFrame, name: str = "log") -> list[str]:
    """A DAQ log against a reference: same columns, rows and NaNs; every float column's values identical or
    at most ``DAQ_MAX_CODE_STEPS`` quantisation steps apart (the step = the smallest spacing of the reference's
    distinct values, i.e. one ADC code for a quantised channel) on at most ``DAQ_MAX_FRACTION`` of the samples."""
    out = _same_shape(got, ref, name)
    if out:
        return out
    for c in ref.columns:
        a, b = got[c].to_numpy(), ref[c].to_numpy()
        bad = _nan_or_kind(a, b, f"{name}.{c}")
        if bad or a.dtype.kind != "f":
            out += bad
            continue
        d = np.abs(a - b)[~np.isnan(b)]
        n_diff = int(np.count_nonzero(d))
        if n_diff == 0:
            continue
        u = np.unique(b[~np.isnan(b)])
        step = float(np.diff(u).min()) if u.size > 1 else 0.0
        if d.max() > DAQ_MAX_CODE_STEPS * step * (1 + 1e-9):
            out.append(f"{name}.{c}: max difference {d.max():.3g} exceeds {DAQ_MAX_CODE_STEPS} step(s) of {step:.3g}")
        if n_diff > DAQ_MAX_FRACTION * d.size:
            out.append(f"{name}.{c}: {n_diff} of {d.size} samples differ (allowed {DAQ_MAX_FRACTION:.1%})")
    return out


def compare_truth(got: pd.DataFrame, ref: pd.DataFrame, name: str = "truth") -> list[str]:
    """A simulator truth table against a reference (``TRUTH_RTOL`` of each signal's range; ``EFFECT_RTOL`` of
    the reference quantity's range for the ``effect__*`` columns)."""
    out = _same_shape(got, ref, name)
    if out:
        return out
    for c in ref.columns:
        a, b = got[c].to_numpy(), ref[c].to_numpy()
        bad = _nan_or_kind(a, b, f"{name}.{c}")
        if bad or a.dtype.kind != "f":
            out += bad
            continue
        if c.startswith("effect__"):
            base = "q" if c.endswith("__q") else "dx_ref"
            scale, rtol = float(np.nanmax(np.abs(ref[base].to_numpy()))), EFFECT_RTOL
        else:
            scale, rtol = float(np.nanmax(np.abs(b), initial=0.0)), TRUTH_RTOL
        d = np.nanmax(np.abs(a - b), initial=0.0)
        if d > rtol * scale:
            out.append(f"{name}.{c}: max difference {d:.3g} exceeds {rtol:g} x {scale:.3g}")
    return out


def compare_dataset_dirs(got_dir: Path, ref_dir: Path, truth: bool = False) -> list[str]:
    """A regenerated dataset folder (or its ``.truth`` folder with ``truth=True``) against a committed one:
    same file names; text files (YAML, CSV) byte-identical; ``*.json`` with :func:`compare_tree`; Parquet
    files with :func:`compare_daq_log` (dataset) or :func:`compare_truth` (truth folder)."""
    got_dir, ref_dir = Path(got_dir), Path(ref_dir)
    names = sorted(p.name for p in ref_dir.iterdir())
    if sorted(p.name for p in got_dir.iterdir()) != names:
        return [f"{ref_dir.name}: files {sorted(p.name for p in got_dir.iterdir())} != {names}"]
    out: list[str] = []
    for n in names:
        g, r = got_dir / n, ref_dir / n
        if n.endswith(".parquet"):
            cmp = compare_truth if truth else compare_daq_log
            out += cmp(pd.read_parquet(g), pd.read_parquet(r), f"{ref_dir.name}/{n}")
        elif n.endswith(".json"):
            out += compare_tree(json.loads(g.read_text()), json.loads(r.read_text()), path=f"{ref_dir.name}/{n}")
        elif g.read_bytes() != r.read_bytes():
            out.append(f"{ref_dir.name}/{n}: content differs")
    return out
