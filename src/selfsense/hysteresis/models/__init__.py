"""Registry of H(q) models: one public interface for every hysteresis model the estimator can use.

Every model (scikit-learn style; ``docs/hysteresis.md``):

* ``kind`` (class attribute, the registry key), hyper-parameters in the constructor;
* ``fit(q, v, dt, extra=None)`` on one trial (arrays) or several (lists of arrays, each from the relaxed state that
  the charge circuit's relay establishes, thesis 000_18d138f03f1777c3.txt sec. 5.1.1); ``dt`` [s] is the sample
  time of the data, stored as ``dt_``;
* ``predict(q, dt=None, state=None)`` -> H [V] from the relaxed state, at the sample time ``dt`` (default ``dt_``):
  creep eigenvalues live in 1/s and are discretised at the evaluation sample time; ``model(q)`` is ``predict(q)``;
* streaming: ``state = model.initial_state()`` (the relaxed state), then ``predict(block, dt, state)`` block after
  block carries the operators' memory in ``state`` (updated in place), and the blocks' outputs concatenated are
  exactly ``predict(whole_record, dt)``: batch evaluation is the stream fed one block (one code path);
* ``to_dict()`` / ``from_dict(d)`` (plain JSON) and fitted attributes ending in ``_``.

The models linear in their parameters (``linear``, ``pi``, ``preisach``, ``ri``) share :class:`LinearParamH`:
a design matrix ``[hysteretic basis | u | creep bank | 1]`` on the normalised charge ``u = (q - q_lo) / q_span``,
solved as a ridge least-squares problem on the column-scaled design augmented by ``sqrt(ridge N) I`` rows (a pivoted
QR of the design itself, never the Gram matrix ``X^T X``, which squares its condition number: docs/method.md).
Extra columns (``extra``) are fitted jointly and not penalised: the estimator uses them to identify H jointly
with the force coefficient on blocked-tip trials and with the charge leakage (``selfsense.sensing.core``).

``modified_pi`` is Kuhnen's operator identified as a QP (thesis App. A) with the sign and linear gauge built in
(:class:`ModifiedPIH`): it is not linear in its parameters, so it takes no extra columns.
"""
from __future__ import annotations

from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from ._duhem import duhem_run
from ._grid import (grid_state, play_features, play_output, play_output_kernel, preisach_grid_features,
                    preisach_grid_kernel, preisach_grid_output, preisach_grid_rows, relaxation_bank, relaxation_gains,
                    relaxation_output, relaxation_output_kernel, reversible_features, reversible_output)

__all__ = ["REGISTRY", "LinearParamH", "LinearH", "PlayH", "PreisachH", "RIH", "ModifiedPIH", "DuhemH", "h_from_dict",
           "make_model", "searches_holds", "without_hold_search", "DEFAULT_CREEP_TAU_S", "DegenerateFitError",
           # the compiled kernels of predict, for callers that compile them into their own loops (the stream)
           "duhem_run", "preisach_grid_kernel", "play_output_kernel", "relaxation_output_kernel", "relaxation_gains"]

#: at most this many rows enter a least-squares fit: longer calibration records are thinned to every k-th sample
#: for the fit (the operators still run over every sample, and the stored sample time stays the data's)
MAX_FIT_ROWS = 200_000


def normalise_input(model, qs, dt: float) -> None:
    """Set ``model``'s input normalisation from the calibration charge segments ``qs`` (``q_lo_`` = min(0, min q),
    ``q_span_`` = 1.02 x the range above it) and its sample time ``dt_`` [s]; raise on a bad dt or no excitation."""
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"H model fit: dt must be a positive sample time [s], got {dt!r}")
    allq = np.concatenate(qs)
    model.q_lo_ = float(min(0.0, allq.min()))
    span = float(allq.max() - model.q_lo_)
    if not span > 0:
        raise DegenerateFitError("H model fit: the calibration charge does not vary (no excitation)")
    model.q_span_ = span * 1.02
    model.dt_ = float(dt)


def fit_stride(lengths) -> int:
    """Row stride that keeps the stacked fit rows of ``lengths`` samples within :data:`MAX_FIT_ROWS`."""
    return max(1, int(np.ceil(sum(int(n) for n in lengths) / MAX_FIT_ROWS)))


#: creep time constants [s] of the relaxation bank (log-spaced, 0.1 s to 30 s)
DEFAULT_CREEP_TAU_S = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)


class DegenerateFitError(ValueError):
    """A fitted H(q) is not better than a linear H (or the data cannot identify it)."""


def _segments(q, v=None):
    if isinstance(q, (list, tuple)):
        qs = [np.asarray(x, dtype=float) for x in q]
        vs = None if v is None else [np.asarray(x, dtype=float) for x in v]
    else:
        qs = [np.asarray(q, dtype=float)]
        vs = None if v is None else [np.asarray(v, dtype=float)]
    for i, x in enumerate(qs):
        if x.ndim != 1 or x.size < 2:
            raise ValueError(f"H model fit: segment {i}: q must be 1-D with >= 2 samples, got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"H model fit: segment {i}: q has non-finite values")
        if vs is not None and vs[i].shape != x.shape:
            raise ValueError(f"H model fit: segment {i}: q {x.shape} and v {vs[i].shape} differ in shape")
    return qs, vs


class FitRows(NamedTuple):
    """The least-squares rows of :meth:`LinearParamH.fit`: ``X = [design | extra | hold-only columns]`` (calibration
    rows, then ``n_hold`` hold rows), targets ``y``, the ridge-penalised columns, the number of extra columns and
    the running index of each hold row's hold (for the CV folds)."""

    X: np.ndarray
    y: np.ndarray
    penalised: np.ndarray
    n_hold: int
    n_extra: int
    hold_id: np.ndarray


class LinearParamH:
    """Base of the H models linear in their parameters (see the module docstring)."""

    kind = "base"
    #: whether the hysteretic basis is penalised by the ridge (the linear, creep and offset columns are not)
    def __init__(self, ridge: float = 1e-6, creep: bool = True, creep_tau_s: Sequence[float] = DEFAULT_CREEP_TAU_S):
        self.ridge = float(ridge)
        self.creep = bool(creep)
        self.creep_tau_s = tuple(float(t) for t in creep_tau_s)
        self.coef_: np.ndarray | None = None
        self.extra_coef_ = np.zeros(0)
        self.q_lo_ = 0.0
        self.q_span_ = 1.0
        self.dt_ = float("nan")
        self.fit_report_: dict = {}

    # -- model-specific -------------------------------------------------------------------------------------------
    def _params(self) -> dict:
        return {}

    def _basis(self, u: np.ndarray, stride: int = 1) -> np.ndarray:  # (N / stride, p) hysteretic basis
        return np.zeros((len(u[::stride]), 0))

    def _basis_into(self, u: np.ndarray, stride: int, out: np.ndarray) -> None:
        """:meth:`_basis` written into ``out`` (the basis columns of a design matrix); subclasses whose kernels can
        write in place avoid the copy."""
        B = self._basis(u, stride)
        if B.shape != out.shape:
            raise ValueError(f"{type(self).__name__}: basis of shape {B.shape}, expected {out.shape}")
        out[...] = B

    def _setup(self, us: list[np.ndarray]) -> None:
        """Choose data-dependent basis settings from the normalised calibration inputs (stored as fitted attrs)."""

    # -- common -----------------------------------------------------------------------------------------------------
    def _u(self, q: np.ndarray) -> np.ndarray:
        return (np.asarray(q, dtype=float) - self.q_lo_) / self.q_span_

    def n_columns(self) -> int:
        """Columns of :meth:`design` (basis, linear, creep bank, offset)."""
        return self._n_basis() + 2 + (len(self.creep_tau_s) if self.creep and self.creep_tau_s else 0)

    def design(self, q, dt: float, stride: int = 1, out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Design matrix ``[basis | u | creep | 1]`` of one trial (every ``stride``-th row; the operators still run
        over every sample) and the mask of ridge-penalised columns. With ``out`` (rows ``ceil(len(q) / stride)``, at
        least :meth:`n_columns` columns, e.g. a block of a stacked matrix) the matrix is written into its first
        columns, which are returned."""
        u = self._u(q)
        us = u[::stride]
        taus = list(self.creep_tau_s) if self.creep and self.creep_tau_s else []
        nb = self._n_basis()
        # filled in place (the basis written into its columns, no copy per stacking): the same values as
        # column-stacking [B | u | creep bank | 1]
        if out is None:
            X = np.empty((us.size, nb + 2 + len(taus)))
        elif out.shape[0] != us.size or out.shape[1] < nb + 2 + len(taus):
            raise ValueError(f"{type(self).__name__}.design: out of shape {out.shape}, expected {us.size} rows and "
                             f">= {nb + 2 + len(taus)} columns")
        else:
            X = out[:, :nb + 2 + len(taus)]
        self._basis_into(u, stride, X[:, :nb])
        X[:, nb] = us
        for j, t in enumerate(taus):
            X[:, nb + 1 + j] = relaxation_bank(u, float(dt), [t])[::stride, 0]
        X[:, -1] = 1.0
        pen = np.zeros(X.shape[1], bool)
        pen[:nb] = True
        pen[nb + 1:nb + 1 + len(taus)] = True
        return X, pen

    def design_rows(self, q, dt: float, stride: int, rows) -> np.ndarray:
        """Rows ``rows`` (sorted, distinct indices) of ``design(q, dt, stride)[0]``, the same values: the basis from
        :meth:`_basis_rows_into` (models whose basis can skip the rows not asked for, :class:`PreisachH`, do so), the
        linear, creep and offset columns as :meth:`design` builds them, taken at the rows."""
        rows = np.asarray(rows, dtype=np.int64)
        stride = int(stride)
        u = self._u(q)
        taus = list(self.creep_tau_s) if self.creep and self.creep_tau_s else []
        nb = self._n_basis()
        X = np.empty((rows.size, nb + 2 + len(taus)))
        self._basis_rows_into(u, stride, rows, X[:, :nb])
        X[:, nb] = u[::stride][rows]
        for j, t in enumerate(taus):
            X[:, nb + 1 + j] = relaxation_bank(u, float(dt), [t])[::stride, 0][rows]
        X[:, -1] = 1.0
        return X

    def _basis_rows_into(self, u: np.ndarray, stride: int, rows: np.ndarray, out: np.ndarray) -> None:
        """Rows ``rows`` of :meth:`_basis` written into ``out``; this default builds every row."""
        out[...] = self._basis(u, stride)[rows]

    def prepare(self, q, dt: float) -> "LinearParamH":
        """Set the input normalisation (charge range of the calibration data) and the sample time, without
        solving: what :meth:`design` needs."""
        qs, _ = _segments(q)
        normalise_input(self, qs, dt)
        self._setup([self._u(x) for x in qs])
        return self

    def fit(self, q, v, dt: float, extra=None, holds=None, *, rows: FitRows | None = None) -> "LinearParamH":
        """Ridge least squares of ``v = design(q) w + extra c`` over all segments (see the module docstring; samples
        with a non-finite ``v`` give no row);
        records longer than :data:`MAX_FIT_ROWS` samples in all are fitted on every k-th sample. ``holds``
        (:class:`~selfsense.hysteresis.models.holds.HoldSet`) adds the reference-free hold rows of every trial.
        ``rows``: the stacked rows of exactly these arguments, already built for a model of the same kind and
        parameters (:class:`FitRows`, kept by the blocked CV of the model selection), used instead of building
        them again -- the same matrix, so the same coefficients bit for bit."""
        qs, vs = _segments(q, v)
        self.prepare(qs, dt)
        k = fit_stride([len(x) for x in qs])
        n_hx = holds.n_extra() if holds else 0   # hold-only columns (drift while identified), not part of the model
        if rows is not None:
            n_cal = sum((len(x) + k - 1) // k for x in qs)
            if (rows.X.shape[0] != n_cal + rows.n_hold or rows.y.size != rows.X.shape[0]
                    or rows.X.shape[1] != self.n_columns() + rows.n_extra + n_hx):
                raise ValueError(f"{type(self).__name__}.fit: rows of shape {rows.X.shape} are not those of these "
                                 f"{n_cal} calibration rows")
        else:
            rows = fit_rows(self, qs, vs, dt, extra, holds)
        X, y, pen, n_hold, nE = rows.X, rows.y, rows.penalised, rows.n_hold, rows.n_extra
        ok = np.isfinite(y)   # a sample whose target is not observed gives no row (its charge still drives the operators)
        if not ok.all():
            X, y = X[ok], y[ok]
        coef = ridge_lstsq(X, y, pen, self.ridge, lower=self._bounds(X.shape[1]))
        resid = X @ coef - y
        coef = coef[:len(coef) - n_hx]
        self.coef_ = coef[:len(coef) - nE]
        self.extra_coef_ = coef[len(coef) - nE:]
        self.fit_report_ = {"rms_v": float(np.sqrt(np.mean(resid**2))), "n_samples": int(len(y)), "row_stride": k,
                            "n_hold_rows": int(n_hold),
                            "n_parameters": int(X.shape[1]), "solver": "pivoted-QR least squares (ridge)"}
        return self

    def initial_state(self) -> dict:
        """The relaxed state (streaming, see the module docstring): the hysteretic basis' memory and the creep
        filters' states."""
        n = len(self.creep_tau_s) if self.creep and self.creep_tau_s else 0
        return {"basis": self._basis_state(), "creep": np.zeros(n)}

    def _basis_state(self):
        return None

    def predict(self, q, dt: float | None = None, state: dict | None = None) -> np.ndarray:
        """H [V] from the relaxed state, or from ``state`` (:meth:`initial_state`, updated in place), at sample
        time ``dt`` [s] (default ``dt_``). Computed term by term without building the design matrix: memory
        O(len(q)), whatever the number of basis functions."""
        if self.coef_ is None:
            raise RuntimeError(f"{type(self).__name__}.predict called before fit()")
        dt = self.dt_ if dt is None else float(dt)
        st = self.initial_state() if state is None else state
        u = self._u(q)
        c = self.coef_
        nb = len(c) - 2 - (len(self.creep_tau_s) if self.creep and self.creep_tau_s else 0)
        y = self._basis_dot(u, c[:nb], st["basis"]) + c[nb] * u
        if self.creep and self.creep_tau_s:
            y = y + relaxation_output(u, dt, self.creep_tau_s, c[nb + 1:nb + 1 + len(self.creep_tau_s)], st["creep"])
        return y + c[-1]

    def _basis_dot(self, u: np.ndarray, w: np.ndarray, state=None) -> np.ndarray:
        """``basis(u) @ w`` from the basis memory ``state`` (:meth:`_basis_state`, updated in place); subclasses
        compute it without the full basis. The base class has no hysteretic basis."""
        if len(w):
            raise NotImplementedError(f"{type(self).__name__}: a hysteretic basis needs its own _basis_dot")
        return np.zeros(u.size)

    def __call__(self, q) -> np.ndarray:
        return self.predict(q)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "ridge": self.ridge, "creep": self.creep, "creep_tau_s": list(self.creep_tau_s),
                "params": self._params(), "q_lo": self.q_lo_, "q_span": self.q_span_, "dt": self.dt_,
                "coef": None if self.coef_ is None else [float(c) for c in self.coef_],
                "extra_coef": [float(c) for c in self.extra_coef_], "fitted": self._fitted_state()}

    def _bounds(self, n_cols: int):
        return None

    def _fitted_state(self) -> dict:
        return {}

    def _load_fitted(self, d: Mapping[str, Any]) -> None:
        pass

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "LinearParamH":
        m = cls(ridge=d["ridge"], creep=d["creep"], creep_tau_s=d["creep_tau_s"], **dict(d.get("params", {})))
        m.q_lo_, m.q_span_, m.dt_ = float(d["q_lo"]), float(d["q_span"]), float(d["dt"])
        m.coef_ = None if d.get("coef") is None else np.asarray(d["coef"], dtype=float)
        m.extra_coef_ = np.asarray(d.get("extra_coef", []), dtype=float)
        m._load_fitted(d.get("fitted", {}))
        if m.coef_ is not None:
            n_creep = len(m.creep_tau_s) if m.creep and m.creep_tau_s else 0
            want = m._n_basis() + 1 + n_creep + 1
            if m.coef_.shape != (want,) or not np.all(np.isfinite(m.coef_)):
                raise ValueError(f"H model {m.kind}: coef must hold {want} finite values ({m._n_basis()} basis, 1 linear, "
                                 f"{n_creep} creep, 1 offset), found shape {m.coef_.shape}")
        return m

    def _n_basis(self) -> int:
        """Number of hysteretic basis columns (coefficients before the linear term)."""
        return 0

    def label(self) -> str:
        extra = ", ".join(f"{k}={v}" for k, v in self._params().items())
        return f"{self.kind}({extra}{', ' if extra else ''}ridge={self.ridge:g}{', creep' if self.creep else ''})"


def stacked_extra(extras, qs, stride: int) -> np.ndarray | None:
    """The extra columns of every ``stride``-th sample of every segment, stacked (``extras``: one array per segment
    of ``qs``, or None)."""
    if extras is None:
        return None
    return np.vstack([np.asarray(e, dtype=float).reshape(len(q), -1)[::stride] for e, q in zip(extras, qs)])


def stacked_rows(model: LinearParamH, qs, dt: float, stride: int, E: np.ndarray | None = None,
                 tail: np.ndarray | None = None):
    """``(X, penalised)``: ``[design | E]`` of every ``stride``-th sample of every segment in ``qs``, stacked (each
    segment's design written into its block of one matrix, no copy per stacking; ``E`` holds the unpenalised extra
    columns of the stacked rows, or is None). ``tail``: rows appended below them (the hold rows,
    :func:`~selfsense.hysteresis.models.holds.hold_design`); its columns beyond ``[design | E]`` are unpenalised and
    zero on the stacked rows."""
    rows = [(len(q) + stride - 1) // stride for q in qs]
    p, ne = model.n_columns(), (0 if E is None else E.shape[1])
    nt = 0 if tail is None else tail.shape[0]
    nx = 0 if tail is None else tail.shape[1] - p - ne
    X = np.empty((sum(rows) + nt, p + ne + nx))
    pen, r0 = np.zeros(p, bool), 0
    for q, n in zip(qs, rows):
        _, pen = model.design(q, dt, stride, out=X[r0:r0 + n])
        r0 += n
    if ne:
        X[:r0, p:p + ne] = E
    if nx:
        X[:r0, p + ne:] = 0.0
    if nt:
        X[r0:] = tail
    return X, np.concatenate([pen, np.zeros(ne + nx, bool)])


def fit_rows(model, q, v, dt: float, extra=None, holds=None) -> FitRows:
    """The stacked least-squares rows of :meth:`LinearParamH.fit` with the same arguments: ``[design | extra |
    hold-only columns]`` of every ``k``-th sample of every segment (:func:`fit_stride`), then the hold rows
    (:func:`~selfsense.hysteresis.models.holds.hold_design`), and their targets. ``model``: anything with
    ``n_columns`` and ``design`` (a :class:`LinearParamH`, or a model linear in its parameters), prepared on ``q``.
    The blocked CV of the model selection builds its rows with it too, so that the selected model's final fit can
    take them as they are (``LinearParamH.fit(..., rows=...)``)."""
    qs, vs = _segments(q, v)
    k = fit_stride([len(x) for x in qs])
    y = np.concatenate([w[::k] for w in vs])
    E = None
    if extra is not None:
        if not isinstance(extra, (list, tuple)):   # stacked rows of all segments -> one array per segment
            stacked = np.asarray(extra, dtype=float).reshape(sum(len(x) for x in qs), -1)
            extra = np.split(stacked, np.cumsum([len(x) for x in qs])[:-1])
        E = stacked_extra(extra, qs, k)
    n_hold = 0
    Xh, hid = None, np.zeros(0, int)
    if holds:
        from .holds import hold_design

        Xh, yh, hid = hold_design(model, holds, dt, len(y), model.n_columns() + (0 if E is None else E.shape[1]))
        y, n_hold = np.concatenate([y, yh]), len(yh)
    X, pen = stacked_rows(model, qs, dt, k, E, tail=Xh)
    return FitRows(X, y, pen, n_hold, 0 if E is None else E.shape[1], hid)


def ridge_lstsq(X: np.ndarray, y: np.ndarray, penalised: np.ndarray, ridge: float, lower=None, *,
                reduced: tuple[int, np.ndarray] | None = None) -> np.ndarray:
    """``argmin |X w - y|^2 + ridge N |D w|^2`` with ``D`` selecting the penalised columns of the column-scaled X,
    solved by a pivoted-QR least-squares solve of the augmented matrix (well-conditioned factor, no normal
    equations); tall rows are first reduced to their triangular factor (:func:`qr_reduce`, the same minimiser).

    ``reduced = (N, column sums of squares)``: ``X, y`` are not the rows themselves but an orthogonal reduction of
    them (``R`` and ``Q^T y`` of a QR factorisation of ``[X_rows | y_rows]``, possibly stacked over row blocks,
    see :func:`qr_reduce`), which has the same minimiser; ``N`` and the column sums of squares are those of the
    rows, so that the ridge weight and the column scaling are the same as for the rows."""
    if reduced is None and X.shape[0] > max(4 * X.shape[1], QR_MIN_ROWS):
        # tall rows: reduced to their triangular factor first (blocked, see qr_reduce), the same minimiser; the
        # pivoted QR below then runs on p + 1 rows instead of all of them (5020 x 93, the leakage search's in-sample
        # rows on tweezer_sim: 27 instead of 147 ms, one thread)
        R, n, ss = qr_reduce(X, y)
        p = X.shape[1]
        return ridge_lstsq(R[:, :p], R[:, p], penalised, ridge, lower, reduced=(n, ss))
    if reduced is None:
        N = X.shape[0]
        s = np.sqrt(np.mean(X**2, axis=0))
    else:
        N = int(reduced[0])
        s = np.sqrt(np.asarray(reduced[1], float) / N)
    s[~(s > 0)] = 1.0
    Xs = X / s
    idx = np.flatnonzero(penalised)
    if ridge > 0 and idx.size:
        R = np.zeros((idx.size, X.shape[1]))
        R[np.arange(idx.size), idx] = np.sqrt(ridge * N)
        A = np.vstack([Xs, R])
        b = np.concatenate([y, np.zeros(idx.size)])
    else:
        A, b = Xs, y
    if lower is not None:
        from scipy.optimize import lsq_linear

        # bounded least squares (trust-region reflective on the same augmented, column-scaled matrix)
        return lsq_linear(A, b, bounds=(np.asarray(lower, float) * 1.0, np.inf), method="trf",
                          lsmr_tol="auto").x / s
    from scipy.linalg import lstsq

    # complete orthogonal factorisation (QR with column pivoting, LAPACK gelsy): rank-revealing like an SVD,
    # several times faster, and never forms X^T X
    w, *_ = lstsq(A, b, lapack_driver="gelsy", check_finite=False)
    return w / s


QR_BLOCK_ROWS = 4096
"""Row block of :func:`qr_reduce`'s tall-skinny QR: each block is factored on its own and the stacked factors
once more (the same triangular factor up to row signs as one Householder QR of all rows, 3x faster on 10^5 x 150)."""


QR_MIN_ROWS = 256
"""Rows above which (and above 4 rows per column) :func:`ridge_lstsq` reduces its rows by :func:`qr_reduce` before
the pivoted QR: below it the two cost about the same."""


def qr_reduce(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, int, np.ndarray]:
    """Orthogonal reduction of the least-squares rows ``[X | y]``: ``(R, n, column sums of squares of X)`` with
    ``R`` the triangular factor of ``[X | y]`` (at most ``p + 1`` rows). ``|X w - y|^2 = |R[:, :p] w - R[:, p]|^2 +
    const`` for every ``w``, and the factors of disjoint row blocks stack: the blocked CV of
    :func:`selfsense.hysteresis.models.select.cv_candidate` factors each held-out block once and solves every fold on
    the stacked factors of its training blocks (the same minimiser as on the rows, a few times faster)."""
    n, b = X.shape[0], QR_BLOCK_ROWS
    if n <= 2 * b:
        A = np.column_stack([X, y])
        R = _qr_r(A) if n else np.zeros((0, A.shape[1]))
    else:
        # tall-skinny QR: one factor per row block (cache-sized panels), then the factor of the stacked factors
        R = _qr_r(np.vstack([_qr_r(np.column_stack([X[i:i + b], y[i:i + b]])) for i in range(0, n, b)]))
    return R, int(n), np.einsum("ij,ij->j", X, X)


QR_PANEL = 32
"""Panel width of :func:`_qr_r`'s blocked Householder QR (LAPACK ``dgeqrt``, compact WY): 32 was the fastest of
16-250 on 4096-8192 x 150-250 rows, one BLAS thread."""


def _qr_r(A: np.ndarray) -> np.ndarray:
    """The triangular factor ``R`` (``min(n, p) x p``) of a Householder QR of ``A``, as ``np.linalg.qr(A, "r")``
    gives it, up to rounding (the same reflectors, so the same signs; relative difference ~5e-16 on 4096 x 150-250).
    LAPACK ``dgeqrt`` (blocked, the compact WY form of each panel) instead of ``dgeqrf``: 2.0x faster on the tall
    blocks of :func:`qr_reduce` with OpenBLAS (4096 x 150: 20 against 42 ms, one thread)."""
    from scipy.linalg import lapack

    n, p = A.shape
    k = min(n, p)
    if k == 0:
        return np.zeros((0, p))
    a, _, info = lapack.dgeqrt(min(QR_PANEL, k), np.array(A, dtype=float, order="F"), overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"QR factorisation failed (LAPACK dgeqrt info {info})")
    return np.triu(a[:k])


class LinearH(LinearParamH):
    """Baseline ``H = a q + b`` (no hysteresis, no creep): the straight line every fit must beat."""

    kind = "linear"

    def __init__(self, ridge: float = 0.0, creep: bool = False, creep_tau_s: Sequence[float] = ()):
        super().__init__(ridge=ridge, creep=False, creep_tau_s=())


class PlayH(LinearParamH):
    """Prandtl-Ishlinskii operator with *signed* weights (thesis eqs. 29-33 without the sign constraints 68-75):
    ``H = sum_i w_i P_{r_i}[u] + w_0 u + creep + b``, thresholds ``r_i = i / n_play`` (u units: up to the whole
    calibration range, so that one-sided, virgin-curve plays are included),
    plays starting at z = 0 (the relaxed state). Signed weights make steepening and saturating loops alike."""

    kind = "pi"

    def __init__(self, n_play: int = 10, ridge: float = 1e-6, creep: bool = True,
                 creep_tau_s: Sequence[float] = DEFAULT_CREEP_TAU_S, nonneg: bool = False):
        super().__init__(ridge, creep, creep_tau_s)
        if int(n_play) < 1:
            raise ValueError(f"PlayH: n_play must be >= 1, got {n_play!r}")
        self.n_play = int(n_play)
        self.nonneg = bool(nonneg)

    def _params(self) -> dict:
        return {"n_play": self.n_play, "nonneg": self.nonneg} if self.nonneg else {"n_play": self.n_play}

    def _bounds(self, n_cols: int):
        """Non-negative play weights (thesis constraints 68-73) when ``nonneg``; the linear, creep, offset and extra
        columns stay free. Non-negative weights extrapolate monotonically beyond the identified input range."""
        if not self.nonneg:
            return None
        lo = np.full(n_cols, -np.inf)
        lo[:self.n_play] = 0.0
        return lo

    def _play_thresholds(self) -> np.ndarray:
        """The plays' thresholds ``r_i = i / n_play``."""
        return np.arange(1, self.n_play + 1) / self.n_play

    def _basis(self, u, stride=1):
        return play_features(np.ascontiguousarray(u, dtype=float), self._play_thresholds(), int(stride))

    def _basis_state(self):
        return np.zeros(self.n_play)

    def _n_basis(self) -> int:
        return self.n_play

    def _basis_dot(self, u, w, state=None):
        return play_output(u, self._play_thresholds(), w, state)


class PreisachH(LinearParamH):
    """Preisach operator with a density constant on the cells of an ``n_grid`` x ``n_grid`` triangular grid of the
    (alpha, beta) plane over the calibration charge range (Mayergoyz; ``_grid.preisach_grid_features``), signed
    cell weights, ridge-regularised: the general rate-independent model with wiping-out and congruent minor loops,
    of which the PI operator is the special case of a density depending on alpha - beta only. ``n_play``: plays near
    the diagonal (:meth:`_basis`). ``n_rev``: the reversible part (Mayergoyz, ch. 1: a density on the line alpha =
    beta is a function of the input alone), ramps ``max(u - i / n_rev, 0)`` of the normalised charge, i = 1 .. n_rev
    - 1 (:func:`~selfsense.hysteresis.models._grid.reversible_features`), so that with the linear column the model
    adds any continuous piecewise-linear function of the charge with those knots: a steep anhysteretic rise that the
    cell grid resolves only at its cell size and with its cells' hysteresis (docs/method.md 6b)."""

    kind = "preisach"

    def __init__(self, n_grid: int = 12, n_play: int = 0, ridge: float = 1e-6, creep: bool = True,
                 creep_tau_s: Sequence[float] = DEFAULT_CREEP_TAU_S, nonneg: bool = False, n_rev: int = 0):
        super().__init__(ridge, creep, creep_tau_s)
        if int(n_grid) < 2:
            raise ValueError(f"PreisachH: n_grid must be >= 2, got {n_grid!r}")
        if int(n_play) < 0:
            raise ValueError(f"PreisachH: n_play must be >= 0, got {n_play!r}")
        if int(n_rev) < 0 or int(n_rev) == 1:
            raise ValueError(f"PreisachH: n_rev must be 0 or >= 2, got {n_rev!r}")
        self.n_grid = int(n_grid)
        self.n_play = int(n_play)
        self.n_rev = int(n_rev)
        self.nonneg = bool(nonneg)

    def _params(self) -> dict:
        p = {"n_grid": self.n_grid, "n_play": self.n_play}
        if self.n_rev:
            p["n_rev"] = self.n_rev
        return {**p, "nonneg": True} if self.nonneg else p

    def _rev_knots(self) -> np.ndarray:
        """The reversible part's knots ``k_i = i / n_rev``, i = 1 .. n_rev - 1 (:meth:`_basis`)."""
        return np.arange(1, self.n_rev) / self.n_rev if self.n_rev else np.zeros(0)

    def _bounds(self, n_cols: int):
        """Non-negative Preisach density (cell and play weights) when ``nonneg``: every hysteron adds to the output
        when it switches up, a counter-clockwise loop with rising branches (a magnet's B(I), a stack's x(V)); the
        linear, creep, offset and extra columns stay free."""
        if not self.nonneg:
            return None
        lo = np.full(n_cols, -np.inf)
        lo[:self.n_grid * (self.n_grid + 1) // 2 + self.n_play] = 0.0
        return lo

    def _basis(self, u, stride=1):
        """Grid cells plus, with ``n_play`` > 0, play operators (thresholds up to 0.5): a density concentrated
        near the diagonal alpha = beta, which makes the slope jump at a reversal (saturating Bouc-Wen-type loops)
        that cell-constant densities cannot."""
        F = np.empty(((len(u) + int(stride) - 1) // int(stride), self._n_basis()))
        self._basis_into(u, stride, F)
        return F

    def _play_thresholds(self) -> np.ndarray:
        """The plays' thresholds ``r_i = 0.5 i / n_play`` (:meth:`_basis`)."""
        return np.arange(1, self.n_play + 1) / self.n_play * 0.5

    def _basis_into(self, u, stride, out):
        u = np.ascontiguousarray(u, dtype=float)
        nc = self.n_grid * (self.n_grid + 1) // 2
        preisach_grid_features(u, 0.0, 1.0, self.n_grid, int(stride), out=out[:, :nc])
        if self.n_play:
            r = self._play_thresholds()
            out[:, nc:nc + self.n_play] = play_features(u, r, int(stride))
        if self.n_rev:
            out[:, nc + self.n_play:] = reversible_features(u[::int(stride)], self._rev_knots())

    def _basis_rows_into(self, u, stride, rows, out):
        """The grid features of the rows asked for only (:func:`~selfsense.hysteresis.models._grid.preisach_grid_rows`:
        the state runs over every sample, the cells are integrated and written at those rows), bit for bit those of
        :meth:`_basis_into`; the plays taken at the rows."""
        u = np.ascontiguousarray(u, dtype=float)
        nc = self.n_grid * (self.n_grid + 1) // 2
        preisach_grid_rows(u, 0.0, 1.0, self.n_grid, int(stride), rows, out=out[:, :nc])
        if self.n_play:
            r = self._play_thresholds()
            out[:, nc:nc + self.n_play] = play_features(u, r, int(stride))[rows]
        if self.n_rev:
            out[:, nc + self.n_play:] = reversible_features(u[::int(stride)][rows], self._rev_knots())

    def _basis_state(self):
        return {"grid": grid_state(self.n_grid), "play": np.zeros(self.n_play)}

    def _n_basis(self) -> int:
        return self.n_grid * (self.n_grid + 1) // 2 + self.n_play + max(self.n_rev - 1, 0)

    def _basis_dot(self, u, w, state=None):
        st = self._basis_state() if state is None else state
        u = np.ascontiguousarray(u, dtype=float)
        nc = self.n_grid * (self.n_grid + 1) // 2
        y = preisach_grid_output(u, 0.0, 1.0, self.n_grid, w[:nc], st["grid"])
        if self.n_play:
            r = self._play_thresholds()
            y = y + play_output(u, r, w[nc:nc + self.n_play], st["play"])
        if self.n_rev:
            y = y + reversible_output(u, self._rev_knots(), w[nc + self.n_play:])
        return y


class RIH(LinearParamH):
    """The one-sided rate-independent model of 002_7d89b7147aad52e4.txt (eqs. 8-11, F polynomial (15), G surface
    (16) with G(M, M) = 0) on the normalised charge, plus the relaxation creep bank and a linear term."""

    kind = "ri"

    def __init__(self, ridge: float = 1e-8, creep: bool = True, creep_tau_s: Sequence[float] = DEFAULT_CREEP_TAU_S):
        super().__init__(ridge, creep, creep_tau_s)

    def _basis(self, u, stride=1):
        from selfsense.hysteresis.ri import RIModel, diagonal_constraint_basis

        ri = RIModel(input_scale=1.0)
        Phi = ri.regressor(np.maximum(u, 0.0))[::stride]   # 20 columns at full rate, then thinned
        return np.column_stack([Phi[:, :5], Phi[:, 5:] @ diagonal_constraint_basis()])

    def _basis_state(self):
        return {"ri": None}   # the RIState of the extrema memory (None: virgin)

    def _n_basis(self) -> int:
        from selfsense.hysteresis.ri import diagonal_constraint_basis

        return 5 + diagonal_constraint_basis().shape[1]

    def _basis_dot(self, u, w, state=None):
        from selfsense.hysteresis.ri import RIModel, diagonal_constraint_basis

        ri = RIModel(b=w[:5], p=diagonal_constraint_basis() @ w[5:], input_scale=1.0)
        y, after = ri.apply(np.maximum(u, 0.0), None if state is None else state["ri"])
        if state is not None:
            state["ri"] = after
        return np.asarray(y, dtype=float)


class ModifiedPIH:
    """Kuhnen's modified Prandtl-Ishlinskii operator with creep (thesis eqs. 36-43), identified as the QP of thesis
    App. A (eqs. 60-80, ``selfsense.hysteresis.identify.fit_modified_pi``), with the sign and linear gauge built in:

    ``H(q) = sign * (G[q] - c q)``, ``G`` fitted to ``sign * v + c q``.

    Play operators with non-negative weights only make counter-clockwise loops with rising branches; a piezo's H(q)
    in the thesis eq. (55) convention runs clockwise and falls with q. ``sign`` is the loop orientation of the data
    (shoelace area) and ``c = 2 max(0, -slope)`` makes the target rise: an exact reparametrisation undone on
    evaluation. The QP tries the configured solver, then the other installed QP solvers, when one fails or raises.
    """

    kind = "modified_pi"

    def __init__(self, n_play: int = 15, n_sup: int = 15, creep: bool = True, n_creep: int | str = "auto",
                 solver: str = "CLARABEL", fit_z0: bool = False, ridge: float = 0.0):
        self.n_play, self.n_sup, self.creep, self.n_creep = int(n_play), int(n_sup), bool(creep), n_creep
        self.solver, self.fit_z0, self.ridge = str(solver), bool(fit_z0), float(ridge)
        self.inner_ = None
        self.sign_, self.c_ = 1.0, 0.0
        self.dt_ = float("nan")
        self.fit_report_: dict = {}
        self.extra_coef_ = np.zeros(0)

    def fit_masked(self, q, v, dt: float, row_mask) -> "ModifiedPIH":
        """Fit with only the samples of ``row_mask`` in the QP objective (blocked cross-validation)."""
        return self.fit(q, v, dt, row_mask=row_mask)

    def fit(self, q, v, dt: float, extra=None, row_mask=None) -> "ModifiedPIH":
        from selfsense.hysteresis.identify import fit_modified_pi_robust

        if extra is not None:
            raise ValueError("modified_pi: the QP model takes no extra columns (it is not linear in its parameters)")
        qs, vs = _segments(q, v)
        Q = np.concatenate(qs) if len(qs) == 1 else qs[0]
        y = np.concatenate(vs) if len(vs) == 1 else vs[0]
        n_creep = self.n_creep
        if n_creep == "auto":   # slowest eigenvalue 1 / (10^(m-1) T_s) reaches the record's duration (thesis eq. 40)
            n_creep = int(np.ceil(np.log10(max(len(Q), 1.0)))) + 1
        sign = loop_orientation(Q, y)
        ys = sign * y
        dq = Q - Q.mean()
        slope = float(np.dot(dq, ys - ys.mean()) / max(np.dot(dq, dq), 1e-300))
        c = 2.0 * max(0.0, -slope)
        self.inner_, rep = fit_modified_pi_robust(Q, ys + c * Q, dt, n_play=self.n_play, n_sup=self.n_sup,
                                                  n_creep=int(n_creep), creep=self.creep and int(n_creep) > 0,
                                                  solver=self.solver, fit_z0=self.fit_z0, row_mask=row_mask)
        self.sign_, self.c_, self.dt_ = float(sign), float(c), float(dt)
        pred = self.predict(Q)
        keep = np.ones(len(Q), bool) if row_mask is None else np.asarray(row_mask, bool)
        rms = float(np.sqrt(np.mean((pred - y)[keep] ** 2)))
        lin = LinearH().fit(Q[keep], y[keep], dt)
        rms_lin = float(np.sqrt(np.mean((lin.predict(Q[keep]) - y[keep]) ** 2)))
        rng = float(np.ptp(y[keep])) or 1.0
        self.fit_report_ = dict(rep)
        self.fit_report_.update({"rms_v": rms, "rms_v_linear": rms_lin, "gauge_sign": self.sign_,
                                 "gauge_c": self.c_, "n_creep": int(n_creep), "n_samples": int(len(y)),
                                 "rms_pct": rms / rng * 100,
                                 "max_pct": float(np.max(np.abs(pred - y)[keep])) / rng * 100})
        if not rms < rms_lin:   # the model stays fitted (the thesis identification keeps it and says so)
            raise DegenerateFitError(
                f"modified PI: the QP returned status {rep.get('status')!r} for a fit worse than a straight line "
                f"({rms:.4g} V RMS vs {rms_lin:.4g} V, in sample): a degenerate fit")
        return self

    def initial_state(self) -> dict:
        """The operator's initial state (streaming: see the module docstring)."""
        return {"pi": None, "inner": None}

    def predict(self, q, dt: float | None = None, state: dict | None = None) -> np.ndarray:
        if self.inner_ is None:
            raise RuntimeError("ModifiedPIH.predict called before fit()")
        q = np.asarray(q, dtype=float)
        inner = self.inner_
        if dt is not None and float(dt) != inner.dt:
            if state is not None and state["inner"] is not None and state["inner"].dt == float(dt):
                inner = state["inner"]   # discretised once per stream
            else:
                inner = inner.with_dt(float(dt))
        g, after = inner.apply(q, None if state is None else state["pi"])
        if state is not None:
            state["pi"], state["inner"] = after, inner
        return self.sign_ * (np.asarray(g, dtype=float) - self.c_ * q)

    def __call__(self, q) -> np.ndarray:
        return self.predict(q)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "params": {"n_play": self.n_play, "n_sup": self.n_sup, "creep": self.creep,
                                              "n_creep": self.n_creep, "solver": self.solver, "fit_z0": self.fit_z0},
                "sign": self.sign_, "c": self.c_, "dt": self.dt_,
                "inner": None if self.inner_ is None else self.inner_.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ModifiedPIH":
        from selfsense.hysteresis.pi import ModifiedPI

        m = cls(**dict(d.get("params", {})))
        m.sign_, m.c_, m.dt_ = float(d["sign"]), float(d["c"]), float(d["dt"])
        m.inner_ = None if d.get("inner") is None else ModifiedPI.from_dict(d["inner"])
        return m

    def label(self) -> str:
        return f"modified_pi(n_play={self.n_play}, n_sup={self.n_sup}{', creep' if self.creep else ''})"


def loop_orientation(x, y) -> float:
    """+1 if the (x, y) loops run counter-clockwise overall (shoelace signed area > 0), else -1."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    area = 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))
    return 1.0 if area >= 0 else -1.0


from .duhem import DuhemH  # noqa: E402  (uses the helpers above)

REGISTRY: dict[str, type] = {c.kind: c for c in (LinearH, PlayH, PreisachH, RIH, ModifiedPIH, DuhemH)}


def make_model(kind: str, **kw):
    """A fresh model of registry ``kind`` with hyper-parameters ``kw``."""
    if kind not in REGISTRY:
        raise ValueError(f"unknown H model kind {kind!r}; expected one of {sorted(REGISTRY)}")
    return REGISTRY[kind](**kw)


def searches_holds(cand) -> bool:
    """Whether the registry form ``cand = (kind, params)`` fits its map to the hold rows as well (a parameter of its
    class's ``hold_search_params`` set, e.g. the Duhem map's joint hold search ``hold_nfev``)."""
    kind, params = cand
    return any(params.get(n) for n in getattr(REGISTRY.get(kind), "hold_search_params", ()))


def without_hold_search(cand) -> tuple[str, dict]:
    """The form ``cand = (kind, params)`` without its class's hold-search parameters: the twin it is fitted as where
    no trial has a hold (the same form for a class without such parameters)."""
    kind, params = cand
    drop = getattr(REGISTRY.get(kind), "hold_search_params", ())
    return kind, {n: v for n, v in params.items() if n not in drop}


def h_from_dict(d: Mapping[str, Any]):
    """Any registered H model from its ``to_dict()``."""
    kind = d.get("kind")
    if kind not in REGISTRY:
        raise ValueError(f"H model: unknown kind {kind!r}; expected one of {sorted(REGISTRY)}")
    return REGISTRY[kind].from_dict(d)
