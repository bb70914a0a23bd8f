"""Reference-free hold rows of the H(q) identification: the creep that the calibration trials never excite.

During a hold of the drive (V constant, relay open) the charge still moves: H(q, t) relaxes (the creep part of the
modified PI operator, thesis 000_18d138f03f1777c3.txt eq. 29-31; Kuhnen's creep operators) and the piezo voltage
V_p = V - H follows it. With the free-tip gauge of the H calibration (thesis eq. 55: V_p = Q / (n_A C_p), H target
``V - slope Q``), the change of H since the first sample of a hold is

    H(q_i, t_i) - H(q_a, t_a) = (V_i - V_a) - slope (Q_i - Q_a)

exactly on a free tip, and within the electromechanical coupling factor k^2 of it under a load (the force that the
tip's own creep changes adds d dF to the charge). These rows need V and Q only -- no reference -- so every trial's
holds can enter the fit, whatever its tip does; validation *references* are never read. A sine-only calibration
(the thesis protocol) has no hold, and a creep bank fitted on sines alone extrapolates into holds with any sign
(measured: benchmarks/hold_rows.py).

The rows are differences within a hold, so only the time-dependent part of H is constrained, never its level. Each
row counts as one calibration sample: the rows are thinned to keep their number at most that of the calibration rows,
and weighted by the square root of the thinning ratio (the weighted sum of squares is then that of every hold
sample at weight 1).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["HoldSet", "difference_rows", "hold_design", "hold_residual"]


@dataclass
class HoldSet:
    """Hold rows of every trial: the full record of each trial with holds (relay segment excluded, from the relaxed
    state), its H target ``V - slope Q`` and its holds ``[(a, b), ...]`` (index ranges of the record)."""

    qs: list = field(default_factory=list)
    ys: list = field(default_factory=list)
    holds: list = field(default_factory=list)
    names: list = field(default_factory=list)
    #: per trial, columns ``(N, k)`` fitted jointly on that trial's hold rows only (the offset-drift ramp ``t, t^2``
    #: of the charge while the drift member is being identified), or None
    extras: list | None = None

    def __bool__(self) -> bool:
        return any(len(h) for h in self.holds)

    def n_extra(self) -> int:
        """Number of hold-only columns (block-diagonal over trials)."""
        return int(sum(0 if e is None else np.asarray(e).reshape(len(q), -1).shape[1]
                       for e, q in zip(self.extras, self.qs))) if self.extras else 0

    def _extra_offsets(self) -> list[int]:
        out, o = [], 0
        for e, q in zip(self.extras or [None] * len(self.qs), self.qs):
            out.append(o)
            o += 0 if e is None else np.asarray(e).reshape(len(q), -1).shape[1]
        return out

    def extra_rows(self, i: int, idx: np.ndarray, a0: int) -> np.ndarray:
        """Differences of trial ``i``'s hold-only columns at rows ``idx`` since row ``a0``, placed in the
        block-diagonal layout of :meth:`n_extra` columns."""
        out = np.zeros((idx.size, self.n_extra()))
        if self.extras and self.extras[i] is not None:
            E = np.asarray(self.extras[i], float).reshape(len(self.qs[i]), -1)
            o = self._extra_offsets()[i]
            out[:, o:o + E.shape[1]] = E[idx] - E[a0]
        return out

    def n_samples(self) -> int:
        return int(sum(max(b - a - 1, 0) for hs in self.holds for a, b in hs))

    def rows(self, stride: int) -> list[tuple[int, np.ndarray, int, int]]:
        """``(trial index, row indices, hold's first index, hold number)`` per hold: every ``stride``-th sample after
        the hold's first one, on the grid ``0, stride, 2 stride, ...`` of the record (that of ``design(q, dt,
        stride)``); the hold number counts every hold of the set in order (the CV folds are made from it)."""
        out, h = [], 0
        for i, hs in enumerate(self.holds):
            for a, b in hs:
                a0 = -(-a // stride) * stride   # first grid sample in the hold
                idx = np.arange(a0 + stride, b, stride)
                if idx.size:
                    out.append((i, idx, a0, h))
                h += 1
        return out

    def subset(self, keep) -> "HoldSet":
        """The holds whose number (see :meth:`rows`) satisfies ``keep(number)``."""
        out, h = HoldSet(extras=[] if self.extras else None), 0
        for i, (q, y, hs, name) in enumerate(zip(self.qs, self.ys, self.holds, self.names)):
            kept = []
            for ab in hs:
                if keep(h):
                    kept.append(ab)
                h += 1
            if kept:
                out.qs.append(q); out.ys.append(y); out.holds.append(kept); out.names.append(name)
                if self.extras:
                    out.extras.append(self.extras[i])
        return out

    def summary(self) -> dict:
        return {"n_holds": int(sum(len(h) for h in self.holds)), "trials": list(self.names),
                "n_samples": self.n_samples()}


def _stride_and_weight(holds: HoldSet, n_cal_rows: int) -> tuple[int, float]:
    n = max(holds.n_samples(), 1)
    s = max(1, int(np.ceil(n / max(int(n_cal_rows), 1))))
    return s, float(np.sqrt(s))


def difference_rows(holds: HoldSet, n_cal_rows: int, n_cols: int, per_trial):
    """``(Xh, yh, hold_id)``: the weighted difference rows of every hold, ``w [x_i - x_a | 0 | e_i - e_a]`` and
    ``w ((y_i - y_a) - (p_i - p_a))``. ``per_trial(i, stride)`` gives trial ``i``'s columns ``x`` on the grid
    ``0, stride, ...`` of its record and an output ``p`` already explained on that grid (or None); ``x`` is padded
    with zeros to ``n_cols`` columns (the extra columns of the calibration rows do not act on a hold), then come the
    :meth:`HoldSet.n_extra` hold-only columns ``e``; and the running index of each row's hold (for the CV folds)."""
    s, w = _stride_and_weight(holds, n_cal_rows)
    rows = holds.rows(s)
    n_x = holds.n_extra()
    # one matrix, each hold's rows written into their block (the values of stacking w [D | 0 | e] block by block)
    Xh = np.zeros((sum(idx.size for _, idx, _, _ in rows), n_cols + n_x))
    ys, ids = [], []
    cache = {}
    r0 = 0
    for i, idx, a0, h in rows:
        if i not in cache:
            cache[i] = per_trial(i, s)
        X, p = cache[i]
        y = np.asarray(holds.ys[i], float)
        D = X[idx // s] - X[a0 // s]
        r1 = r0 + idx.size
        np.multiply(w, D, out=Xh[r0:r1, :D.shape[1]])
        if n_x:
            np.multiply(w, holds.extra_rows(i, idx, a0), out=Xh[r0:r1, n_cols:])
        r0 = r1
        dy = y[idx] - y[a0]
        ys.append(w * (dy if p is None else dy - (p[idx // s] - p[a0 // s])))
        ids.append(np.full(idx.size, h))
    if not ys:
        return np.zeros((0, n_cols + n_x)), np.zeros(0), np.zeros(0, int)
    return Xh, np.concatenate(ys), np.concatenate(ids)


class _GridRows:
    """Rows of a trial's design matrix on the grid ``0, stride, ...``, of which only ``rows`` (sorted) were built:
    ``X[j]`` / ``X[index array]`` as the full matrix would answer for those rows."""

    def __init__(self, rows: np.ndarray, X: np.ndarray):
        self.rows, self.X = rows, X

    def __getitem__(self, j):
        return self.X[np.searchsorted(self.rows, j)]


def hold_design(model, holds: HoldSet, dt: float, n_cal_rows: int, n_cols: int):
    """:func:`difference_rows` of a model linear in its parameters
    (:class:`~selfsense.hysteresis.models.LinearParamH`, prepared on the calibration rows): its design matrix, of
    each trial only at the rows the holds read (``design_rows`` where the model has it: the hold rows are about a
    quarter of a record, and the Preisach grid's features cost per row written), the same values."""
    if not hasattr(model, "design_rows"):
        return difference_rows(holds, n_cal_rows, n_cols, lambda i, s: (model.design(holds.qs[i], dt, s)[0], None))

    def per_trial(i, s):
        rows = np.unique(np.concatenate([np.concatenate([idx // s, [a0 // s]])
                                         for j, idx, a0, _ in holds.rows(s) if j == i]))
        return _GridRows(rows, model.design_rows(holds.qs[i], dt, s, rows)), None

    return difference_rows(holds, n_cal_rows, n_cols, per_trial)


def hold_residual(model, holds: HoldSet, dt: float, n_cal_rows: int):
    """``(r, hold_id)``: weighted residual ``w ((H_i - H_a) - (y_i - y_a))`` of any fitted model on every hold row
    (the model predicted over each trial's whole record), and each row's hold index; the same rows and weights as
    :func:`hold_design`. With hold-only columns (:attr:`HoldSet.extras`) the residual is that left after
    regressing them out of each trial's hold residuals."""
    s, w = _stride_and_weight(holds, n_cal_rows)
    rs, ids, Es = [], [], []
    preds = {}
    for i, idx, a0, h in holds.rows(s):
        if i not in preds:
            preds[i] = np.asarray(model.predict(holds.qs[i], dt), float)
        p = preds[i]
        y = np.asarray(holds.ys[i], float)
        rs.append(w * ((p[idx] - p[a0]) - (y[idx] - y[a0])))
        ids.append(np.full(idx.size, h))
        Es.append(holds.extra_rows(i, idx, a0)) if holds.n_extra() else None
    if not rs:
        return np.zeros(0), np.zeros(0, int)
    r = np.concatenate(rs)
    if holds.n_extra():
        E = w * np.vstack(Es)
        c, *_ = np.linalg.lstsq(E, r, rcond=None)
        r = r - E @ c
    return r, np.concatenate(ids)
