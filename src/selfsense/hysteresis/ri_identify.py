"""Identification of the RI hysteresis model and model-comparison tools.

Seed: ``002_7d89b7147aad52e4.txt`` Sect. 4.3: the identification protocol eq. (14) (sines from 0 to V_pp at 100 Hz,
V_pp = 0..70 V in 5 V steps), F(M_max) read at the first maximum, G(M, m) = F(M) - f read on the following
falling branch at m on a grid, then least squares for the quartic (15) and the trend surface (16).

``compare_models`` puts the RI model next to the modified Prandtl-Ishlinskii model of the thesis
(``selfsense.hysteresis.identify.fit_modified_pi``, imported lazily), a plain PI (10 play operators, non-negative
least squares, the baseline of the external records' PROVENANCE.md) and a straight line, all with the same split and
the same metrics (RMS and max error in % of the test output range).
"""
from __future__ import annotations

import numpy as np

from .ri import RIModel, diagonal_constraint_basis

__all__ = ["identification_protocol", "extract_protocol_points", "fit_protocol", "fit_F", "fit_G",
           "error_metrics", "compare_models", "fit_line", "fit_plain_pi", "markdown_table"]


def identification_protocol(v_max: float = 70.0, v_step: float = 5.0, freq: float = 100.0, fs: float = 20_000.0,
                            n_periods: float = 1.0):
    """Eq. (14): u(t) = V_pp/2 + (V_pp/2) sin(2 pi freq t + 1.5 pi), V_pp = v_step, 2 v_step, ..., v_max.

    Returns a list of (V_pp, u) with u sampled at ``fs`` [Hz] for ``n_periods`` periods (starts and ends at 0).
    Each record is meant to be applied to the plant from a virgin state (paper: t=0, u=0, f=0).
    """
    n = int(round(n_periods * fs / freq)) + 1
    t = np.arange(n) / fs
    out = []
    for vpp in np.arange(v_step, v_max + 0.5 * v_step, v_step):
        u = vpp / 2 + (vpp / 2) * np.sin(2 * np.pi * freq * t + 1.5 * np.pi)
        out.append((float(vpp), np.maximum(u, 0.0)))
    return out


def extract_protocol_points(records, m_step: float | None = None):
    """Paper Sect. 4.3: from each (u, f) record started in the virgin state, take
    F(M_max) = f at the first maximum and G(M, m) = F(M) - f at the falling-branch points u = m.

    ``m_step``: read G at m = 0, m_step, 2 m_step, ... <= M (the paper's grid, 5 V) by linear interpolation; None
    takes every falling-branch sample. Returns (M_F, F, M_G, m_G, G) arrays.
    """
    MF, FF, MG, mG, GG = [], [], [], [], []
    for u, f in records:
        u = np.asarray(u, float)
        f = np.asarray(f, float)
        du = np.diff(u)
        down = np.flatnonzero(du < 0)
        if down.size == 0:
            continue
        i_max = int(down[0])
        up_after = np.flatnonzero(du[i_max:] > 0)
        i_min = i_max + (int(up_after[0]) if up_after.size else len(du) - i_max)
        M, Fm = float(u[i_max]), float(f[i_max])
        MF.append(M)
        FF.append(Fm)
        ub, fb = u[i_max:i_min + 1], f[i_max:i_min + 1]
        if m_step is None:
            ms, fs_ = ub, fb
        else:
            ms = np.arange(0.0, M + 1e-9 * max(M, 1.0), m_step)
            ms = ms[(ms >= ub.min()) & (ms <= M)]
            fs_ = np.interp(ms, ub[::-1], fb[::-1])
        MG.append(np.full(ms.shape, M))
        mG.append(ms)
        GG.append(Fm - fs_)
    cat = (lambda a: np.concatenate(a) if a else np.zeros(0))
    return np.asarray(MF), np.asarray(FF), cat(MG), cat(mG), cat(GG)


def fit_F(M, F) -> np.ndarray:
    """Least squares for eq. (15) (columns normalised)."""
    A = np.vander(np.asarray(M, float), 5, increasing=True)
    n = np.linalg.norm(A, axis=0)
    n[n == 0] = 1.0
    sol, *_ = np.linalg.lstsq(A / n, np.asarray(F, float), rcond=1e-13)
    return sol / n


def fit_G(M, m, G, constrain_diagonal: bool = True) -> np.ndarray:
    """Least squares for the trend surface eq. (16); optionally with G(M, M) = 0."""
    from .ri import G_MONOMIALS
    M = np.asarray(M, float)
    m = np.asarray(m, float)
    A = np.stack([M ** a * m ** c for a, c in G_MONOMIALS], axis=1)
    T = diagonal_constraint_basis() if constrain_diagonal else np.eye(15)
    AT = A @ T
    n = np.linalg.norm(AT, axis=0)
    n[n == 0] = 1.0
    sol, *_ = np.linalg.lstsq(AT / n, np.asarray(G, float), rcond=1e-13)
    return T @ (sol / n)


def fit_protocol(records, m_step: float | None = None, constrain_diagonal: bool = True,
                 input_scale: float | None = None, input_offset: float = 0.0) -> RIModel:
    """Identify an ``RIModel`` from protocol records [(x, y), ...] (each from the virgin state), paper Sect. 4.3.

    x is the raw input (e.g. V), y the hysteresis output f. ``input_scale=None`` -> max over all records.
    """
    recs = [(np.asarray(x, float), np.asarray(y, float)) for x, y in records]
    if input_scale is None:
        input_scale = max(float(np.max(x) - input_offset) for x, _ in recs) or 1.0
    model = RIModel(input_scale=input_scale, input_offset=input_offset)
    scaled = [(model.scale_input(x), y) for x, y in recs]
    step = None if m_step is None else m_step / input_scale
    MF, FF, MG, mG, GG = extract_protocol_points(scaled, m_step=step)
    if MF.size < 5:
        raise ValueError(f"fit_protocol: need at least 5 records with a maximum, got {MF.size}")
    model.b = fit_F(MF, FF)
    model.p = fit_G(MG, mG, GG, constrain_diagonal=constrain_diagonal)
    model.fit_info = {"method": "paper protocol (Sect. 4.3): F at first maxima, G on falling branches",
                      "n_F": int(MF.size), "n_G": int(GG.size), "constrain_diagonal": bool(constrain_diagonal)}
    return model


# ---------------------------------------------------------------------------------------------- comparison
def error_metrics(y_true, y_pred) -> tuple[float, float]:
    """(RMS, max) absolute error in % of the range of y_true."""
    y_true = np.asarray(y_true, float)
    e = np.asarray(y_pred, float) - y_true
    rng = float(np.ptp(y_true)) or 1.0
    return float(100 * np.sqrt(np.mean(e ** 2)) / rng), float(100 * np.max(np.abs(e)) / rng)


def fit_line(x, y):
    """Straight line y = a + c x by least squares; returns a callable."""
    c, a = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    return lambda xx: a + c * np.asarray(xx, float)


def fit_plain_pi(x, y, n_play: int = 10):
    """Plain Prandtl-Ishlinskii: affine term + ``n_play`` play operators (radii uniform on [0, range/2)),
    weights by non-negative least squares (the PROVENANCE.md baseline). Play states start at the first input.
    Returns a callable x -> y (each call starts again from that initial state convention)."""
    from scipy.optimize import nnls
    x = np.asarray(x, float)
    lo, hi = float(np.min(x)), float(np.max(x))
    r = np.linspace(0.0, (hi - lo) / 2, n_play, endpoint=False)

    def ops(xx):
        xx = np.asarray(xx, float)
        Z = np.empty((xx.size, n_play))
        z = np.full(n_play, xx[0])
        for k, v in enumerate(xx):
            z = np.minimum(np.maximum(z, v - r), v + r)
            Z[k] = z
        return Z

    A = ops(x)
    A1 = np.column_stack([np.ones(x.size), -np.ones(x.size), A])  # free offset as difference of two >= 0
    w, _ = nnls(A1, np.asarray(y, float))
    return lambda xx: w[0] - w[1] + ops(xx) @ w[2:]


def _modified_pi(x_tr, y_tr, dt):
    """Lazy import of the thesis' modified PI (another engineer's module). Returns (callable, note)."""
    try:
        from .identify import fit_modified_pi
        model, report = fit_modified_pi(np.asarray(x_tr, float), np.asarray(y_tr, float), dt, creep=False)
    except (ImportError, NotImplementedError) as exc:
        return None, f"modified PI unavailable ({type(exc).__name__}: fit_modified_pi not implemented yet)"
    except Exception as exc:  # noqa: BLE001 - report, do not hide
        return None, f"modified PI failed: {type(exc).__name__}: {exc}"
    return model, ""


def compare_models(x_train, y_train, x_test, y_test, dt: float = 1.0, ri_kwargs: dict | None = None,
                   history_train=None, history_test=None, include_pi: bool = True) -> list[dict]:
    """Fit RI, modified PI (if available), plain PI and a straight line on (x_train, y_train); evaluate on the test set.

    ``history_*``: optional input histories applied to the RI model before each set (memory only), e.g. the
    magnet's preconditioning cycle. Returns rows {model, train_rms, train_max, test_rms, test_max, note}
    (errors in % of the respective output range).
    """
    ri_kwargs = dict(ri_kwargs or {})
    rows = []
    ri = RIModel(input_scale=ri_kwargs.pop("input_scale", None), input_offset=ri_kwargs.pop("input_offset", 0.0))
    ri.fit(x_train, y_train, x_history=history_train, **ri_kwargs)
    st_tr = ri.state_after(history_train) if history_train is not None else None
    st_te = ri.state_after(history_test) if history_test is not None else None
    rows.append(_row("RI (eqs. 10-11, 15-16)", ri(x_train, st_tr), ri(x_test, st_te), y_train, y_test, ""))
    if include_pi:
        mpi, note = _modified_pi(x_train, y_train, dt)
        if mpi is not None:
            rows.append(_row("modified PI (thesis eqs. 36, 42)", mpi(np.asarray(x_train, float)),
                             mpi(np.asarray(x_test, float)), y_train, y_test, ""))
        else:
            rows.append({"model": "modified PI (thesis eqs. 36, 42)", "train_rms": np.nan, "train_max": np.nan,
                         "test_rms": np.nan, "test_max": np.nan, "note": note})
        pi = fit_plain_pi(x_train, y_train)
        rows.append(_row("plain PI (10 play, NNLS)", pi(x_train), pi(x_test), y_train, y_test, ""))
    line = fit_line(x_train, y_train)
    rows.append(_row("straight line", line(x_train), line(x_test), y_train, y_test, ""))
    return rows


def _row(name, yhat_tr, yhat_te, y_tr, y_te, note):
    a, b = error_metrics(y_tr, yhat_tr)
    c, d = error_metrics(y_te, yhat_te)
    return {"model": name, "train_rms": a, "train_max": b, "test_rms": c, "test_max": d, "note": note}


def markdown_table(rows, columns, headers=None, fmt="{:.3f}") -> str:
    """Rows of dicts -> Markdown table (NaN printed as 'n/a')."""
    headers = headers or columns
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    for r in rows:
        cells = []
        for c in columns:
            v = r.get(c, "")
            if isinstance(v, float):
                cells.append("n/a" if not np.isfinite(v) else fmt.format(v))
            else:
                cells.append(str(v))
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)
