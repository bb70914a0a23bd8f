"""Identification of the modified Prandtl-Ishlinskii operator as a quadratic programme.

Seed: ``000_18d138f03f1777c3.txt`` Appendix A, eqs. (60)-(80) (Kuhnen's method), with eq. (64) read as
V(w) = 1/2 int E^2 dt (seeds/README.md).

Procedure (all in non-dimensional units x~ = x / max|x|, y~ = y / max|y|, mapped back at the end):

1. Thresholds: play and creep r_i = i / n_play * max|x| (eq. 61, n + 1 = n_play operators); creep eigenvalues
   a_j = 1 / (10^(j-1) dt) (eq. 40). Inverse-superposition thresholds r'_S: eq. (62) puts them on
   [-max|y|/2, max|y|/2], which wastes half of them when y does not straddle 0 and duplicates r' = 0 when l is
   even; we place l = n_sup - 1 thresholds uniformly inside [min y, max y] (plus the identity r'_0 = 0).
2. Regressors Q(t) = [H_{r_H}[x, z_H0], -S_{r'_S}[y], K[x] i, (1)] (eq. 67), so E = Q^T w (eq. 60); Gram matrix
   P = mean(Q Q^T) built once (eq. 65 up to the positive factor t_f - t_0).
3. Constraints (eqs. 68-75): w_H0 >= eps, w_Hi >= 0, w_K >= 0 and the inverse superposition strictly increasing:
   every linear piece of S' has slope >= eps. Eq. (72) as printed constrains tail sums of w'_S, which is the
   right condition only for a one-sided operator ordered from the outside in; the slope form is its exact
   two-sided equivalent.
4. Scale (gauge). Gamma is unchanged when w_H, w_K, w'_S and the offset are multiplied by the same positive
   number, so one linear equality fixes the scale. Eqs. (76)-(78) fix sum w_H (|x| - r_H) + m sum w_K (|x| - r_K)
   = |x|; that admits a degenerate minimiser (all weight on the widest play operator, whose output hardly moves,
   and a superposition with near-zero slopes: both sides of E shrink together -- the "collapse" of
   docs/method.md). ``gauge="range"`` (default) instead fixes the mean slope of S' over the data,
   (S'(max y) - S'(min y)) / (max y - min y) = 1, so u must traverse the output's range; the solution is then
   rescaled to satisfy eq. (76) so the returned weights are in the thesis' gauge. ``gauge="thesis"`` solves
   with (76)-(78) directly.
5. Solve min 1/2 w^T P w with cvxpy (``cp.quad_form(w, cp.psd_wrap(P))``); any status but optimal raises
   IdentificationError. Superposition weights and thresholds of the forward model follow from eqs. (79)-(80)
   (``pi.invert_superposition``).

Optional: ``fit_z0`` searches one common initial play state z_H0 (the preload case of App. A) by a bounded 1-D
minimisation of the QP optimum; ``offset=True`` adds a free constant inside the superposition (u + b), which
helps when the input's zero is arbitrary (e.g. a bipolar drive voltage whose history before the record is
unknown).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .operators import creep_operator, log_creep_eigenvalues, play_operator, superposition_operator
from .pi import ModifiedPI, invert_superposition


_CLARABEL_TOLS = (
    {"tol_gap_abs": 1e-14, "tol_gap_rel": 1e-12, "tol_feas": 1e-12},
    {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-10, "tol_feas": 1e-10},
    {},
)


class IdentificationError(ValueError):
    """The QP solver did not return status 'optimal' (or the data cannot be identified)."""


@dataclass
class FitReport:
    """Fit quality on the identification data; errors in % of the output range (max y - min y)."""

    rms_pct: float
    max_pct: float
    solver: str
    status: str
    seconds: float
    n_samples: int
    objective: float = float("nan")
    z_H0: float = 0.0
    gauge: str = "range"


def _sup_slope_rows(r):
    """Rows A with A @ w = slopes of each linear piece of sum_i w_i S_{r_i} (identity piece first)."""
    r = np.asarray(r, float)
    rows = []
    base = (r == 0).astype(float)
    rows.append(base)
    for side in (r > 0, r < 0):
        idx = np.where(side)[0]
        idx = idx[np.argsort(np.abs(r[idx]), kind="stable")]
        acc = base.copy()
        for i in idx:
            acc = acc.copy()
            acc[i] = 1.0
            rows.append(acc)
    return np.array(rows)


def _regressors(xs, ys, r_H, z0, r_S, creep_bank, offset):
    """Q (N, nw) with columns [H (nH), -S' (nS), K i (nK), 1?] in non-dimensional units (eq. 67)."""
    cols = [play_operator(xs, r_H, z0), -superposition_operator(ys, r_S)]
    if creep_bank is not None:
        cols.append(creep_bank)
    if offset:
        cols.append(np.ones((len(xs), 1)))
    return np.hstack(cols)


def osqp_interposed() -> bool:
    """Whether OSQP's compiled solver would call another library's ``csc_copy`` in this process.

    PuLP (>= 3.3; Snakemake imports it for its scheduler, so every pipeline job that runs in the Snakemake process
    has it) loads HiGHS's extension with ``RTLD_GLOBAL``. That puts HiGHS's exported C function ``csc_copy`` into the
    process's global symbol scope, and OSQP's extension (loaded ``RTLD_LOCAL`` by Python) exports and calls a
    ``csc_copy`` of its own with another signature. The dynamic linker resolves a shared object's calls through the
    global scope first, so OSQP's setup runs HiGHS's function and the process dies with SIGSEGV: no exception, no
    message (measured: ``import pulp`` then any ``osqp.OSQP().setup(...)``, osqp 1.1.3, PuLP 3.3.2, highspy 1.16).
    True where the global scope resolves ``csc_copy``; OSQP is then not called (:func:`_solve_qp` raises instead)."""
    import ctypes

    try:
        return hasattr(ctypes.CDLL(None), "csc_copy")
    except OSError:  # no handle on the global scope (not a dlopen platform): nothing can be interposed through it
        return False


def _solve_qp(R, nH, nS, nK, r_Hs, r_Ss, ys_lo, ys_hi, m, eps, offset, gauge, solver, solver_opts):
    import cvxpy as cp

    if str(solver).upper() == "OSQP" and osqp_interposed():
        raise IdentificationError("solver OSQP not run: another library in this process (HiGHS, loaded globally by "
                                  "PuLP, which Snakemake imports) exports the C function csc_copy that OSQP calls, "
                                  "and OSQP would crash the process (SIGSEGV); use CLARABEL or SCS")

    nw = nH + nS + nK + (1 if offset else 0)
    w = cp.Variable(nw)
    wH, wS = w[:nH], w[nH:nH + nS]
    cons = []
    # eqs. (71), (73): w_H0 >= eps (r = 0 operator), other play weights >= 0
    lbH = np.where(r_Hs == 0, eps, 0.0)
    cons.append(wH >= lbH)
    if nK:
        cons.append(w[nH + nS:nH + nS + nK] >= 0)  # eqs. (71), (75)
    cons.append(_sup_slope_rows(r_Ss) @ wS >= eps)  # eqs. (72), (74), slope form
    if gauge == "range":
        span = superposition_operator(np.array([ys_lo, ys_hi]), r_Ss)
        cons.append((span[1] - span[0]) @ wS == ys_hi - ys_lo)
    elif gauge == "thesis":
        qv = np.zeros(nw)
        qv[:nH] = 1.0 - r_Hs  # eq. (77) with |x~| = 1
        if nK:
            qv[nH + nS:nH + nS + nK] = m * (1.0 - r_Hs)
        cons.append(qv @ w == 1.0)  # eqs. (76), (78)
    else:
        raise ValueError(f"gauge must be 'range' or 'thesis', got {gauge!r}")
    # V(w) = 1/2 mean(E^2) = 1/2 |R w|^2 with R the triangular factor of the regressors (Q = Q_ R / sqrt(N)): the
    # QP is posed on the factor, whose condition number is that of the regressors, not on the Gram matrix Q^T Q,
    # which squares it (cond 5e4 -> 2.9e9 on a tweezer calibration trial, docs/method.md)
    prob = cp.Problem(cp.Minimize(0.5 * cp.sum_squares(R @ w)), cons)
    if solver_opts is None and str(solver).upper() == "CLARABEL":
        # the optimum of V(w) is tiny for good fits (1e-10..1e-16 in non-dimensional units): Clarabel's default
        # absolute gap tolerance (1e-8) stops far too early (weights ~1 % off). Try tight tolerances first and
        # relax step by step if Clarabel can only reach 'optimal_inaccurate' (noise-free, exactly representable
        # data, optimum ~ 0); only a final status 'optimal' is accepted.
        attempts = [dict(t) for t in _CLARABEL_TOLS]
    else:
        attempts = [dict(solver_opts or {})]
    import warnings

    for opts in attempts:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # cvxpy's "may be inaccurate": we check status
                prob.solve(solver=solver, **opts)
        except cp.error.SolverError as exc:
            raise IdentificationError(f"solver {solver} failed: {exc}") from exc
        if prob.status == cp.OPTIMAL:
            break
    if prob.status != cp.OPTIMAL:
        raise IdentificationError(
            f"solver {solver} returned status {prob.status!r} (need 'optimal'); try another solver, "
            f"more iterations or fewer operators")
    return np.asarray(w.value, float), float(prob.value), str(prob.status)


def fit_modified_pi(x, y, dt, n_play=15, n_sup=15, n_creep=4, creep=True, solver="CLARABEL", fit_z0=False,
                    eps=1e-6, offset=False, gauge="range", z_H0=0.0, r_H=None, r_S_inv=None,
                    solver_opts=None, row_mask=None):
    """Identify a ModifiedPI y = Gamma[x] (eq. 42) by Kuhnen's QP (App. A). Returns (ModifiedPI, FitReport).

    This is the raw operator fit: non-negative play weights make counter-clockwise, rising loops only. To fit a
    piezo's H(q) (clockwise, falling with q in the eq. 55 convention) use ``selfsense.hysteresis.models.ModifiedPIH``
    (``make_model("modified_pi").fit(q, v, dt)``), which builds the sign and linear gauge in, tries every installed
    solver and refuses a fit worse than a straight line.

    x, y: 1-D input / output (any units, e.g. charge [C] and V_H [V]); dt [s] sample time.
    n_play: play operators incl. r = 0 (creep uses the same thresholds, eq. 61); n_sup: superposition
    operators incl. the identity; n_creep: creep eigenvalues m per threshold (eq. 40); creep=False drops K.
    solver: any cvxpy QP solver name (default Clarabel); solver_opts: passed to ``Problem.solve`` (default for
    Clarabel: tol_gap_abs=1e-14, tol_gap_rel=1e-12, tol_feas=1e-12, relaxed to 1e-12/1e-10/1e-10 and then
    Clarabel's defaults if only 'optimal_inaccurate' is reached; the optimum is tiny for good fits).
    fit_z0: also search a common initial play state z_H0 (else ``z_H0`` is used, [x units]).
    offset: add a free constant inside the superposition. gauge: 'range' (default) or 'thesis', see module doc.
    r_H / r_S_inv: override the play thresholds [x] / inverse-superposition thresholds [y] (r_S_inv must
    contain 0). row_mask: boolean (N,) selecting the samples whose error enters V(w) (the operators still run over
    the whole record: blocked cross-validation). Raises IdentificationError for any solver status other than optimal.
    """
    t0 = time.perf_counter()
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if x.shape != y.shape or x.size < 3:
        raise ValueError(f"x and y must be 1-D of equal length >= 3, got {x.shape} and {y.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x and y must be finite")
    sx, sy = float(np.max(np.abs(x))), float(np.max(np.abs(y)))
    if sx == 0 or sy == 0 or np.ptp(y) == 0:
        raise IdentificationError("input or output is constant zero / has no range; nothing to identify")
    xs, ys = x / sx, y / sy
    r_Hs = (np.arange(n_play) / n_play) if r_H is None else np.asarray(r_H, float) / sx
    if r_S_inv is None:
        lo, hi = ys.min(), ys.max()
        l = n_sup - 1
        rr = lo + (hi - lo) * np.arange(1, l + 1) / (l + 1)
        rr = rr[np.abs(rr) > 1e-9 * (hi - lo)]
        r_Ss = np.r_[0.0, rr]
    else:
        r_Ss = np.asarray(r_S_inv, float) / sy
        if np.count_nonzero(r_Ss == 0) != 1:
            raise ValueError("r_S_inv must contain exactly one 0 (identity term)")
    a_K = log_creep_eigenvalues(n_creep, dt) if creep and n_creep > 0 else np.zeros(0)
    bank = creep_operator(xs, r_Hs, a_K, dt).sum(axis=2) if len(a_K) else None
    nH, nS, nK = len(r_Hs), len(r_Ss), (len(r_Hs) if bank is not None else 0)
    N = len(xs)

    def solve_for(z0s):
        Q = _regressors(xs, ys, r_Hs, z0s, r_Ss, bank, offset)
        if row_mask is not None:
            Q = Q[np.asarray(row_mask, bool)]
        # eq. (65) (mean instead of integral, same minimiser) as 1/2 |R w|^2 with Q = Q_ R: a well-conditioned factor
        R = np.linalg.qr(Q, mode="r") / np.sqrt(len(Q))
        return _solve_qp(R, nH, nS, nK, r_Hs, r_Ss, ys.min(), ys.max(), len(a_K), eps, offset, gauge,
                         solver, solver_opts)

    z0s = float(z_H0) / sx
    if fit_z0:
        from scipy.optimize import minimize_scalar

        grid = np.linspace(-1.0, 1.0, 9)
        vals = [solve_for(z)[1] for z in grid]
        k = int(np.argmin(vals))
        lo_b, hi_b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        res = minimize_scalar(lambda z: solve_for(z)[1], bounds=(lo_b, hi_b), method="bounded",
                              options={"xatol": 1e-4})
        z0s = float(res.x) if res.fun <= vals[k] else float(grid[k])
    w, obj, status = solve_for(z0s)

    # rescale to the thesis gauge, eqs. (76)-(78): sum w_H (1 - r_H) + m sum w_K (1 - r_K) = 1
    qv = 1.0 - r_Hs
    lam_den = qv @ w[:nH] + (len(a_K) * (qv @ w[nH + nS:nH + nS + nK]) if nK else 0.0)
    lam = 1.0 / lam_den if lam_den > 0 else 1.0
    w = w * lam
    wH, wSi = w[:nH], w[nH:nH + nS]
    wK = w[nH + nS:nH + nS + nK] if nK else np.zeros(0)
    b = float(w[-1]) if offset else 0.0
    # back to physical units: u = sx u~; S'(y) = sx S~'(y / sy) -> r' = sy r~', w' = w~' sx / sy (eq. 79-80 next)
    r_S, w_S = invert_superposition(r_Ss * sy, wSi * sx / sy)
    model = ModifiedPI(r_H=r_Hs * sx, w_H=wH, z_H0=z0s * sx, r_K=(r_Hs * sx) if nK else np.zeros(0), w_K=wK,
                       a_K=a_K if nK else np.zeros(0), r_S=r_S, w_S=w_S, dt=dt, offset=b * sx)
    yhat = model(x)
    err = yhat - y
    rng = float(np.ptp(y))
    rep = FitReport(rms_pct=float(100 * np.sqrt(np.mean(err ** 2)) / rng), max_pct=float(100 * np.max(np.abs(err)) / rng),
                    solver=str(solver), status=status, seconds=time.perf_counter() - t0, n_samples=int(N),
                    objective=obj * lam * lam, z_H0=z0s * sx, gauge=gauge)
    return model, rep


#: QP solvers tried, in order, after the configured one fails or raises (only those installed are used). OSQP is not
#: among them: in the Snakemake process it cannot run (:func:`osqp_interposed`), and a fallback that exists only
#: outside the pipeline would give the pipeline and a library call different models of the same data
FALLBACK_SOLVERS = ("CLARABEL", "SCS", "ECOS")


def fit_modified_pi_robust(x, y, dt, solver="CLARABEL", solvers=None, **kw):
    """:func:`fit_modified_pi` that tries the configured solver, then every other installed QP solver of
    ``FALLBACK_SOLVERS`` when one fails, raises or does not reach status 'optimal' (e.g. Clarabel on a
    shape-memory-alloy record that SCS solves). Returns (model, report dict with ``solver_attempts``);
    raises :class:`IdentificationError` listing every attempt when all fail."""
    import cvxpy as cp

    installed = set(cp.installed_solvers())
    order = [solver] + [s for s in (solvers or FALLBACK_SOLVERS) if s != solver]
    attempts = []
    for s in order:
        if s not in installed:
            if s == solver:
                attempts.append(f"{s}: not installed")
            continue
        try:
            model, rep = fit_modified_pi(x, y, dt, solver=s, **kw)
        except (IdentificationError, ArithmeticError, ValueError) as exc:
            attempts.append(f"{s}: {exc}")
            continue
        except Exception as exc:  # a solver that raises anything else is one failed attempt, not the end
            attempts.append(f"{s}: {type(exc).__name__}: {exc}")
            continue
        d = {k: v for k, v in rep.__dict__.items() if k != "seconds"}
        d["solver_attempts"] = attempts + [f"{s}: {rep.status}"]
        return model, d
    raise IdentificationError("modified PI QP: every solver failed: " + "; ".join(attempts))
