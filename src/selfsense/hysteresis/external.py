"""Real-data check of the H(q) model registry on measurements made by other people (the external data folder).

Pairs (fit -> evaluate), errors in % of the evaluation output range (RMS / max):
- SmartHysteresis ``hysteresis_v_150_1hz.csv``: first half -> second half (input volt [V], output disp [um]);
- danny_preisach ``bigsine_1`` -> ``sine50_1`` and ``prbn_1`` (input Pdrag voltage [V], output Mling [um]);
- SLAC quadrupole ``strdat.ru3`` -> ``strdat.ru4`` and back (current [A] -> integrated gradient [T]).
The model is selected by blocked cross-validation on the fit record only (:func:`select_external`: the registry's
candidates plus the non-negative-density twin of each PI and Preisach candidate, then the one-standard-error rule
towards the most constrained class); baselines: a straight line and a plain 10-operator Prandtl-Ishlinskii operator
fitted by non-negative least squares (the data's PROVENANCE.md). A record's declared prehistory (the SLAC runs: the
standardisation cycle 0 -> 165 A -> 0 before each run) is the initial state of every candidate
(:class:`PrehistoryH`). The aixACCT PNZT record (a poling pulse of a switching ferroelectric) is for charge-drift
handling, not for H(q).

Run: ``selfsense fit-external [--out FILE.md] [--data-dir DIR] [--fit FILE:X:Y[:T] [--eval FILE:X:Y[:T]]
[--prehistory X1,X2,...] [--quasi-static]]`` (:mod:`selfsense.cli.fit_external`).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from .operators import play_operator

PROVENANCE_BASELINE = {"smart": (0.38, 1.46), "sine50_1": (2.1, 8.2), "prbn_1": (1.9, 11.1)}


#: environment variable naming the folder of external measurements (see :func:`default_data_dir`)
DATA_ENV = "SELFSENSE_EXTERNAL_DATA"


def default_data_dir() -> Path:
    """The folder of external measurements (sub-folders ``smart_hysteresis``, ``danny_preisach``,
    ``slac_quadrupole``), named by the environment variable ``SELFSENSE_EXTERNAL_DATA``. These records are not part
    of the package; without the variable (and without ``--data-dir``) there is no default and the caller says so."""
    val = os.environ.get(DATA_ENV, "").strip()
    if not val:
        raise FileNotFoundError(f"no external data folder: pass --data-dir DIR or set {DATA_ENV}=DIR "
                                "(a folder with smart_hysteresis/, danny_preisach/, slac_quadrupole/)")
    return Path(val)


def load_smart(data_dir: Path):
    """SmartHysteresis CSV -> (t [s], volt [V], disp [um]), from the first non-zero command (t >= 3.257 s)."""
    import pandas as pd

    df = pd.read_csv(data_dir / "smart_hysteresis" / "hysteresis_v_150_1hz.csv", header=None, skiprows=0)
    df = df.iloc[:, 1:4]
    df.columns = ["t", "disp", "volt"]
    df = df.apply(pd.to_numeric, errors="coerce").dropna()
    t, d, v = (df[c].to_numpy(float) for c in ("t", "disp", "volt"))
    start = int(np.argmax(np.abs(v) > 0))
    start = max(start - 1, 0)
    return t[start:], v[start:], d[start:]


def load_danny(data_dir: Path, name: str):
    """danny_preisach .mat -> (t [s], Pdrag voltage [V], Mling displacement [um]); last sample dropped."""
    import scipy.io as sio

    s = sio.loadmat(str(data_dir / "danny_preisach" / f"{name}.mat"))[name]
    t = s["X"][0, 0]["Data"][0, 0].ravel().astype(float)
    Y = s["Y"][0, 0]
    disp = Y[0, 0]["Data"].ravel().astype(float)
    volt = Y[0, 2]["Data"].ravel().astype(float)
    return t[:-1], volt[:-1], disp[:-1]


def errors_pct(yhat, y):
    rng = float(np.ptp(y))
    e = yhat - y
    return 100 * float(np.sqrt(np.mean(e ** 2))) / rng, 100 * float(np.max(np.abs(e))) / rng


class PIBaseline:
    """Plain PI: y = sum_i w_i H_{r_i}[x] + c, w >= 0 by NNLS (c split in +/- columns); r_i = i/n * max|x|."""

    def __init__(self, n=10):
        self.n = n

    def _feat(self, x):
        F = play_operator(x, self.r, 0.0)
        return np.hstack([F, np.ones((len(x), 1)), -np.ones((len(x), 1))])

    def fit(self, x, y):
        from scipy.optimize import nnls

        self.r = np.arange(self.n) / self.n * np.max(np.abs(x))
        self.w, _ = nnls(self._feat(x), y)
        return self

    def __call__(self, x):
        return self._feat(x) @ self.w


def _pairs(data_dir: Path, sub_smart: int, sub_danny: int):
    """Yield (key, label, x_fit, y_fit, dt_fit, x_eval_full, y_eval_full, eval_mask, dt_eval, prehistory)."""
    t, v, d = load_smart(data_dir)
    t, v, d = t[::sub_smart], v[::sub_smart], d[::sub_smart]
    dt = float(np.median(np.diff(t)))
    half = len(v) // 2
    mask = np.zeros(len(v), bool)
    mask[half:] = True
    # evaluation runs over the whole record so the second half starts from the state the first half left
    yield "smart", "SmartHysteresis 1st half -> 2nd half", v[:half], d[:half], dt, v, d, mask, dt, None
    tb, vb, db = load_danny(data_dir, "bigsine_1")
    tb, vb, db = tb[::sub_danny], vb[::sub_danny], db[::sub_danny]
    dtb = float(np.median(np.diff(tb)))
    for name in ("sine50_1", "prbn_1"):
        te, ve, de = load_danny(data_dir, name)
        ve, de = ve[::sub_danny], de[::sub_danny]
        yield name, f"danny bigsine_1 -> {name}", vb, db, dtb, ve, de, np.ones(len(ve), bool), dtb, None
    slac = data_dir / "slac_quadrupole"
    if (slac / "strdat.ru3").is_file() and (slac / "strdat.ru4").is_file():
        from .slac import SLAC_I_MAX, parse_slac_report

        r3, r4 = parse_slac_report(slac / "strdat.ru3"), parse_slac_report(slac / "strdat.ru4")
        # quasi-static tables: one "sample" per current step (dt = 1 s is nominal; no creep on these records).
        # Both runs start at the remanent BL = 0.034 T left by the magnet's standardisation cycle 0 -> I_max -> 0
        # (I_max = 165 A, the "Max" of the run headers; at least the fit run's largest current): that cycle is the
        # records' declared prehistory, the same for the fit and the evaluation run
        for key, (a, b) in {"slac_ru3_ru4": (r3, r4), "slac_ru4_ru3": (r4, r3)}.items():
            pre = (0.0, max(SLAC_I_MAX, float(np.max(a["current"]))), 0.0)
            yield (key, f"SLAC {key[5:8]} -> {key[9:]}", a["current"], a["BL"], 1.0, b["current"], b["BL"],
                   np.ones(len(b["current"]), bool), 1.0, pre)


class PrehistoryH:
    """A registry model linear in its parameters (:class:`selfsense.hysteresis.models.LinearParamH`) whose operators
    start from a declared input prehistory instead of the relaxed state: the ``prehistory`` input samples are run
    through the operators (and the creep bank) before every record, and their outputs, which were not measured,
    never enter the fit. This is the record's initial magnetic / electric state as part of the model: a record that
    starts at remanence after a standardisation cycle 0 -> I_max -> 0 has its play states z0 (the initial states of
    the play operators, 000_18d138f03f1777c3.txt eqs. (29)-(31)) and Preisach states set by that cycle (Mayergoyz's
    wiping-out: only the cycle's extrema matter to a rate-independent model), not relaxed. The prehistory samples
    come just before the record at its sample time (what a creep bank sees). The input normalisation covers the
    prehistory, so thresholds reach the cycle's peak."""

    def __init__(self, inner, prehistory):
        from .models import LinearParamH

        if not isinstance(inner, LinearParamH):
            raise ValueError(f"prehistory: {inner.label()} is not linear in its parameters (it runs from the relaxed "
                             "state only)")
        pre = np.asarray(prehistory, float).ravel()
        if pre.size < 1 or not np.all(np.isfinite(pre)):
            raise ValueError(f"prehistory: expected finite input values, got {prehistory!r}")
        self.inner, self.prehistory = inner, pre
        self.kind, self.ridge, self.convex = inner.kind, inner.ridge, True
        self.linear_in_parameters = True   # cross-validated like its inner model (select.cv_candidate)
        self.nonneg = bool(getattr(inner, "nonneg", False))
        self.coef_, self.extra_coef_ = None, np.zeros(0)

    def _pad(self, stride: int) -> np.ndarray:
        # prehistory left-padded with its first value to a multiple of the row stride, so that the strided rows of
        # the record stay the record's every stride-th sample (a rate-independent operator ignores repeated inputs)
        n = self.prehistory.size
        return np.concatenate([np.full(-(-n // stride) * stride - n, self.prehistory[0]), self.prehistory])

    def _bounds(self, n_cols: int):
        return self.inner._bounds(n_cols)

    def prepare(self, q, dt: float):
        qs = q if isinstance(q, (list, tuple)) else [q]
        self.inner.prepare([self.prehistory] + [np.asarray(x, float) for x in qs], dt)
        return self

    def n_columns(self) -> int:
        return self.inner.n_columns()

    def design(self, q, dt: float, stride: int = 1, out: np.ndarray | None = None):
        p = self._pad(int(stride))
        X, pen = self.inner.design(np.concatenate([p, np.asarray(q, float)]), dt, int(stride))
        X = X[p.size // int(stride):]
        if out is None:
            return X, pen
        out[:, :X.shape[1]] = X
        return out[:, :X.shape[1]], pen

    def fit(self, q, v, dt: float, extra=None):
        from .models import LinearParamH

        LinearParamH.fit(self, q, v, dt, extra)   # the base fit through this class's prepare / design
        self.inner.coef_ = self.coef_
        return self

    def predict(self, q, dt: float | None = None) -> np.ndarray:
        self.inner.coef_ = self.coef_
        return self.inner.predict(np.concatenate([self.prehistory, np.asarray(q, float)]), dt)[self.prehistory.size:]

    def __call__(self, q):
        return self.predict(q)

    def label(self) -> str:
        return f"{self.inner.label()} from prehistory {_fmt_pre(self.prehistory)}"


def _fmt_pre(pre) -> str:
    return " -> ".join(f"{p:g}" for p in pre)


def _nonneg_variants(cands) -> tuple:
    """The non-negative-density twin of every PI and Preisach candidate (the monotone-branch prior). A Preisach
    candidate with a reversible part (``n_rev``) has none: its ramps' weights are signed (they set the curvature of
    a piecewise-linear function, not a density), so a bound on the grid's cells would not make it a non-negative
    density, and it competes as the signed fit it is."""
    out = []
    for k, p in cands:
        if (k in ("pi", "preisach") and not p.get("nonneg") and not p.get("n_rev")
                and (k, {**p, "nonneg": True}) not in cands):
            out.append((k, {**p, "nonneg": True}))
    return tuple(out)


#: candidates of the real-data check: the registry's, without the creep bank on the quasi-static SLAC tables, plus
#: the non-negative (monotone) twin of each PI / Preisach candidate
def _candidates(quasi_static: bool):
    from .models.select import DEFAULT_CANDIDATES

    if not quasi_static:
        base = DEFAULT_CANDIDATES
    else:
        # few samples (one per current step): stronger ridges join the grid
        base = tuple((k, {**p, "creep": False}) if k not in ("linear",) else (k, p) for k, p in DEFAULT_CANDIDATES
                     if k != "modified_pi") + (
            ("pi", {"n_play": 10, "ridge": 1e-2, "creep": False}), ("pi", {"n_play": 10, "ridge": 1e-1, "creep": False}),
            ("preisach", {"n_grid": 8, "n_play": 0, "ridge": 1e-2, "creep": False}),
            ("modified_pi", {"n_play": 12, "n_sup": 6, "creep": False}))
    return tuple(base) + _nonneg_variants(base)


def _constraint_class(model) -> int:
    """0: non-negative density (the most constrained); 1: signed weights, convex fit; 2: non-convex search."""
    if getattr(model, "nonneg", False):
        return 0
    return 1 if getattr(model, "convex", True) else 2


def select_external(x, y, dt: float, candidates, prehistory=None, names=("fit record",), n_blocks: int = 5,
                    thin: int = 1):
    """Blocked CV on the fit record only (the folds of :func:`selfsense.hysteresis.models.select.select_h_model`),
    then the one-standard-error rule (Hastie, Tibshirani & Friedman, Elements of Statistical Learning, sec. 7.10):
    among the candidates whose mean fold RMS exceeds the best one's by no more than one standard error of the paired
    fold differences, the most constrained class is taken (non-negative density, then signed convex fits, then
    non-convex searches; the straight line only if it is the best), its best member selected. With ``prehistory``
    every candidate linear in its parameters starts from it (:class:`PrehistoryH`); the others cannot and are
    left out. Returns ``(model refitted on the whole record, table, warnings)``."""
    from .models import DegenerateFitError, LinearParamH, fit_stride, make_model
    from .models import select as S

    x, y = np.asarray(x, float), np.asarray(y, float)
    k = fit_stride([len(x)])
    folds = S.blocked_folds([len(x[::k])], n_blocks, rotate=S.ROTATE_FOLDS)
    table, models = [], []
    for kind, params in candidates:
        model = make_model(kind, **params)
        if prehistory is not None and not isinstance(model, LinearParamH):
            # a model fitted from the relaxed state only cannot honour the declared initial state: not offered
            table.append({"kind": kind, "params": dict(params), "label": model.label(),
                          "cv_rms_v": [float("nan")] * n_blocks, "cv_rms_mean_v": float("nan"),
                          "status": "not offered: starts from the relaxed state only (a prehistory is declared)",
                          "selected": False, "class": _constraint_class(model)})
            models.append(model)
            continue
        if prehistory is not None:
            model = PrehistoryH(model, prehistory)
        row = S.cv_candidate(model, kind, params, [x], [y], dt, None, np.ones(1, bool), folds, n_blocks,
                             S.ROTATE_FOLDS, thin)
        table.append({**row, "class": _constraint_class(model)})
        models.append(model)
    ok = [i for i, r in enumerate(table) if np.isfinite(r["cv_rms_mean_v"])]
    if not ok:
        raise DegenerateFitError(f"H(q) selection on {list(names)}: no candidate could be fitted: "
                                 + "; ".join(f"{r['label']}: {r['status']}" for r in table))
    ib = min(ok, key=lambda i: table[i]["cv_rms_mean_v"])
    best = np.asarray(table[ib]["cv_rms_v"])

    def within_one_se(i):
        d = np.asarray(table[i]["cv_rms_v"]) - best
        return float(np.mean(d)) <= float(np.std(d, ddof=1) / np.sqrt(d.size))

    near = [i for i in ok if i == ib or (table[i]["kind"] != "linear" and within_one_se(i))]
    cls = min(table[i]["class"] for i in near)
    isel = min((i for i in near if table[i]["class"] == cls), key=lambda i: table[i]["cv_rms_mean_v"])
    table[isel]["selected"] = True
    warnings = []
    lin = next((r for r in table if r["kind"] == "linear" and np.isfinite(r["cv_rms_mean_v"])), None)
    sel = table[isel]
    if lin is not None and sel is not lin and not sel["cv_rms_mean_v"] < lin["cv_rms_mean_v"]:
        raise DegenerateFitError(f"H(q) on {list(names)}: {sel['label']} does not beat a straight line in the "
                                 f"cross-validation ({sel['cv_rms_mean_v']:.4g} vs {lin['cv_rms_mean_v']:.4g})")
    if sel["kind"] == "linear":
        warnings.append(f"H(q) on {list(names)}: no hysteresis model beats a straight line in the cross-validation")
    model = models[isel]
    model.fit(x, y, dt)
    return model, table, warnings


def fit_pair(x_fit, y_fit, dt_fit, x_eval, y_eval, dt_eval, mask=None, quasi_static: bool = False,
             names=("fit record",), prehistory=None) -> dict:
    """Select an H model by blocked CV on the fit record (:func:`select_external`), refit it on the whole fit
    record and score it out of sample on the evaluation record, against a straight line and the plain 10-operator
    PI (NNLS) fitted on the same samples. ``prehistory``: input values run through before each record (both start
    from the state it leaves). Errors in % of the evaluation output range (RMS, max)."""
    from .models import LinearH

    x_fit, y_fit = np.asarray(x_fit, float), np.asarray(y_fit, float)
    x_eval, y_eval = np.asarray(x_eval, float), np.asarray(y_eval, float)
    mask = np.ones(len(x_eval), bool) if mask is None else np.asarray(mask, bool)
    t0 = time.perf_counter()
    model, table, warnings = select_external(x_fit, y_fit, dt_fit, _candidates(quasi_static), prehistory, names,
                                             thin=max(1, len(x_fit) // 8000))
    lin = LinearH().fit(x_fit, y_fit, dt_fit)
    pi10 = PIBaseline(10).fit(x_fit, y_fit)
    row = {"selected": model.label(), "selection": table, "warnings": warnings,
           "h_selected": errors_pct(model.predict(x_eval, dt_eval)[mask], y_eval[mask]),
           "linear": errors_pct(lin.predict(x_eval)[mask], y_eval[mask]),
           "baseline_pi10": errors_pct(pi10(x_eval)[mask], y_eval[mask]),
           "seconds": time.perf_counter() - t0}
    return row


def run(data_dir: Path | None = None, sub_smart: int = 2, sub_danny: int = 2, solver: str = "CLARABEL"):
    """Fit and evaluate every pair; returns a list of row dicts (errors in % of evaluation output range)."""
    data_dir = Path(data_dir) if data_dir is not None else default_data_dir()
    rows = []
    for key, label, xf, yf, dtf, xe, ye, mask, dte, pre in _pairs(data_dir, sub_smart, sub_danny):
        row = {"key": key, "pair": label, "n_fit": len(xf), "dt": dtf,
               "provenance_baseline": PROVENANCE_BASELINE.get(key, (float("nan"), float("nan")))}
        row.update(fit_pair(xf, yf, dtf, xe, ye, dte, mask, quasi_static=key.startswith("slac"), names=[label],
                            prehistory=pre))
        rows.append(row)
    return rows


def ri_smoothing_by_cv(x_fit, y_fit, x_eval, y_eval, prehistory, smooth_grid=(0.0, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4,
                                                                                1e-3, 1e-2, 1e-1), n_blocks: int = 5):
    """The one-sided RI model (002_7d89b7147aad52e4.txt eqs. 10-11, F (15), G (16); ``selfsense.hysteresis.ri``)
    from the declared ``prehistory``, its smoothing weight chosen by the blocked CV folds of the selection on the fit
    record only. Returns ``(smooth, cv fold-mean RMS [output units], (RMS %, max %) on the evaluation record)``."""
    from .models.select import ROTATE_FOLDS, blocked_folds
    from .ri import RIModel, solve_ls

    xf, xe = np.maximum(np.asarray(x_fit, float), 0.0), np.maximum(np.asarray(x_eval, float), 0.0)
    yf, ye = np.asarray(y_fit, float), np.asarray(y_eval, float)
    pre = np.asarray(prehistory, float)
    scale = float(max(np.max(pre), np.max(xf)))
    ri = RIModel(input_scale=scale)
    st = ri.state_after(pre)
    Phi = ri.regressor(xf, st)
    u_max = float(max(np.max(ri.scale_input(xf)), st.M_max))
    folds = blocked_folds([len(xf)], n_blocks, rotate=ROTATE_FOLDS)
    cv = [float(np.mean([np.sqrt(np.mean((Phi[h] @ solve_ls(Phi[~h], yf[~h], smooth=s, u_max=u_max) - yf[h]) ** 2))
                         for h in folds])) for s in smooth_grid]
    s = float(smooth_grid[int(np.argmin(cv))])
    m = RIModel(input_scale=scale).fit(xf, yf, smooth=s, x_history=pre)
    return s, float(min(cv)), errors_pct(m(xe, m.state_after(pre)), ye)


def slac_checks(data_dir: Path | None = None) -> str:
    """What each part of the selection does on the SLAC pairs (relaxed start or declared prehistory, signed only or
    with the non-negative twins) and the RI model with its smoothing chosen by CV on the fit record: markdown."""
    data_dir = Path(data_dir) if data_dir is not None else default_data_dir()
    out = ["| SLAC pair | variant | selected H | RMS / max % |", "|---|---|---|---|"]
    for key, label, xf, yf, dtf, xe, ye, mask, dte, pre in _pairs(data_dir, 2, 2):
        if not key.startswith("slac"):
            continue
        signed = tuple(c for c in _candidates(True) if not c[1].get("nonneg"))
        for name, cands, p in (("relaxed start, signed only", signed, None),
                               ("relaxed start, + non-negative twins", _candidates(True), None),
                               ("prehistory, signed only", signed, pre),
                               ("prehistory, + non-negative twins (default)", _candidates(True), pre)):
            m, _, _ = select_external(xf, yf, dtf, cands, p, [label])
            e = errors_pct(m.predict(xe, dte), ye)
            out.append(f"| {label} | {name} | {m.label()} | {e[0]:.2f} / {e[1]:.2f} |")
        s, cv, e = ri_smoothing_by_cv(xf, yf, xe, ye, pre)
        out.append(f"| {label} | RI from prehistory, smooth = {s:g} by CV (fold RMS {cv:.3g}) | ri (eqs. 10-11) | "
                   f"{e[0]:.2f} / {e[1]:.2f} |")
    return "\n".join(out) + "\n"


def to_markdown(rows) -> str:
    f = lambda p: f"{p[0]:.2f} / {p[1]:.2f}"  # noqa: E731
    out = ["| pair | selected H (blocked CV on the fit record) | selected: RMS / max | straight line | "
           "plain PI-10 (NNLS) | PROVENANCE baseline |", "|---|---|---|---|---|---|"]
    for r in rows:
        pb = r["provenance_baseline"]
        out.append(f"| {r['pair']} | {r['selected']} | {f(r['h_selected'])} | {f(r['linear'])} | "
                   f"{f(r['baseline_pi10'])} | {f(pb) if np.isfinite(pb[0]) else 'n/a'} |")
    return "\n".join(out) + "\n"


def _read_record(spec: str):
    """``FILE:X:Y[:T]`` -> (x, y, dt): a CSV or Parquet file and the names of its input, output and (optional) time
    columns; without T, dt = 1 (samples)."""
    import pandas as pd

    parts = spec.rsplit(":", 3)
    if len(parts) < 3:
        raise ValueError(f"record {spec!r}: expected FILE:X_COLUMN:Y_COLUMN[:T_COLUMN]")
    if len(parts) == 4 and not Path(parts[0]).exists() and Path(":".join(parts[:2])).exists():
        parts = [":".join(parts[:2])] + parts[2:]
    path = Path(parts[0])
    cols = parts[1:]
    if not path.is_file():
        raise ValueError(f"record {spec!r}: file {str(path)!r} not found")
    df = pd.read_parquet(path) if path.suffix.lower() in (".parquet", ".pq") else pd.read_csv(path)
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: columns {missing} not found; it has {list(df.columns)[:12]}")
    d = df[cols].apply(pd.to_numeric, errors="coerce").dropna()
    if len(d) < 50:
        raise ValueError(f"{path}: fewer than 50 numeric rows in columns {cols}")
    x, y = d[cols[0]].to_numpy(float), d[cols[1]].to_numpy(float)
    dt = float(np.median(np.diff(d[cols[2]].to_numpy(float)))) if len(cols) > 2 else 1.0
    if not dt > 0:
        raise ValueError(f"{path}: column {cols[2]!r} is not increasing time")
    return x, y, dt


def _parse_prehistory(text):
    """``"0,165,0"`` -> array of input values, or None."""
    if text is None:
        return None
    try:
        pre = np.array([float(v) for v in text.split(",") if v.strip()], float)
    except ValueError:
        pre = np.zeros(0)
    if pre.size < 1 or not np.all(np.isfinite(pre)):
        raise ValueError(f"--prehistory {text!r}: expected comma-separated finite input values, e.g. 0,165,0")
    return pre
