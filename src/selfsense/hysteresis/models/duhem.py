"""Generic Duhem (Coleman-Hodgdon) H(q) model: hysteresis whose branch slope depends on the output.

Preisach-class models (PI, Preisach grid, RI) have *congruent* minor loops: between the same two input reversals the
output changes by the same amount whatever the level it starts from. Many materials and devices do not behave so:
in a Duhem model (Coleman & Hodgdon; Visintin, *Differential Models of Hysteresis*, ch. III) the slope of a branch is
a function of the current input *and output*,

    dv/dt = g_+(u, v) du/dt  (du/dt > 0),   dv/dt = g_-(u, v) du/dt  (du/dt < 0),

so a branch that starts higher saturates sooner and minor loops at different levels differ. The class is
rate-independent (dt cancels) and contains the saturating, clockwise and counter-clockwise loops alike. Nothing of
a particular model is assumed: ``g_+`` and ``g_-`` are polynomials of total degree ``degree`` in the normalised input
and output (``_duhem.duhem_terms``), identified from the calibration data.

The H model (same input normalisation, creep bank and joint extra columns as :class:`LinearParamH`,
thesis 000_18d138f03f1777c3.txt eqs. 38-41 for the creep operator):

    H(q) = v[u] + a u + sum_j w_j (u - z_j) + b,   u = (q - q_lo) / q_span,   v = 0 in the relaxed state,

with the linear part ``[creep bank | 1 | u]`` of the models linear in their parameters (the creep weights carry the
model's ridge, as there). Without its own ``u`` column the reversible slope ``a`` has to come from the map or from
the creep columns whose time constants outlast the calibration records (``u - z_j`` is close to ``u`` there): those
took large cancelling weights that fit the sines and diverged in the holds and longer trials (measured on
whole-device Bouc-Wen devices, docs/cross_device.md).

* initial ``g`` by equation error: the increments of the output left after a preliminary PI fit of the linear part
  (creep, offset, linear term, extra columns) regressed on ``phi(u, v) du``, per direction; a second start from
  ``g = 0``;
* refined by output error: ``min_c |P (y - v[u; c])|^2`` with ``P`` the projector on the complement of the
  linear columns (creep, offset, linear term, extra; ridge-augmented for the creep weights) -- variable projection,
  exact because those columns do not depend on c --
  by a trust-region least-squares solver with the exact sensitivities of the discrete map;
* a small ridge on c (relative to the output range) keeps unidentified directions of the polynomial at zero;
* ``hold_nfev > 0`` (a candidate of its own in the selection, ``select.DEFAULT_CANDIDATES``): the reference-free
  hold rows of every trial (:mod:`selfsense.hysteresis.models.holds`) join the output-error search, continued from
  the calibration rows' optimum for ``hold_nfev`` evaluations -- the map and the creep bank identified jointly on
  both. With ``hold_nfev = 0`` the map is fitted on the calibration rows and the holds fit the linear part only; on
  sine-only calibrations the map then keeps the loop width the sines gave the creep, and the holds of the
  mixed-drive trials relax 8-16 % more than their own reference-free target says (docs/method.md 6b'). Whether the
  holds are H's depends on the device (under a tip that creeps they are not), so both variants are candidates and
  the selection's hold folds decide.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from . import DEFAULT_CREEP_TAU_S, DegenerateFitError, _qr_r, _segments, fit_stride, normalise_input, ridge_lstsq
from ._duhem import duhem_run, duhem_state, n_terms
from ._grid import play_features, relaxation_bank, relaxation_output

__all__ = ["DuhemH"]

#: at most this many rows enter the output-error residual (the map still runs over every sample)
MAX_OE_ROWS = 12_000


def _directions(u: np.ndarray, eps: float) -> np.ndarray:
    """Input direction (+1 / -1) of each increment u[k] -> u[k+1], with the kernel's dead band ``eps``."""
    s = np.empty(max(u.size - 1, 0), dtype=np.int8)
    d, ext = 1, u[0]
    for k in range(u.size - 1):
        un = u[k + 1]
        if d > 0:
            if un > ext:
                ext = un
            elif ext - un > eps:
                d, ext = -1, un
        else:
            if un < ext:
                ext = un
            elif un - ext > eps:
                d, ext = 1, un
        s[k] = d
    return s


class DuhemH:
    """Generic Duhem H(q) model (module docstring); registry ``kind = "duhem"``."""

    kind = "duhem"
    #: fitted by a non-convex search: the selection keeps it only where it wins clearly (select.select_h_model)
    convex = False
    #: fits extra columns jointly and accepts a row mask (blocked CV over every segment, ``select._cv_masked``)
    joint_extra = True
    #: constructor parameters that only say how the fit reads the hold rows (:func:`~selfsense.hysteresis.models.
    #: without_hold_search`): without them the form is its map-first twin
    hold_search_params = ("hold_nfev",)

    def __init__(self, degree: int = 3, ridge: float = 1e-7, creep: bool = True,
                 creep_tau_s: Sequence[float] = DEFAULT_CREEP_TAU_S, eps: float = 2e-3, max_nfev: int = 30,
                 creep_ridge: float | None = None, hold_nfev: int = 0):
        if int(degree) < 1:
            raise ValueError(f"DuhemH: degree must be >= 1, got {degree!r}")
        if not float(eps) >= 0:
            raise ValueError(f"DuhemH: eps (direction dead band, normalised input) must be >= 0, got {eps!r}")
        self.degree, self.ridge, self.creep = int(degree), float(ridge), bool(creep)
        self.creep_tau_s = tuple(float(t) for t in creep_tau_s) if self.creep else ()
        self.eps, self.max_nfev = float(eps), int(max_nfev)
        self.creep_ridge = None if creep_ridge is None else float(creep_ridge)
        if int(hold_nfev) < 0:
            raise ValueError(f"DuhemH: hold_nfev (evaluations of the joint hold search) must be >= 0, got {hold_nfev!r}")
        #: evaluations of the joint search on the calibration and hold rows, continued from the calibration rows'
        #: optimum (each runs the map over every hold trial's record); 0: the hold rows fit the linear part only
        self.hold_nfev = int(hold_nfev)
        self.coef_: np.ndarray | None = None
        self.lin_coef_ = np.zeros(0)
        self.extra_coef_ = np.zeros(0)
        self.q_lo_, self.q_span_, self.v_lo_, self.v_span_ = 0.0, 1.0, 0.0, 1.0
        self.dt_ = float("nan")
        self.fit_report_: dict = {}

    # -- helpers ------------------------------------------------------------------------------------------------------
    def _u(self, q) -> np.ndarray:
        return np.ascontiguousarray((np.asarray(q, dtype=float) - self.q_lo_) / self.q_span_)

    def _linear_cols(self, u: np.ndarray, dt: float, stride: int = 1) -> np.ndarray:
        """``[creep bank | 1 | u]`` of one segment, every ``stride``-th row (the filters run over every sample)."""
        cols = [relaxation_bank(u, dt, [t])[::stride] for t in self.creep_tau_s]
        cols.append(np.ones((u[::stride].size, 1)))
        cols.append(u[::stride, None])
        return np.column_stack(cols)

    def _v_bounds(self) -> tuple[float, float]:
        """The map's output clip ``[v_lo - v_span, v_lo + 2 v_span]``."""
        return self.v_lo_ - 1.0 * self.v_span_, self.v_lo_ + 2.0 * self.v_span_

    def _run(self, u, c, stride=1, jac=False, state=None):
        vmin, vmax = self._v_bounds()
        return duhem_run(u, np.ascontiguousarray(c, dtype=float), self.degree, self.v_lo_, self.v_span_, self.eps,
                         vmin, vmax, int(stride), bool(jac), duhem_state() if state is None else state)

    # -- fit ----------------------------------------------------------------------------------------------------------
    def fit(self, q, v, dt: float, extra=None, row_mask=None, holds=None, starts=None) -> "DuhemH":
        """Fit on one or several segments (each from the relaxed state); ``extra``: joint columns (one array per
        segment, or stacked), fitted without penalty; ``row_mask``: rows (one boolean array per segment, or stacked)
        that enter the objective (blocked cross-validation); ``holds``
        (:class:`~selfsense.hysteresis.models.holds.HoldSet`): the reference-free hold rows of every trial join the
        linear part (creep bank, offset) once the Duhem map is fitted, and with ``hold_nfev > 0`` the map's search
        too (module docstring). ``starts``: parameter vectors of earlier fits of the same form (the fold fits of
        the blocked CV, :func:`selfsense.hysteresis.models.select._final_fit`); the one with the lowest objective
        is a third start of the search. Runs with one BLAS thread: the matrices are small (<= MAX_OE_ROWS x a few
        dozen), and threads contending for the cores made it ten times slower."""
        from threadpoolctl import threadpool_limits

        with threadpool_limits(1):
            return self._fit(q, v, dt, extra, row_mask, holds, starts)

    def _hold_rows(self, holds, c, dt: float, n_cal: int, n_cols: int):
        """Weighted hold rows of the linear part: differences of ``[creep bank | 1]`` within each hold and of the
        target minus the fitted Duhem map (:func:`selfsense.hysteresis.models.holds.difference_rows`)."""
        from .holds import difference_rows

        def per_trial(i, s):
            u = self._u(holds.qs[i])
            return self._linear_cols(u, dt, s), self._run(u, c, s)[0]

        return difference_rows(holds, n_cal, n_cols, per_trial)[:2]

    def _hold_map_rows(self, holds, dt: float, n_cal: int, n_cols: int):
        """The hold rows of the joint search: ``(Lh, yh, run)`` with ``Lh`` the weighted differences of the linear
        columns (:meth:`_hold_rows`' layout), ``yh`` those of the target, and ``run(c, want_jac)`` the weighted
        differences of the map's output within each hold and of its sensitivities to ``c`` (the map run over each
        hold trial's record from the relaxed state, read on the rows' grid)."""
        from .holds import _stride_and_weight, difference_rows

        Lh, yh, _ = difference_rows(holds, n_cal, n_cols,
                                    lambda i, s: (self._linear_cols(self._u(holds.qs[i]), dt, s), None))
        s, w = _stride_and_weight(holds, n_cal)
        rows = holds.rows(s)
        us = {i: self._u(holds.qs[i]) for i, _, _, _ in rows}
        take = [(i, idx // s, a0 // s) for i, idx, a0, _ in rows]

        def run(c, want_jac):
            out = {i: self._run(u, c, s, want_jac) for i, u in us.items()}
            V = np.concatenate([w * (out[i][0][j] - out[i][0][j0]) for i, j, j0 in take])
            if not want_jac:
                return V, None
            return V, np.vstack([w * (out[i][1][j] - out[i][1][j0]) for i, j, j0 in take])

        return Lh, yh, run

    def _fit(self, q, v, dt, extra, row_mask, holds=None, starts=None) -> "DuhemH":
        from scipy.optimize import least_squares

        qs, vs = _segments(q, v)
        normalise_input(self, qs, dt)
        lengths = [len(x) for x in qs]
        us = [self._u(x) for x in qs]
        Es = self._split(extra, lengths, "extra")
        masks = self._split(row_mask, lengths, "row_mask")
        masks = [np.ones(L, bool) if m is None else np.asarray(m, bool).reshape(L) for m, L in zip(masks, lengths)]
        # rows of the objective: every k-th sample (the map runs over every sample), within the mask
        k = max(fit_stride(lengths), int(np.ceil(sum(int(m.sum()) for m in masks) / MAX_OE_ROWS)))
        Ls = [self._linear_cols(u, dt, k) if E is None else np.column_stack([self._linear_cols(u, dt, k), E[::k]])
              for u, E in zip(us, Es)]
        nl = Ls[0].shape[1] - (0 if Es[0] is None else Es[0].shape[1])
        rows = [np.flatnonzero(m[::k]) for m in masks]
        y = np.concatenate([vv[::k][r] for vv, r in zip(vs, rows)])
        L = np.vstack([Lm[r] for Lm, r in zip(Ls, rows)])
        if y.size < 4 * (2 * n_terms(self.degree) + L.shape[1]):
            raise DegenerateFitError(f"duhem: {y.size} fit rows are too few for {2 * n_terms(self.degree)} + "
                                     f"{L.shape[1]} parameters")
        # 1. preliminary PI fit of the linear part -> state estimate v_eq = y - L beta on the strided rows
        P = np.vstack([play_features(u, np.arange(1, 11) / 10.0, k)[r] for u, r in zip(us, rows)])
        X0 = np.column_stack([P, L])
        pen = np.concatenate([np.ones(P.shape[1], bool), np.zeros(L.shape[1], bool)])
        b0 = ridge_lstsq(X0, y, pen, 1e-6)[P.shape[1]:]
        v_eq = [vv[::k] - Lm @ b0 for vv, Lm in zip(vs, Ls)]
        both = np.concatenate([ve[m[::k]] for ve, m in zip(v_eq, masks)])
        lo, hi = float(np.min(both)), float(np.max(both))
        if not hi > lo:
            raise DegenerateFitError("duhem: the calibration output does not vary")
        self.v_lo_ = lo - 0.05 * (hi - lo)
        self.v_span_ = 1.1 * (hi - lo)
        c0 = self._equation_error([u[::k] for u in us], v_eq, [m[::k] for m in masks])
        # 2. output error with the linear columns projected out (variable projection); the creep bank's weights
        # carry the ridge of ridge_lstsq (column-scaled, ridge N): the projection is that of the ridge-augmented
        # linear columns, so the projected residual is exactly the ridge-solved linear part's residual
        nc = len(self.creep_tau_s)
        pen = np.zeros(L.shape[1], bool)
        pen[:nc] = True
        cr = self.ridge if self.creep_ridge is None else self.creep_ridge
        nb = 2 * n_terms(self.degree)
        lam = np.sqrt(self.ridge * y.size) * (1.0 / self.v_span_)   # c ~ v_span: relative ridge

        def objective(hl):
            """``(fun, jac, resid)`` of the search on the calibration rows and, with ``hl``
            (:meth:`_hold_map_rows`), the hold rows: the linear columns of both projected out together."""
            Lj, penj, yj = L, pen, y
            if hl is not None:
                Lj = np.vstack([np.column_stack([L, np.zeros((len(L), hl[0].shape[1] - L.shape[1]))]), hl[0]])
                penj = np.concatenate([pen, np.zeros(Lj.shape[1] - L.shape[1], bool)])
                yj = np.concatenate([y, hl[1]])
            La, n_aug = self._ridge_augment(Lj, penj, cr)
            Qf, _ = np.linalg.qr(La)
            zpad = np.zeros(n_aug)

            def resid_jac(c, want_jac):
                Vs, Js = [], []
                for u, r in zip(us, rows):
                    Vk, Jk = self._run(u, c, k, want_jac)
                    Vs.append(Vk[r])
                    if want_jac:
                        Js.append(Jk[r])
                if hl is not None:
                    Vh, Jh = hl[2](c, want_jac)
                    Vs.append(Vh)
                    if want_jac:
                        Js.append(Jh)
                e = np.concatenate([yj - np.concatenate(Vs), zpad])
                e = e - Qf @ (Qf.T @ e)
                if not want_jac:
                    return np.concatenate([e, lam * c]), None
                J = np.vstack([-np.vstack(Js), np.zeros((n_aug, nb))])
                J = J - Qf @ (Qf.T @ J)
                return np.concatenate([e, lam * c]), np.vstack([J, lam * np.eye(nb)])

            # the trust-region loop asks for the Jacobian at the point whose residual it has just evaluated (after
            # each accepted step): the residual is computed together with the sensitivities (the map's run computes
            # V the same way with or without them, so the residual has the same bits) and the Jacobian is kept for
            # that call, instead of running the map over every sample once more.
            # The trust-region steps read the residual f and the Jacobian J only through J^T J, J^T f, J's column
            # norms and |f|^2, so the search runs on their orthogonal reduction: J = Q R, and the residual becomes
            # [Q^T f, |(I - Q Q^T) f|] with the Jacobian [R; 0] -- the same quadratic model, the same cost and
            # gradient, the same column scaling, up to rounding. Each iteration's SVD is then of a (p + 1) x p matrix
            # instead of the rows' (MAX_OE_ROWS x p): a third of the fit's time on the tip campaign's cases.
            kept: list = []

            def fun(c):
                f, J = resid_jac(c, True)
                # the triangular factor of [J | f] holds R, Q^T f and the norm of f's part outside J's range
                Ra = _qr_r(np.column_stack([J, f]))
                p = J.shape[1]
                Rj = np.zeros((p + 1, p))
                Rj[:min(p, Ra.shape[0])] = Ra[:p, :p]
                fc = np.zeros(p + 1)
                fc[:min(p + 1, Ra.shape[0])] = Ra[:p + 1, p]
                kept[:] = [np.array(c, dtype=float), Rj]
                return fc

            def jac(c):
                if not (kept and np.array_equal(kept[0], c)):
                    fun(c)
                J = kept[1]
                kept.clear()
                return J

            return fun, jac, resid_jac

        fun, jac, resid_jac = objective(None)
        # two starts (the equation-error estimate and g = 0, a flat state), and a third where earlier fits of the
        # same form are given (``starts``): the output-error objective has local minima; the lowest one is kept
        first = [c0, np.zeros(nb)]
        given = [np.asarray(c, dtype=float) for c in (starts or ()) if np.shape(c) == (nb,) and np.isfinite(c).all()]
        if given:   # the earlier fit whose parameters fit these rows best, without a search
            first.append(min(given, key=lambda c: float(np.sum(resid_jac(c, False)[0] ** 2))))
        best = None
        for start in first:
            sol = least_squares(fun, start, jac=jac, method="trf", x_scale="jac", max_nfev=self.max_nfev)
            if best is None or sol.cost < best.cost:
                best = sol
        sol = best
        if holds and self.hold_nfev > 0:
            # the hold rows (reference-free, every trial) join the map's objective, from the calibration rows'
            # optimum (continuation): their linear columns (creep bank, offset, hold-only columns) are projected out
            # with the calibration rows', and the map's own change within each hold (q moves while H relaxes) is a
            # residual of the same search -- the map and the creep bank identified jointly on both. With the map
            # fitted on the calibration rows alone and only the creep bank on the holds after it, the map kept the
            # loop width that the sines had given the creep
            fun_h, jac_h, _ = objective(self._hold_map_rows(holds, dt, y.size, L.shape[1]))
            sol_h = least_squares(fun_h, sol.x, jac=jac_h, method="trf", x_scale="jac", max_nfev=self.hold_nfev)
            sol_h.nfev = int(best.nfev + sol_h.nfev)
            sol = sol_h
        c = sol.x
        Vall = np.concatenate([self._run(u, c, k)[0][r] for u, r in zip(us, rows)])
        n_hold = 0
        if holds:
            Lh, rh = self._hold_rows(holds, c, dt, y.size, L.shape[1])
            Lz = np.column_stack([L, np.zeros((len(L), Lh.shape[1] - L.shape[1]))])
            penh = np.concatenate([pen, np.zeros(Lh.shape[1] - L.shape[1], bool)])
            beta = ridge_lstsq(np.vstack([Lz, Lh]), np.concatenate([y - Vall, rh]), penh, cr)
            beta = beta[:L.shape[1]]   # the hold-only columns are not part of the model
            n_hold = len(rh)
        else:
            beta = ridge_lstsq(L, y - Vall, pen, cr)
        self.coef_ = np.asarray(c, float)
        self.lin_coef_ = beta[:nl]
        self.extra_coef_ = beta[nl:]
        res = y - Vall - L @ beta
        self.fit_report_ = {"rms_v": float(np.sqrt(np.mean(res**2))), "n_samples": int(y.size), "row_stride": k,
                            "n_parameters": int(nb + L.shape[1]), "nfev": int(sol.nfev), "status": int(sol.status),
                            "n_hold_rows": int(n_hold),
                            "solver": "variable-projection trust-region least squares (output error)"}
        return self

    @staticmethod
    def _ridge_augment(L: np.ndarray, pen: np.ndarray, ridge: float) -> tuple[np.ndarray, int]:
        """``L`` with the ridge rows of :func:`~selfsense.hysteresis.models.ridge_lstsq` appended (``sqrt(ridge N)``
        on each penalised column, in the column scaling of ``L``'s RMS), and their number."""
        idx = np.flatnonzero(pen)
        if not (ridge > 0 and idx.size):
            return L, 0
        s = np.sqrt(np.mean(L ** 2, axis=0))
        s[~(s > 0)] = 1.0
        R = np.zeros((idx.size, L.shape[1]))
        R[np.arange(idx.size), idx] = np.sqrt(ridge * L.shape[0]) * s[idx]
        return np.vstack([L, R]), int(idx.size)

    @staticmethod
    def _split(a, lengths, name):
        if a is None:
            return [None] * len(lengths)
        if isinstance(a, (list, tuple)):
            if len(a) != len(lengths):
                raise ValueError(f"duhem: {name} has {len(a)} segments, q has {len(lengths)}")
            return [None if x is None else np.asarray(x, float).reshape(L, -1) if name == "extra"
                    else np.asarray(x) for x, L in zip(a, lengths)]
        arr = np.asarray(a)
        arr = arr.reshape(sum(lengths), -1) if name == "extra" else arr.reshape(sum(lengths))
        out = np.split(arr, np.cumsum(lengths)[:-1])
        return [x.astype(float) if name == "extra" else x for x in out]

    def _equation_error(self, us, v_eq, masks) -> np.ndarray:
        """Per-direction least squares of the output increments on ``phi(u, v) du`` (midpoint values, increments of
        ``m`` samples that do not straddle a reversal)."""
        nb = n_terms(self.degree)
        rowsA, rowsb = [], []
        for u, ve, msk in zip(us, v_eq, masks):
            s = _directions(u, self.eps)
            m = max(1, int(u.size // 3000))
            i0 = np.arange(0, u.size - m, m)
            i1 = i0 + m
            ok = msk[i0] & msk[i1]
            # the direction must be the same over the increment
            cs = np.concatenate([[0], np.cumsum(s != 1)])
            same = (cs[i1] - cs[i0] == 0) | (cs[i1] - cs[i0] == m)
            ok &= same
            a, b = i0[ok], i1[ok]
            du = u[b] - u[a]
            a, b, du = a[du != 0], b[du != 0], du[du != 0]
            # all increments at once, each with the operations of duhem_terms in its order (the same bits as one
            # increment at a time): monomials x^i w^j by repeated products
            x = np.minimum(np.maximum(u[a] + u[b] - 1.0, -1.5), 1.5)
            w = np.minimum(np.maximum((ve[a] + ve[b] - 2 * self.v_lo_) / self.v_span_ - 1.0, -1.5), 1.5)
            rows = np.zeros((a.size, 2 * nb))
            asc = s[a] > 0
            col = 0
            xi = np.ones(a.size)
            for i in range(self.degree + 1):
                wj = np.ones(a.size)
                for _ in range(self.degree + 1 - i):
                    t = (xi * wj) * du
                    rows[asc, col] = t[asc]
                    rows[~asc, nb + col] = t[~asc]
                    wj = wj * w
                    col += 1
                xi = xi * x
            rowsA.append(rows)
            rowsb.append(ve[b] - ve[a])
        if sum(len(r) for r in rowsb) < 4 * nb:
            return np.zeros(2 * nb)
        A = np.vstack(rowsA)
        b = np.concatenate(rowsb)
        return ridge_lstsq(A, b, np.ones(A.shape[1], bool), 1e-8)

    # -- evaluation ---------------------------------------------------------------------------------------------------
    def initial_state(self) -> dict:
        """The relaxed state (streaming, see ``selfsense.hysteresis.models``): the map's state and the creep
        filters'."""
        return {"map": duhem_state(), "creep": np.zeros(len(self.creep_tau_s))}

    def predict(self, q, dt: float | None = None, state: dict | None = None) -> np.ndarray:
        """H [V] from the relaxed state, or from ``state`` (:meth:`initial_state`, updated in place), at sample time
        ``dt`` [s] (default ``dt_``; the creep bank's time constants are in seconds, the Duhem map is
        rate-independent)."""
        if self.coef_ is None:
            raise RuntimeError("DuhemH.predict called before fit()")
        dt = self.dt_ if dt is None else float(dt)
        st = self.initial_state() if state is None else state
        u = self._u(q)
        y = self._run(u, self.coef_, state=st["map"])[0]
        nc = len(self.creep_tau_s)
        if nc:
            y = y + relaxation_output(u, dt, self.creep_tau_s, self.lin_coef_[:nc], st["creep"])
        a = self.lin_coef_[nc + 1] if self.lin_coef_.size > nc + 1 else 0.0   # the linear term (0 if absent)
        return y + self.lin_coef_[nc] + a * u

    def __call__(self, q) -> np.ndarray:
        return self.predict(q)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "params": self._params(), "q_lo": self.q_lo_, "q_span": self.q_span_,
                "v_lo": self.v_lo_, "v_span": self.v_span_, "dt": self.dt_,
                "coef": None if self.coef_ is None else [float(x) for x in self.coef_],
                "lin_coef": [float(x) for x in self.lin_coef_], "extra_coef": [float(x) for x in self.extra_coef_]}

    def _params(self) -> dict:
        return {"degree": self.degree, "ridge": self.ridge, "creep": self.creep, "creep_tau_s": list(self.creep_tau_s),
                "eps": self.eps, "max_nfev": self.max_nfev, **({} if self.creep_ridge is None else
                                                               {"creep_ridge": self.creep_ridge}),
                **({"hold_nfev": self.hold_nfev} if self.hold_nfev else {})}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "DuhemH":
        m = cls(**dict(d.get("params", {})))
        m.q_lo_, m.q_span_ = float(d["q_lo"]), float(d["q_span"])
        m.v_lo_, m.v_span_, m.dt_ = float(d["v_lo"]), float(d["v_span"]), float(d["dt"])
        m.coef_ = None if d.get("coef") is None else np.asarray(d["coef"], dtype=float)
        m.lin_coef_ = np.asarray(d.get("lin_coef", []), dtype=float)
        m.extra_coef_ = np.asarray(d.get("extra_coef", []), dtype=float)
        if m.coef_ is not None and m.coef_.shape != (2 * n_terms(m.degree),):
            raise ValueError(f"H model duhem: coef must hold {2 * n_terms(m.degree)} values (degree {m.degree}, "
                             f"ascending and descending), found shape {m.coef_.shape}")
        nc = len(m.creep_tau_s)
        if m.coef_ is not None and m.lin_coef_.shape == (nc + 1,):
            m.lin_coef_ = np.append(m.lin_coef_, 0.0)   # written before the linear term u joined: its weight is 0
        if m.coef_ is not None and m.lin_coef_.shape != (nc + 2,):
            raise ValueError(f"H model duhem: lin_coef must hold {nc + 2} values (creep bank, offset and the "
                             f"linear term), found shape {m.lin_coef_.shape}")
        return m

    def label(self) -> str:
        return (f"duhem(degree={self.degree}, ridge={self.ridge:g}{', creep' if self.creep else ''}"
                f"{', joint holds' if self.hold_nfev else ''})")
