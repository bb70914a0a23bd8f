"""Choice of the H(q) model family and its regularisation by blocked cross-validation on calibration trials only.

Each calibration trial is cut into ``n_blocks`` contiguous blocks; fold k leaves block k of *every* trial out. The
operators always run over the whole record from the relaxed state (their state depends on the input history, which
is measured), only the rows that enter the least-squares fit are restricted: this is the blocked CV of
time-series models (no leakage of the held-out *output*). The score is the RMS of the held-out residual [V].

A model fitted by a non-convex search (``convex = False``: ``duhem``) is selected only if it beats the best convex
candidate by more than one standard error of the paired fold differences.

Every selection table contains the straight line (``linear``) and the signed-weight PI baseline; a selected model
that does not beat the straight line out of sample raises :class:`DegenerateFitError`, one that does not beat the
PI baseline is reported with a warning (``warnings`` of the result), naming the trials.
"""
from __future__ import annotations

import contextlib
import contextvars
import logging
from dataclasses import dataclass, field

import numpy as np

from selfsense.parallel import with_one_blas_thread

from . import (DegenerateFitError, LinearParamH, fit_rows, fit_stride, make_model, qr_reduce, ridge_lstsq,
               searches_holds, stacked_extra, stacked_rows, without_hold_search)

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_CANDIDATES", "SelectionResult", "select_h_model", "blocked_folds"]

#: (kind, hyper-parameters): the search space of ``h_model: auto``
DEFAULT_CANDIDATES: tuple = (
    ("linear", {}),
    ("pi", {"n_play": 20, "ridge": 1e-6}),
    ("pi", {"n_play": 20, "ridge": 1e-3}),
    ("preisach", {"n_grid": 12, "n_play": 0, "ridge": 1e-4}),
    ("preisach", {"n_grid": 12, "n_play": 10, "ridge": 1e-4}),
    ("preisach", {"n_grid": 16, "n_play": 10, "ridge": 1e-3}),
    ("preisach", {"n_grid": 24, "n_play": 0, "ridge": 1e-6}),
    ("preisach", {"n_grid": 12, "n_play": 10, "ridge": 1e-4, "n_rev": 48}),
    ("preisach", {"n_grid": 24, "n_play": 0, "ridge": 1e-6, "n_rev": 48}),
    ("ri", {"ridge": 1e-8}),
    ("modified_pi", {"n_play": 12, "n_sup": 6, "n_creep": 3}),
    ("duhem", {"degree": 3, "ridge": 1e-7}),
    ("duhem", {"degree": 3, "ridge": 1e-7, "creep": False}),
    ("duhem", {"degree": 3, "ridge": 1e-7, "hold_nfev": 8}),
)


#: default fold layout of the selection (``blocked_folds(..., rotate=...)``)
ROTATE_FOLDS = True

#: threads that :func:`select_h_model` may use for its candidates (:func:`cv_workers`); 1 = one after the other
_CV_WORKERS: contextvars.ContextVar[int] = contextvars.ContextVar("selfsense_cv_workers", default=1)


@contextlib.contextmanager
def cv_workers(n: int):
    """Let :func:`select_h_model` cross-validate up to ``n`` candidates at a time inside this block (of this thread
    or task only: a context variable): in forked processes where the job runs a process of its own, else in threads
    (:func:`selfsense.parallel.fork_map`). Each candidate's blocked CV is independent of the others and computed
    by the same code on the same inputs in whichever worker, so the selection table -- and the model
    -- are bit-identical for every ``n`` (the BLAS libraries stay pinned to one thread each,
    :func:`selfsense.determinism.single_thread_blas`). The pipeline's ``calibrate_hysteresis`` job sets it to its
    ``threads`` (nothing else runs beside it)."""
    token = _CV_WORKERS.set(max(1, int(n)))
    try:
        yield
    finally:
        _CV_WORKERS.reset(token)


def cv_worker_count() -> int:
    """The workers :func:`cv_workers` allows here (1 outside such a block): also those of the calibration's other
    independent searches (the leakage search of :class:`~selfsense.sensing.estimator.SelfSensingEstimator`)."""
    return _CV_WORKERS.get()


#: the serial selection keeps the least-squares rows of its best candidate so far for the final fit (no second build)
#: if they take at most this many bytes (within the fit-row cap MAX_FIT_ROWS they could take several hundred MB;
#: 128 MB keeps the jobs inside their memory budgets, benchmarks/MEMORY.md)
KEEP_ROWS_BYTES = 128 << 20


def _cost_rank(kind: str, params=None) -> tuple:
    """Order in which parallel workers take the units of work (:func:`select_h_model`), the longest first
    (longest-processing-time order), so that no worker is left with a long one at the end: the finest Preisach grids
    (their cost grows with the grid's cells, n_grid^2), the QP of the modified PI (its worker also imports the QP
    solver, about as long as its fit), the folds of the non-convex searches (each fold a unit of its own), the other
    Preisach grids from the finest, then the rest in the given order. Measured blocked CVs on tweezer_sim, one
    worker: preisach n_grid 24 1.5 s, modified PI 0.9 s (+ 1.3 s solver import), duhem 2.7 and 3.1 s in five folds,
    n_grid 16 0.5 s, n_grid 12 0.45 and 0.3 s, the others 0.03-0.2 s. Only the order of work changes, never the
    table's."""
    if kind == "preisach":
        cells = int((params or {}).get("n_grid", 0)) ** 2
        return (0, -cells) if cells >= 400 else (3, -cells)
    if kind == "modified_pi":
        return (1, 0)
    if kind == "duhem":
        return (2, 0)
    return (4, 0)


@dataclass
class SelectionResult:
    model: object                      # the selected model, refitted on all calibration rows
    extra_coef: np.ndarray             # coefficients of the extra (joint) columns
    table: list = field(default_factory=list)   # one dict per candidate: kind, label, fold RMS, mean, selected
    warnings: list = field(default_factory=list)
    envelope: list | None = None       # the envelope checks (:func:`envelope_excursion`) of the refitted candidates


def blocked_folds(lengths, n_blocks: int, rotate: bool = False) -> list[np.ndarray]:
    """Boolean held-out masks over the stacked rows: fold k holds out the k-th contiguous block of every segment, or
    with ``rotate`` the ((k + i) mod n_blocks)-th block of segment i: every fold then leaves a different stretch of
    each trial out, so that a part of the input history held out in one trial (the first rise from the relaxed state,
    say) is visited by the training rows of another -- as when a new trial is predicted from the calibration
    trials."""
    n = int(sum(lengths))
    folds = []
    for k in range(n_blocks):
        m = np.zeros(n, bool)
        off = 0
        for i, L in enumerate(lengths):
            edges = np.linspace(0, L, n_blocks + 1).astype(int)
            b = (k + i) % n_blocks if rotate else k
            m[off + edges[b]:off + edges[b + 1]] = True
            off += L
        folds.append(m)
    return folds


def _stack_extra(extras, lengths):
    if extras is None:
        return None
    return np.vstack([np.asarray(e, float).reshape(L, -1) for e, L in zip(extras, lengths)])


def split_rows(a, lengths) -> list:
    """Cut the stacked rows of ``a`` back into the segments of ``lengths`` samples."""
    out, off = [], 0
    for L in lengths:
        out.append(a[off:off + L])
        off += L
    return out


def stacked_design(model: LinearParamH, qs, ys, dt, extras, stride: int):
    """``(X, y, penalised)``: ``[design | extra columns]`` and the targets of every ``stride``-th sample of every
    segment, stacked (the operators run over every sample); ``extras`` is one array per segment, or None."""
    model.prepare(qs, dt)
    y = np.concatenate([np.asarray(v, float)[::stride] for v in ys])
    E = stacked_extra(extras, qs, stride)
    X, pen = stacked_rows(model, qs, dt, stride, E)
    return X, y, pen


def _hold_folds(hold_id: np.ndarray, n_folds: int) -> np.ndarray:
    """Held-out masks of the hold rows: hold h is held out in fold h mod n_folds (a hold is never split)."""
    return np.stack([hold_id % n_folds == f for f in range(n_folds)]) if n_folds else np.zeros((0, 0), bool)


def _combined_rms(r_cal: np.ndarray, r_hold: np.ndarray, w2: float = 1.0) -> float:
    """RMS of the held-out calibration and (weighted) hold rows together, each hold row counting as the ``w2``
    hold samples it stands for."""
    n = r_cal.size + (r_hold.size * w2 if r_hold.size else 0.0)
    ss = float(np.sum(r_cal ** 2)) + float(np.sum(r_hold ** 2))
    return float(np.sqrt(ss / n)) if n else float("nan")


def _cv_linear(model: LinearParamH, qs, ys, dt, extras, folds, thin, holds=None, rows_out: list | None = None,
               bound: float | None = None):
    """Fold RMS of ``model``; ``extras`` per segment, ``folds`` over the stacked rows of every ``fit_stride``-th
    sample; ``holds`` (:class:`~selfsense.hysteresis.models.holds.HoldSet`): the hold rows of every trial join the
    fit, each hold held out in one fold and scored there. ``rows_out``: a list that receives the stacked rows
    (:class:`~selfsense.hysteresis.models.FitRows`, those of the model's final fit on all rows). ``bound``: no fold
    error (an empty list) once the held-out blocks factored so far put the mean above it: a fold's held-out residual
    is at least its block's own least-squares residual, ``|R[p, p]|`` of the block's factor, whatever the fit of the
    training blocks (a relative margin of 1e-3 and 1e-9 of the factor's norm against rounding)."""
    model.prepare(qs, dt)
    # the stacked calibration rows ([design | extras]) with the hold rows below them, in one matrix: the rows of
    # the model's fit on all of them (models.fit_rows)
    rows = fit_rows(model, qs, ys, dt, extras, holds)
    if rows_out is not None:
        rows_out.append(rows)
    X, y, pen = rows.X, rows.y, rows.penalised
    n_cal = len(y) - rows.n_hold
    keep = np.ones(len(y), bool)
    keep[:n_cal] = False
    keep[:n_cal:thin] = True
    w2 = 1.0
    if holds:
        from .holds import _stride_and_weight

        w2 = _stride_and_weight(holds, n_cal)[1] ** 2
        hf = _hold_folds(rows.hold_id, len(folds))
        folds = [np.concatenate([np.asarray(f, bool), h]) for f, h in zip(folds, hf)]
    rms = []
    lower = model._bounds(X.shape[1])
    held_all = np.asarray(folds, bool)
    # folds that partition the rows (blocked folds do): each held-out block is factored once (qr_reduce) and every
    # fold is solved on the stacked factors of its training blocks -- the same minimiser as on the training rows
    blocks = [] if held_all.ndim == 2 and np.all(held_all.sum(axis=0) == 1) else None
    p, low = X.shape[1], 0.0
    for h in (held_all if blocks is not None else ()):
        blocks.append(qr_reduce(X[keep & h], y[keep & h]))
        R, ev = blocks[-1][0], keep & h
        if bound is not None and R.shape[0] > p:
            n_ev = np.count_nonzero(ev[:n_cal]) + np.count_nonzero(ev[n_cal:]) * w2
            low += max(abs(R[p, p]) - 1e-9 * np.linalg.norm(R), 0.0) / np.sqrt(n_ev) / len(held_all)
            if low > bound * (1.0 + 1e-3):
                return []
    for f, held in enumerate(folds):
        if blocks is None:
            tr = keep & ~held
            w = ridge_lstsq(X[tr], y[tr], pen, model.ridge, lower=lower)
        else:
            train = [b for i, b in enumerate(blocks) if i != f]
            R = np.vstack([b[0] for b in train])
            w = ridge_lstsq(R[:, :p], R[:, p], pen, model.ridge, lower=lower,
                            reduced=(sum(b[1] for b in train), np.sum([b[2] for b in train], axis=0)))
        ev = held & keep
        r = X[ev] @ w - y[ev]
        n_ev_cal = int(np.count_nonzero(ev[:n_cal]))
        rms.append(_combined_rms(r[:n_ev_cal], r[n_ev_cal:], w2))
    return rms


def _hold_score(model, holds, dt, n_cal: int, n_folds: int):
    """Per fold: the weighted hold residuals of a fitted model on the holds held out in that fold (models that do
    not take hold rows in their fit are still scored on them), and ``w^2``."""
    from .holds import _stride_and_weight, hold_residual

    r, hid = hold_residual(model, holds, dt, n_cal)
    return r, _hold_folds(hid, n_folds), _stride_and_weight(holds, n_cal)[1] ** 2


def _cv_qp(model, qs, ys, dt, E, folds, free, thin, holds=None, bound: float | None = None):
    """CV of a model without extra columns (modified PI): fitted on the first free-tip segment's training rows,
    then the extra columns regressed on the residual of the training rows of all segments. ``bound``: stop once the
    folds done can no longer give a mean below it (:func:`_beyond`)."""
    lengths = [len(q) for q in qs]
    i0 = int(np.flatnonzero(free)[0])
    off0 = int(sum(lengths[:i0]))
    y = np.concatenate(ys)
    keep = np.zeros(len(y), bool)
    keep[::thin] = True
    rms = []
    for held in folds:
        m = (~held)[off0:off0 + lengths[i0]]
        model.fit_masked(qs[i0], ys[i0], dt, m)
        pred = np.concatenate([model.predict(q, dt) for q in qs])
        r = y - pred
        tr = keep & ~held
        if E is not None:
            c, *_ = np.linalg.lstsq(E[tr], r[tr], rcond=None)
            r = r - E @ c
        ev = held & keep
        rms.append(_fold_rms(model, r[ev], holds, dt, len(y) // max(fit_stride(lengths), 1), len(folds), len(rms)))
        if _beyond(rms, len(folds), bound):
            break
    return rms


def _fold_rms(model, r_cal, holds, dt, n_cal: int, n_folds: int, fold: int) -> float:
    """Held-out RMS of fold ``fold``: calibration rows ``r_cal`` and, with ``holds``, the fitted model's residual on
    the holds held out in that fold."""
    if not holds:
        return float(np.sqrt(np.mean(r_cal ** 2)))
    rh, hf, w2 = _hold_score(model, holds, dt, n_cal, n_folds)
    return _combined_rms(r_cal, rh[hf[fold]] if hf.size else rh[:0], w2)


def _takes_fold_starts(model) -> bool:
    """A model fitted by a non-convex search on masked rows (``duhem``): its final fit on all rows also starts from
    its blocked-CV fold fits (:func:`_final_fit`), in the selection and where the form is held alike."""
    return bool(getattr(model, "joint_extra", False)) and not getattr(model, "convex", True)


def _beyond(rms: list, n_folds: int, bound) -> bool:
    """Whether the fold errors done already put the mean over ``n_folds`` folds above ``bound``: every fold's RMS is
    >= 0, so the mean is at least ``sum(done) / n_folds`` (a strict, relative margin of 1e-12 against rounding).
    ``bound = (mean, folds)`` of the best convex candidate (a non-convex candidate, :func:`select_h_model`): also
    whether the one-standard-error rule can no longer prefer this one to it (:func:`_se_beyond`)."""
    ref, alt = bound if isinstance(bound, tuple) else (bound, None)
    return ref is not None and (float(np.sum(rms)) / n_folds > ref * (1.0 + 1e-12)
                                or (alt is not None and _se_beyond(rms, alt)))


def _se_beyond(rms: list, alt) -> bool:
    """Whether a non-convex candidate with the fold errors ``rms`` done can no longer pass the one-standard-error
    rule against the convex candidate of fold errors ``alt`` (:func:`select_h_model`): it needs ``m > 0`` and
    ``n m^2 > s^2`` for the paired differences ``d = alt - rms`` (mean ``m``, sample variance ``s^2``, ``n`` folds).
    Every fold's RMS is >= 0, so ``m <= M = (sum(d done) + sum(alt not done)) / n``, and ``(n - 1) s^2 >= S(m) =
    sum over the folds done of (d - m)^2``; ``n (n - 1) m^2 - S(m)`` is convex in ``m`` and <= 0 at 0, so it is <= 0
    on all of (0, M] when it is < 0 at M (or M <= 0): the candidate could not be selected whatever its other folds
    (a relative margin of 1e-9 against rounding). Its first folds far above the convex candidate's decide early."""
    n, k = len(alt), len(rms)
    d = np.asarray(alt[:k], float) - np.asarray(rms, float)
    m = max((float(np.sum(d)) + float(np.sum(alt[k:]))) / n, 0.0)
    S = float(np.sum((d - m) ** 2))
    return n > 1 and n * (n - 1) * m * m < S * (1.0 - 1e-9)


def _cv_masked(model, qs, ys, dt, extras, n_blocks, rotate, thin, holds=None, starts_out: list | None = None,
               bound: float | None = None, only: int | None = None):
    """CV of a model that is not linear in its parameters but fits extra columns jointly and accepts a row mask
    (``duhem``): fitted on the training rows of every segment (its state runs over every sample), scored on every
    ``thin``-th held-out row. ``starts_out``: a list that receives each fold fit's parameters (``coef_``), the
    extra starting points of the final fit on all rows (:func:`_final_fit`). ``bound``: stop once the folds done
    can no longer give a mean below it (:func:`_beyond`). ``only``: fit and score fold ``only`` alone (a list of one
    RMS): each fold's fit starts afresh from the rows (nothing of an earlier fold is read), so the folds of one
    candidate can be fitted in separate workers and give the bits of the loop over all of them."""
    lengths = [len(q) for q in qs]
    folds = blocked_folds(lengths, n_blocks, rotate=rotate)
    y = np.concatenate(ys)
    keep = np.zeros(len(y), bool)
    keep[::thin] = True
    rms = []
    for f, held in enumerate(folds):
        if only is not None and f != only:
            continue
        # the model thins its own objective rows (contiguous rows keep its equation-error increments); the holds
        # of the other folds join its fit, those of this fold are scored
        kw = {"holds": holds.subset(lambda h: h % len(folds) != f)} if holds else {}
        model.fit(qs, ys, dt, extra=extras, row_mask=split_rows(~held, lengths), **kw)
        if starts_out is not None and getattr(model, "coef_", None) is not None:
            starts_out.append(np.array(model.coef_, dtype=float))
        pred = np.concatenate([model.predict(q, dt) for q in qs])
        if extras is not None and len(model.extra_coef_):
            pred = pred + _stack_extra(extras, lengths) @ model.extra_coef_
        ev = held & keep
        rms.append(_fold_rms(model, (pred - y)[ev], holds, dt, len(y) // max(fit_stride(lengths), 1), len(folds), f))
        if _beyond(rms, len(folds), bound):
            break
    return rms


#: the QP candidate (modified PI) is cross-validated at full rate on records of up to this many samples (three 16 s
#: trials at 5 kHz: 228,750); its fit and prediction grow linearly with them (1.1 GB at 10^6 samples on one trial),
#: so longer records keep it out of the race with a status that says so (a configured h_model names it in a warning)
QP_MAX_SAMPLES = 800_000


def cv_candidate(model, kind: str, params, qs, ys, dt: float, extras, free, folds, n_blocks: int, rotate: bool,
                 thin: int, holds=None, rows_out: list | None = None, starts_out: list | None = None,
                 bound: float | None = None) -> dict:
    """One row of the selection table: the blocked-CV fold RMS of ``model`` (made from ``kind``, ``params``) on the
    segments, by the fit its class needs (linear least squares, the masked joint fit, or the QP on the first
    free-tip segment); a candidate that cannot be fitted is out of the race and its status says why.
    ``rows_out``: a list that receives the stacked least-squares rows of a model linear in its parameters
    (:func:`_cv_linear`); ``starts_out``: a list that receives the fold fits' parameters of a masked joint fit
    (:func:`_cv_masked`). ``bound`` (a fit fold by fold: the masked joint fit, the QP): the CV stops once its mean
    cannot come below ``bound`` (:func:`_beyond`); the row then has the folds done, NaN for the others and the status
    :data:`PRUNED_STATUS`."""
    lengths = [len(q) for q in qs]
    k = fit_stride(lengths)
    try:
        if isinstance(model, LinearParamH) or getattr(model, "linear_in_parameters", False):
            rms = _cv_linear(model, qs, ys, dt, extras, folds, thin, holds, rows_out=rows_out,
                             bound=bound[0] if isinstance(bound, tuple) else bound)
        elif _fitted_fold_by_fold(model):
            rms = _cv_masked(model, qs, ys, dt, extras, n_blocks, rotate, thin * k, holds,
                             starts_out=starts_out if _takes_fold_starts(model) else None, bound=bound)
        elif k == 1:
            rms = _cv_qp(model, qs, ys, dt, _stack_extra(extras, lengths), folds, free, thin, holds, bound=bound)
        elif sum(lengths) > QP_MAX_SAMPLES:
            raise ValueError(f"records of {sum(lengths)} samples: the QP candidate is cross-validated at full rate on "
                             f"up to {QP_MAX_SAMPLES} samples (memory)")
        else:
            # records longer than MAX_FIT_ROWS: the other candidates' rows are every k-th sample, but the QP fits
            # its one free-tip segment at full rate anyway (its play states need every sample): the same contiguous
            # blocks at full rate, scored on every (thin k)-th row as the strided candidates are
            full = blocked_folds(lengths, n_blocks, rotate=rotate)
            rms = _cv_qp(model, qs, ys, dt, _stack_extra(extras, lengths), full, free, thin * k, holds, bound=bound)
        status = "ok"
        if len(rms) < n_blocks:
            se = isinstance(bound, tuple) and not _beyond(rms, n_blocks, bound[0])   # stopped by the 1-SE rule
            status = PRUNED_SE_STATUS if se else PRUNED_STATUS if len(rms) else PRUNED_BLOCKS_STATUS
            rms = list(rms) + [float("nan")] * (n_blocks - len(rms))
    except Exception as exc:  # a candidate that cannot be fitted is out of the race, and says why
        rms, status = [float("nan")] * n_blocks, _failed(exc)
    return _table_row(model, kind, params, rms, status)


def _failed(exc: BaseException) -> str:
    """The status of a candidate whose fit raised ``exc``."""
    return f"failed: {type(exc).__name__}: {str(exc)[:200]}"


def _table_row(model, kind: str, params, rms, status: str) -> dict:
    """A row of the selection table from the fold errors ``rms`` and the fit's ``status``; a fit that returned NaN /
    inf on some folds is out of the race too."""
    bad = [i + 1 for i, r in enumerate(rms) if not np.isfinite(r)]
    if status == "ok" and bad:
        status = f"failed: non-finite held-out error on fold(s) {bad}"
    return {"kind": kind, "params": dict(params), "label": model.label(), "cv_rms_v": [float(r) for r in rms],
            "cv_rms_mean_v": float(np.mean(rms)) if np.all(np.isfinite(rms)) else float("nan"),
            "status": status, "selected": False}


def _fitted_fold_by_fold(model) -> bool:
    """Whether :func:`cv_candidate` cross-validates ``model`` by the masked joint fit (:func:`_cv_masked`: not linear
    in its parameters, extra columns fitted jointly), whose folds :func:`cv_fold` can fit one at a time."""
    return (not (isinstance(model, LinearParamH) or getattr(model, "linear_in_parameters", False))
            and bool(getattr(model, "joint_extra", False)))


def cv_fold(model, qs, ys, dt: float, extras, n_blocks: int, rotate: bool, thin: int, holds, fold: int):
    """Fold ``fold`` alone of the blocked CV that :func:`cv_candidate` makes of a model fitted fold by fold
    (:func:`_fitted_fold_by_fold`, no ``bound``): ``(its held-out RMS, its fit's parameters as starting points (a
    list), None)``, or ``(None, [], the failed status)`` where its fit raises. :func:`merge_folds` makes the
    candidate's row of them."""
    starts: list = []
    k = fit_stride([len(q) for q in qs])
    try:
        rms = _cv_masked(model, qs, ys, dt, extras, n_blocks, rotate, thin * k, holds,
                         starts_out=starts if _takes_fold_starts(model) else None, only=fold)
    except Exception as exc:  # noqa: BLE001 -- a fold that cannot be fitted fails its candidate, as in cv_candidate
        return None, [], _failed(exc)
    return rms[0], starts, None


def merge_folds(model, kind: str, params, parts: list, n_blocks: int) -> dict:
    """The row of :func:`cv_candidate` (no ``bound``) from the results of :func:`cv_fold` for every fold, in fold
    order: the same fold errors and status (the first fold that raised decides it, as the loop over the folds stops
    there), and the fold fits' parameters as ``_starts`` (popped by :func:`select_h_model`)."""
    err = next((e for _, _, e in parts if e is not None), None)
    if err is not None:
        return _table_row(model, kind, params, [float("nan")] * n_blocks, err)
    row = _table_row(model, kind, params, [r for r, _, _ in parts], "ok")
    starts = [c for _, st, _ in parts for c in st]
    if starts:
        row["_starts"] = starts
    return row


#: status of a candidate whose blocked CV was stopped (``select_h_model(..., prune=True)``): it could not be selected
PRUNED_STATUS = "pruned: its folds done already exceed the best convex candidate's mean"
#: ... a non-convex one stopped because the one-standard-error rule could no longer prefer it (:func:`_se_beyond`)
PRUNED_SE_STATUS = "pruned: its folds done already fail the one-standard-error rule against the best convex candidate"
#: ... one linear in its parameters stopped by its held-out blocks' own least-squares residuals (:func:`_cv_linear`)
PRUNED_BLOCKS_STATUS = "pruned: its held-out blocks' own least-squares residuals already exceed the best convex mean"


#: a candidate whose worst held-out fold exceeds this many times the straight line's worst fold is unstable out of
#: sample (a non-convex fit or a state that wanders where no data were) and is not selected
UNSTABLE_FACTOR = 10.0


def _reject_unstable(table: list[dict]) -> None:
    """Mark candidates that explode on some folds (worst fold > :data:`UNSTABLE_FACTOR` x the straight line's worst
    fold) as rejected, with the numbers in their status."""
    lin = next((r for r in table if r["kind"] == "linear" and r["status"] == "ok"), None)
    if lin is None:
        return
    ref = float(np.max(lin["cv_rms_v"]))
    for r in table:
        if r is lin or r["status"] != "ok":
            continue
        if _unstable(r, ref):
            r["status"] = (f"rejected: unstable out of sample (worst fold {float(np.max(r['cv_rms_v'])):.4g} V > "
                           f"{UNSTABLE_FACTOR:g} x the straight line's worst fold {ref:.4g} V)")


def _unstable(row: dict, lin_worst: float) -> bool:
    """Whether a candidate's worst held-out fold exceeds :data:`UNSTABLE_FACTOR` x the straight line's worst fold."""
    return float(np.max(row["cv_rms_v"])) > UNSTABLE_FACTOR * lin_worst


def json_safe_table(table: list[dict]) -> list[dict]:
    """The selection table with non-finite numbers as ``None`` (JSON null): failed candidates stay on record."""
    def safe(v):
        if isinstance(v, float) and not np.isfinite(v):
            return None
        if isinstance(v, list):
            return [safe(x) for x in v]
        return v
    return [{k: safe(v) for k, v in r.items()} for r in table]


# one BLAS thread throughout, in the serial loop and around its workers alike (the pipeline pins the process anyway):
# the table and the model then have the same bits for every cv_workers count in any caller's process
@with_one_blas_thread
def select_h_model(qs, ys, dt: float, extras=None, free=None, candidates=DEFAULT_CANDIDATES, n_blocks: int = 5,
                   thin: int = 4, trial_names=None, baseline_only_warn: bool = True,
                   rotate_folds: bool | None = None, holds=None, cv: bool = True, prune: bool = False,
                   probes=None) -> SelectionResult:
    """Blocked CV over ``candidates`` on the calibration segments ``(qs[i], ys[i])`` with joint ``extras[i]``
    columns; returns the best model refitted on all rows, its extra coefficients and the selection table.

    ``free``: boolean per segment, the free-tip segments (a model without extra-column support is fitted on the
    first of them). ``trial_names``: used in warnings and errors. ``holds``
    (:class:`~selfsense.hysteresis.models.holds.HoldSet`): reference-free hold rows of every trial, fitted by the
    models linear in their parameters and scored for every candidate (each hold held out in one fold).

    ``cv=False``: a held form (``candidates`` = the straight line and at most one other form, e.g.
    :meth:`~selfsense.sensing.estimator.SelfSensingEstimator.selected_form`) is fitted without the blocked CV: the
    form other than the straight line (the straight line when there is none) is selected and refitted on all rows
    by the same final fit as after the CV -- the final fit reads no CV number, so the model is bit-identical to the
    one the CV gives wherever it selects that form. Its table rows carry no fold errors (NaN) and the status
    :data:`HELD_STATUS`; no warning or straight-line check is made (they read the CV).

    ``prune=True`` (a caller that reads only the selected row, as the gap diagnostic's recalibrations): candidates
    are cross-validated one after the other in the given order, and one fitted fold by fold (the masked joint fit,
    the QP) is stopped as soon as the mean of its fold errors is sure to exceed that of the best convex candidate
    done so far (each fold's RMS is >= 0): it could be neither the best nor, under the one-standard-error rule
    above, preferred to that convex one, so the selected model, its row and the warnings are those of the full
    selection; the stopped rows keep the folds done and the status :data:`PRUNED_STATUS`. Two more stops that leave
    the selection as it is: a candidate linear in its parameters whose held-out blocks' own least-squares residuals
    already put its mean above that one's (:func:`_cv_linear`, :data:`PRUNED_BLOCKS_STATUS`: every fold's factor is
    needed before any fold is solved, so its rows are built but the remaining blocks are not factored), and a
    non-convex candidate whose folds done can no longer pass the one-standard-error rule against it
    (:func:`_se_beyond`, :data:`PRUNED_SE_STATUS`; kept only where that convex row stays the best convex one and no
    other candidate comes to its mean, else cross-validated again with the mean bound alone). On the gap
    recalibration of tweezer_sim with the stress member forced on: Preisach n_grid 24 stopped after 4 of 5 blocks,
    RI after 2, the Duhem form with creep after 1 fold instead of 2 (about 1.2 s CPU less). The straight line and
    the PI baseline are never stopped (the checks above read them), and nothing is stopped before the straight line
    is done (its worst fold decides which candidates are unstable, :func:`_reject_unstable`).

    ``probes``: ``(name, q)`` charge paths of every trial (reference-free, from the relay's opening). The selected
    candidate, refitted on all rows, must keep its output on each within its own major loop
    (:func:`envelope_excursion`, :data:`ENVELOPE_TOL`); one that does not is marked rejected with the numbers in its
    status and the next best is selected and refitted (the straight line is never rejected so). With ``prune``, the
    candidates stopped before the next pick are cross-validated in full first, so the selection stays the one without
    pruning."""
    if not cv:
        return _fit_held(qs, ys, dt, extras, free, candidates, holds, n_blocks, thin, rotate_folds)
    if not holds:
        # without hold rows, a form that differs from another candidate only in how it fits them is that candidate
        # (a form held alone, as the chain's member searches pass it, stays: it is then fitted as that twin)
        candidates = tuple(c for c in candidates if not searches_holds(c) or without_hold_search(c) not in candidates)
    qs = [np.asarray(q, float) for q in qs]
    ys = [np.asarray(y, float) for y in ys]
    lengths = [len(q) for q in qs]
    free = np.ones(len(qs), bool) if free is None else np.asarray(free, bool)
    names = list(trial_names) if trial_names is not None else [f"segment {i}" for i in range(len(qs))]
    k = fit_stride(lengths)
    E = _stack_extra(extras, lengths)
    rotate = ROTATE_FOLDS if rotate_folds is None else bool(rotate_folds)
    folds = blocked_folds([len(q[::k]) for q in qs], n_blocks, rotate=rotate)
    holds = holds if holds else None
    def row(cand, rows_out=None, bound=None):
        kind, params = cand
        starts: list = []
        r = cv_candidate(make_model(kind, **params), kind, params, qs, ys, dt, extras, free, folds, n_blocks,
                         rotate, thin, holds, rows_out=rows_out, starts_out=starts, bound=bound)
        if starts:   # the fold fits of a non-convex model: starting points of its final fit (taken off below)
            r["_starts"] = starts
        return r

    workers = 1 if prune else min(_CV_WORKERS.get(), len(candidates))   # pruning needs the order of the candidates
    kept = None   # (table row, its least-squares rows): the best candidate so far linear in its parameters
    if workers > 1:
        from selfsense.parallel import fork_map

        # units of work: a candidate, or one fold of a candidate fitted fold by fold (the non-convex searches, the
        # longest candidates: as whole candidates two of them kept both workers busy while the rest waited; their
        # folds are independent fits, cv_fold); the longest first
        units = []
        for i in sorted(range(len(candidates)), key=lambda i: _cost_rank(*candidates[i])):
            split = _fitted_fold_by_fold(make_model(candidates[i][0], **candidates[i][1]))
            units += [(i, f) for f in range(n_blocks)] if split else [(i, None)]

        def unit(u):
            i, f = u
            if f is None:
                return row(candidates[i])
            kind, params = candidates[i]
            return cv_fold(make_model(kind, **params), qs, ys, dt, extras, n_blocks, rotate, thin, holds, f)

        table, parts = [None] * len(candidates), {}
        for (i, f), got in zip(units, fork_map(unit, units, workers, threads_fallback=True)):
            if f is None:
                table[i] = got
            else:
                parts.setdefault(i, []).append(got)
        for i, got in parts.items():
            kind, params = candidates[i]
            table[i] = merge_folds(make_model(kind, **params), kind, params, got, n_blocks)
    else:
        # one after the other, here: the stacked rows of the best candidate so far are kept (at most one matrix
        # of at most KEEP_ROWS_BYTES), and if it is selected its final fit solves them as they are instead of
        # building them again (the same rows, so the same model bit for bit; in forked workers they stay there)
        table, se_cut = [], []   # se_cut: (index, candidate, the row it was stopped against) of 1-SE stops
        ref, ref_row, lin_worst = None, None, (None if any(c[0] == "linear" for c in candidates) else np.inf)
        for c in candidates:
            got: list = []
            bound = ref if prune and lin_worst is not None and c[0] not in ("linear", "pi") else None
            if bound is not None and not getattr(make_model(c[0], **c[1]), "convex", True):
                bound = (ref, ref_row["cv_rms_v"])
            r = row(c, got, bound)
            if r["status"] == PRUNED_SE_STATUS:
                se_cut.append((len(table), c, ref_row))
            if r["kind"] == "linear" and lin_worst is None:
                lin_worst = float(np.max(r["cv_rms_v"])) if r["status"] == "ok" else np.inf
            if (prune and r["kind"] != "linear" and r["status"] == "ok" and np.isfinite(r["cv_rms_mean_v"])
                    and getattr(make_model(r["kind"], **r["params"]), "convex", True) and lin_worst is not None
                    and not _unstable(r, lin_worst)
                    and (ref is None or r["cv_rms_mean_v"] < ref)):
                ref, ref_row = r["cv_rms_mean_v"], r   # the best convex candidate so far that _reject_unstable keeps
            table.append(r)
            if (got and r["status"] == "ok" and np.isfinite(r["cv_rms_mean_v"]) and got[0].X.nbytes <= KEEP_ROWS_BYTES
                    and (kept is None or r["cv_rms_mean_v"] < kept[0]["cv_rms_mean_v"])):
                kept = (r, got[0])
            del got
        for i, c, alt in se_cut:
            # a 1-SE stop holds where that convex row stayed the best convex one (the SE rule's reference) and no
            # other candidate's mean is at or below it (else it, not that row, would stand in for the stopped one):
            # elsewhere the candidate is cross-validated again as the mean bound alone would have done
            if ref_row is not alt or any(r["status"] == "ok" and r is not alt and not r["cv_rms_mean_v"] > ref
                                         for r in table):
                table[i] = row(c, None, alt["cv_rms_mean_v"])
    starts = [r.pop("_starts", None) for r in table]
    _reject_unstable(table)
    envelope: list = []   # the envelope check of each candidate refitted (the last one is the selected one's)
    while True:
        ok = [r for r in table if r["status"] == "ok" and np.isfinite(r["cv_rms_mean_v"])]
        if not ok:
            raise DegenerateFitError("H(q) selection: no candidate model could be fitted on the calibration trials "
                                     f"{names}: " + "; ".join(f"{r['label']}: {r['status']}" for r in table))
        best = _pick_best(ok)
        i_best = next(i for i, r in enumerate(table) if r is best)
        model, extra_coef = _final_fit(best, qs, ys, dt, E, lengths, free, holds,
                                       kept[1] if kept is not None and kept[0] is best else None,
                                       starts=starts[i_best])
        if probes is None or best["kind"] == "linear":
            break
        env = envelope_excursion(model, qs, probes, dt)
        env["label"] = best["label"]
        envelope.append(env)
        if not env["excursion"] > ENVELOPE_TOL:
            break
        # the refitted model leaves the range of its own major loop on a trial's measured charge: out of the race
        # (the next best candidate is refitted; the straight line, bounded by construction, is never rejected here).
        # Candidates stopped against it (prune) are cross-validated in full first: the stop assumed that it, or a
        # candidate better than them, stays in the race, so the selection is again the one without pruning
        best["status"] = envelope_status(env)
        redo = [i for i, r in enumerate(table) if r["status"] in (PRUNED_STATUS, PRUNED_SE_STATUS,
                                                                  PRUNED_BLOCKS_STATUS)]
        for i in redo:
            table[i] = row(candidates[i])
            starts[i] = table[i].pop("_starts", None)
        if redo:
            _reject_unstable(table)
    best["selected"] = True
    warnings = []
    lin = next((r for r in ok if r["kind"] == "linear"), None)
    pis = [r for r in ok if r["kind"] == "pi"]
    if lin is not None and best is not lin and not best["cv_rms_mean_v"] < lin["cv_rms_mean_v"]:
        raise DegenerateFitError(f"H(q) on calibration trials {names}: {best['label']} does not beat a straight line "
                                 f"out of sample ({best['cv_rms_mean_v']:.4g} V vs {lin['cv_rms_mean_v']:.4g} V)")
    if best["kind"] == "linear":
        warnings.append(f"H(q) on calibration trials {names}: no hysteresis model beats a straight line out of "
                        f"sample ({best['cv_rms_mean_v']:.4g} V RMS); H is linear (no hysteresis identified)")
    if pis and best["kind"] != "pi" and not best["cv_rms_mean_v"] < min(r["cv_rms_mean_v"] for r in pis):
        warnings.append(f"H(q) on {names}: {best['label']} does not beat the PI baseline out of sample")
    warnings += [f"H(q) on {names}: {e['label']} " + envelope_status(e).removeprefix("rejected: ") + ": not selected"
                 for e in envelope if e["excursion"] > ENVELOPE_TOL]
    for w in warnings:
        log.warning(w)
    return SelectionResult(model=model, extra_coef=extra_coef, table=table, warnings=warnings,
                           envelope=envelope if probes is not None else None)


def _pick_best(ok: list[dict]) -> dict:
    """The row with the lowest blocked-CV mean among ``ok``; a model fitted by a non-convex search (local minima, a
    state that can wander where no data were) is kept only if it beats the best convex candidate clearly: by more
    than one standard error of the paired fold differences (the one-standard-error rule, Hastie, Tibshirani &
    Friedman, Elements of Statistical Learning, sec. 7.10), else the convex one is selected."""
    best = min(ok, key=lambda r: r["cv_rms_mean_v"])
    if not getattr(make_model(best["kind"], **best["params"]), "convex", True):
        convex = [r for r in ok if getattr(make_model(r["kind"], **r["params"]), "convex", True)
                  and r["kind"] != "linear"]
        if convex:
            alt = min(convex, key=lambda r: r["cv_rms_mean_v"])
            d = np.asarray(alt["cv_rms_v"]) - np.asarray(best["cv_rms_v"])
            se = float(np.std(d, ddof=1) / np.sqrt(d.size)) if d.size > 1 else 0.0
            if not float(np.mean(d)) > se:
                best = alt
    return best


#: the selected H(q), run on the measured charge of every trial (reference-free: V and Q are logged in operation),
#: may leave the range its output spans on the calibration rows by at most this fraction of that range, beyond
#: what the trial's charge outside the calibrated charge range allows (docs/method.md 6b)
ENVELOPE_TOL = 0.5


def envelope_excursion(model, qs_cal, probes, dt: float) -> dict:
    """How far ``model``'s output on the charge paths ``probes`` (``(name, q)`` pairs: every trial's charge after
    the relay opens, from the relaxed state) leaves the range ``[lo, hi]`` of its output on the calibration rows
    ``qs_cal``, in units of that range: ``max(0, max H - hi, lo - min H) / (hi - lo)`` less the fraction of the
    calibrated charge range by which the probe's charge goes beyond it (H may go on along its slope there).

    A hysteresis operator with the wiping-out and congruency properties (Preisach, and the PI and Kuhnen operators
    built from plays) keeps every minor loop inside the major loop that encloses it (Mayergoyz, Mathematical Models
    of Hysteresis, ch. 1), and a creep part relaxes towards it. The calibration's sine from the relaxed state is
    such a major loop, so a model whose output on a trial's charge leaves it far has not identified the operator:
    a Duhem model with polynomial shape functions, or a creep bank held at a level for seconds it never saw, can
    run away on the minor loops and holds of the validation drives (measured: -80 V against a calibrated -28 to
    1 V, the tip estimate then pinned at its limit). Returns ``{"excursion", "trial", "range_v", "h_v"}`` of the
    worst probe (``excursion`` inf where the output is not finite)."""
    h_cal = [np.asarray(model.predict(np.asarray(q, float), dt), float) for q in qs_cal]
    lo, hi = float(min(h.min() for h in h_cal)), float(max(h.max() for h in h_cal))
    qlo, qhi = float(min(np.min(q) for q in qs_cal)), float(max(np.max(q) for q in qs_cal))
    span, qspan = hi - lo, qhi - qlo
    worst = {"excursion": 0.0, "trial": None, "range_v": [lo, hi], "h_v": None}
    if not (span > 0 and qspan > 0):
        return worst
    for name, q in probes:
        q = np.asarray(q, float)
        if q.size < 2:
            continue
        h = np.asarray(model.predict(q, dt), float)
        if not np.all(np.isfinite(h)):
            return {**worst, "excursion": float("inf"), "trial": name, "h_v": None}
        beyond = max(0.0, float(q.max()) - qhi, qlo - float(q.min())) / qspan
        exc = max(0.0, float(h.max()) - hi, lo - float(h.min())) / span - beyond
        if exc > worst["excursion"]:
            worst = {"excursion": exc, "trial": name, "range_v": [lo, hi], "h_v": [float(h.min()), float(h.max())]}
    return worst


def configured_envelope(model, qs_cal, probes, dt: float, names) -> tuple[dict, str | None]:
    """The major-loop check (:func:`envelope_excursion`) of a model the configuration names (``h_model`` other than
    ``auto``): run on the same charge paths as the selection's, but the model is kept -- it is the user's choice --
    and a warning says what ``auto`` would have done. Returns the check (with the model's ``label``) and the warning,
    None where the model stays within :data:`ENVELOPE_TOL` of its range."""
    env = envelope_excursion(model, qs_cal, probes, dt)
    env["label"] = model.label()
    if not env["excursion"] > ENVELOPE_TOL:
        return env, None
    return env, (f"H(q) on {list(names)}: the configured {model.label()} "
                 + envelope_status(env).removeprefix("rejected: ")
                 + "; kept because h_model names it (h_model: auto would not select it): expect runaway estimates on "
                   "that trial's minor loops and holds")


def envelope_status(env: dict) -> str:
    """The selection table's status of a candidate rejected by :func:`envelope_excursion`."""
    lo, hi = env["range_v"]
    got = ("a non-finite output" if env["h_v"] is None else
           f"{env['h_v'][0]:.4g} to {env['h_v'][1]:.4g} V, {env['excursion']:.2f} of that range beyond it")
    return (f"rejected: leaves its own major loop on the measured charge of trial {env['trial']} ({got}; the "
            f"calibration rows span {lo:.4g} to {hi:.4g} V; at most {ENVELOPE_TOL:g} of the range is allowed)")


#: status of the table rows of a form held without the blocked CV (``select_h_model(..., cv=False)``)
HELD_STATUS = "held: fitted without blocked CV"


def _fit_held(qs, ys, dt: float, extras, free, candidates, holds, n_blocks: int = 5, thin: int = 4,
              rotate_folds: bool | None = None) -> SelectionResult:
    """``select_h_model(..., cv=False)``: the held form refitted on all rows, with the arguments prepared as the
    selection prepares them and the same final fit (:func:`_final_fit`). A form fitted by a non-convex search takes
    the fold fits of its blocked CV as extra starting points there, as after the selection; they are fitted here the
    same way (their errors are not scored), so the held model is still the one the selection gives."""
    qs = [np.asarray(q, float) for q in qs]
    ys = [np.asarray(y, float) for y in ys]
    lengths = [len(q) for q in qs]
    free = np.ones(len(qs), bool) if free is None else np.asarray(free, bool)
    forms = [c for c in candidates if c[0] != "linear"]
    if len(forms) > 1 or not candidates:
        raise ValueError("select_h_model(cv=False) holds one form (beside the straight line), got "
                         f"{[c[0] for c in candidates]}")
    i_held = next((i for i, c in enumerate(candidates) if c[0] != "linear"), 0)
    table = [{"kind": kind, "params": dict(params), "label": make_model(kind, **params).label(), "cv_rms_v": [],
              "cv_rms_mean_v": float("nan"), "status": HELD_STATUS, "selected": i == i_held}
             for i, (kind, params) in enumerate(candidates)]
    held = next(r for r in table if r["selected"])
    holds = holds if holds else None
    model = make_model(held["kind"], **held["params"])
    starts = None
    if _takes_fold_starts(model):
        starts = []
        _cv_masked(model, qs, ys, dt, extras, n_blocks, ROTATE_FOLDS if rotate_folds is None else bool(rotate_folds),
                   thin * fit_stride(lengths), holds, starts_out=starts)
    model, extra_coef = _final_fit(held, qs, ys, dt, _stack_extra(extras, lengths), lengths, free, holds, None,
                                   starts=starts)
    return SelectionResult(model=model, extra_coef=extra_coef, table=table, warnings=[])


def _final_fit(best: dict, qs, ys, dt: float, E, lengths, free, holds, rows, starts=None):
    """The selected row's model refitted on all calibration rows (``rows``: its stacked least-squares rows kept
    from the CV, or None) and its extra coefficients. ``starts``: the fold fits' parameters of a non-convex model
    (:func:`_cv_masked`), extra starting points of its search on all rows: its own two starts can end in a local
    minimum far above every fold's fit (measured: 1.76 V RMS in sample where the five folds reached 0.066-0.070 V,
    Jiles-Atherton drift device 0 of the stage chain with leakage and offset drift)."""
    model = make_model(best["kind"], **best["params"])
    if isinstance(model, LinearParamH):
        model.fit(qs, ys, dt, extra=None if E is None else split_rows(E, lengths), holds=holds, rows=rows)
        extra_coef = model.extra_coef_
    elif getattr(model, "joint_extra", False):
        kw = {"starts": starts} if starts else {}
        model.fit(qs, ys, dt, extra=None if E is None else split_rows(E, lengths), holds=holds, **kw)
        extra_coef = model.extra_coef_
    else:
        i0 = int(np.flatnonzero(free)[0])
        model.fit(qs[i0], ys[i0], dt)
        if E is not None:
            r = np.concatenate(ys) - np.concatenate([model.predict(q, dt) for q in qs])
            extra_coef, *_ = np.linalg.lstsq(E, r, rcond=None)
        else:
            extra_coef = np.zeros(0)
    return model, np.asarray(extra_coef, float)
