"""Truth hysteresis families of the virtual tweezer, acting on the normalised actuator charge u = q_act / q_ref.

The estimator fits Prandtl-Ishlinskii-type, Preisach-grid and RI models (``selfsense.hysteresis.models``); the
truth families below are deliberately of *other* forms, so that the cross-device benchmark measures how the
identification generalises, not how well a model recovers its own family (``docs/simulator.md``, "Device
families"). Every family produces an output ``y`` [V] that the kernel combines as

    V_H = h_lin * u - sign * (y - y0) (+ electrical creep, stress)

with ``sign = +1`` (loops like the thesis' clockwise H(q), paper 001_972cacfaa08ad91a.txt Fig. 12) or ``-1``
(counter-clockwise), ``y0`` the output in the relaxed initial state.

Family codes (``FAMILIES``):

0. ``preisach``: the continuous asymmetric Preisach element of :mod:`selfsense.sim.preisach` (Everett function
   from logistic-product components; congruent minor loops, wiping-out).
1. ``bouc_wen``: saturating Bouc-Wen oscillator on charge (Bouc 1971, Wen 1976),
   ``dz = du [A - |z|^n (beta sgn(du z) + gamma)]``, ``y = w z``; loops saturate at
   ``z_max = (A / (beta + gamma))^(1/n)``; minor loops are not congruent (not a Preisach operator).
2. ``gpi``: generalised play operators with *input-side* envelope functions (Al Janaideh, Rakheja, Su 2009):
   ``z_r = min(max(z_r, g_a(u) - r), max(g_d(u) + r, g_a(u) - r))`` with different saturating ascending and
   descending envelopes ``g_a(u) = a tanh(b u)``, ``g_d(u) = a tanh(b u + c u^2) / (1 + c/2)`` and
   ``y = w sum p_r z_r / sum p_r``, ``p_r = exp(-tau r)``: asymmetric loops whose branches flatten with charge.
3. ``jiles_atherton``: a Jiles-Atherton-type domain-wall model (Jiles & Atherton 1986, in its ferroelectric
   reading): field ``H = u - u0``, effective field ``He = H + a_c M``, anhysteretic Langevin
   ``M_an = M_s (coth(He / a) - a / He)``, irreversible part ``dM_irr/dH = (M_an - M_irr) / (k delta - a_c
   (M_an - M_irr))`` (zero when it would move against the anhysteretic), reversible part
   ``M = c M_an + (1 - c) M_irr``, ``y = w M``; loops that steepen towards the coercive field.
4. ``rate_kp``: rate-dependent Krasnosel'skii-Pokrovskii operator: a grid of 6 x 4 KP hysterons (Krasnosel'skii &
   Pokrovskii 1989; ramp hysterons, each the state ``z`` in [-1, 1] clamped between an ascending ramp that starts at
   ``alpha`` and a descending ramp that ends at ``beta``, ramp width 0.8 (alpha - beta)) with centres
   ``(alpha + beta) / 2`` in 0.05-0.95 and half-widths 0.02-0.25, density ``exp(-(centre - m)^2 / (2 s1^2))
   exp(-half-width / s2)``, ``y = w sum p z / sum p``. The half-widths grow with the input rate,
   ``x (1 + c log10(1 + |du/dt| / r0))`` (a loop that widens by ``c`` per decade of rate, as PZT stacks do); when
   the rate falls (a hold), the hysterons that the narrower thresholds no longer hold relax towards them. It is a
   Preisach-class operator only at a fixed rate: none of the estimator's candidates has this rate dependence.

State vectors (``hs``, length ``NSTATE``) and parameter vectors (``hp``, length ``NPAR``) are plain float arrays
so that the kernel stays one compiled function; their layouts are documented per family below.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["FAMILIES", "NSTATE", "NPAR", "family_code", "truth_init", "truth_eval", "truth_commit", "truth_path"]

FAMILIES = ("preisach", "bouc_wen", "gpi", "jiles_atherton", "rate_kp")
NSTATE = 40
NPAR = 40
_DU = 2e-3   # largest input step of one explicit integration step of the differential families


def family_code(name: str) -> int:
    if name not in FAMILIES:
        raise ValueError(f"unknown truth hysteresis family {name!r}; expected one of {FAMILIES}")
    return FAMILIES.index(name)


# ---- 1: Bouc-Wen.  hp = [A, beta, gamma, n, w];  hs = [u, z] ----------------------------------------------------
@njit(cache=True)
def _bw_step(u, hs, hp):
    du_total = u - hs[0]
    m = int(math.ceil(abs(du_total) / _DU))
    z = hs[1]
    if m == 0:
        return z
    du = du_total / m
    A, be, ga, n = hp[0], hp[1], hp[2], hp[3]
    for _ in range(m):
        az = abs(z)
        s = 1.0 if du * z >= 0.0 else -1.0
        z += du * (A - az ** n * (be * s + ga))
    return z


# ---- 2: generalised PI.  hp = [a, b, c, w, tau, nr, r_0..r_(nr-1)];  hs = [u, z_0..z_(nr-1)] -------------------
@njit(cache=True)
def _gpi_env(u, hp):
    a, b, c = hp[0], hp[1], hp[2]
    ga = a * math.tanh(b * u)
    gd = a * math.tanh(b * u + c * u * u) / (1.0 + 0.5 * c)
    return ga, gd


@njit(cache=True)
def _gpi_out(u, hs, hp, store):
    ga, gd = _gpi_env(u, hp)
    nr = int(hp[5])
    num = 0.0
    den = 0.0
    for i in range(nr):
        r = hp[6 + i]
        lo = ga - r
        hi = max(gd + r, lo)
        z = min(max(hs[1 + i], lo), hi)
        if store:
            hs[1 + i] = z
        p = math.exp(-hp[4] * r)
        num += p * z
        den += p
    return hp[3] * num / den


# ---- 3: Jiles-Atherton.  hp = [Ms, a, k, c, a_c, u0, w];  hs = [u, M_irr] -----------------------------------------
@njit(cache=True)
def _langevin(x):
    if abs(x) < 1e-4:
        return x / 3.0
    return 1.0 / math.tanh(x) - 1.0 / x


@njit(cache=True)
def _ja_man(H, M, hp):
    return hp[0] * _langevin((H + hp[4] * M) / hp[1])


@njit(cache=True)
def _ja_step(u, hs, hp):
    """Integrate M_irr from hs[0] to u; returns (M_irr, M)."""
    k, c, ac, u0 = hp[2], hp[3], hp[4], hp[5]
    du_total = u - hs[0]
    m = int(math.ceil(abs(du_total) / _DU))
    mi = hs[1]
    H = hs[0] - u0
    M = mi
    # reversible + irreversible magnetisation at the start (fixed point of M = c Man(M) + (1-c) Mi, 3 sweeps)
    for _ in range(3):
        M = c * _ja_man(H, M, hp) + (1.0 - c) * mi
    if m > 0:
        dH = du_total / m
        delta = 1.0 if dH > 0 else -1.0
        for _ in range(m):
            man = _ja_man(H, M, hp)
            diff = man - mi
            dmi = 0.0
            if diff * delta > 0.0:
                den = k * delta - ac * diff
                if den * delta > 0.0:
                    dmi = diff / den * dH
            mi += dmi
            H += dH
            for _ in range(2):
                M = c * _ja_man(H, M, hp) + (1.0 - c) * mi
    return mi, M


# ---- 4: rate-dependent KP.  hp = [w, m, s1, s2, c, r0];  hs = [u, z_0..z_(KP_N-1)] ------------------------------
KP_CENTRES = 6
KP_WIDTHS = 4
KP_N = KP_CENTRES * KP_WIDTHS


@njit(cache=True)
def _kp_out(u, dt, hs, hp, store):
    """Output of the KP grid at input ``u`` reached from ``hs[0]`` in ``dt`` seconds (``dt <= 0``: at rest, the
    rate-independent thresholds); with ``store`` the hysteron states are updated."""
    widen = 1.0
    if dt > 0.0:
        widen = 1.0 + hp[4] * math.log10(1.0 + abs(u - hs[0]) / dt / hp[5])
    num = 0.0
    den = 0.0
    for i in range(KP_CENTRES):
        c = 0.05 + 0.9 * i / (KP_CENTRES - 1)
        for j in range(KP_WIDTHS):
            h0 = 0.02 + 0.23 * j / (KP_WIDTHS - 1)
            h = h0 * widen
            a = c + h
            b = c - h
            d = 1.6 * h   # ramp width 0.8 (alpha - beta): the ascending ramp stays below the descending one
            ra = min(max(2.0 * (u - a) / d + 1.0, -1.0), 1.0)
            rd = min(max(2.0 * (u - b) / d - 1.0, -1.0), 1.0)
            k = 1 + i * KP_WIDTHS + j
            z = min(max(hs[k], ra), rd)
            if store:
                hs[k] = z
            p = math.exp(-0.5 * (c - hp[1]) ** 2 / hp[2] ** 2 - h0 / hp[3])
            num += p * z
            den += p
    return hp[0] * num / den


# ---- dispatch -----------------------------------------------------------------------------------------------------
@njit(cache=True)
def truth_eval(fam, u, hs, hp, dt):
    """Output y [V] at input u, reached from the state's input in ``dt`` seconds (the rate-dependent family; ``dt <=
    0``: at rest), without changing the state."""
    if fam == 1:
        return hp[4] * _bw_step(u, hs, hp)
    if fam == 2:
        return _gpi_out(u, hs, hp, False)
    if fam == 3:
        mi, M = _ja_step(u, hs, hp)
        return hp[6] * M
    if fam == 4:
        return _kp_out(u, dt, hs, hp, False)
    return 0.0


@njit(cache=True)
def truth_commit(fam, u, hs, hp, dt):
    """Move the state to input u in ``dt`` seconds (see :func:`truth_eval`); returns y [V]."""
    if fam == 1:
        z = _bw_step(u, hs, hp)
        hs[0] = u
        hs[1] = z
        return hp[4] * z
    if fam == 2:
        y = _gpi_out(u, hs, hp, True)
        hs[0] = u
        return y
    if fam == 3:
        mi, M = _ja_step(u, hs, hp)
        hs[0] = u
        hs[1] = mi
        return hp[6] * M
    if fam == 4:
        y = _kp_out(u, dt, hs, hp, True)
        hs[0] = u
        return y
    return 0.0


@njit(cache=True)
def truth_init(fam, hs, hp):
    """Relaxed initial state at u = 0 (anhysteretic for Jiles-Atherton, zero internal state otherwise); y(0)."""
    for i in range(hs.size):
        hs[i] = 0.0
    if fam == 3:
        # anhysteretic state at H = -u0: M_irr = M_an
        H = -hp[5]
        M = 0.0
        for _ in range(50):
            M = _ja_man(H, M, hp)
        hs[1] = M
    if fam == 4:
        for k in range(1, 1 + KP_N):
            hs[k] = -1.0   # every hysteron down: the relaxed state below all thresholds
        return _kp_out(0.0, 0.0, hs, hp, True)
    return truth_eval(fam, 0.0, hs, hp, 0.0)


@njit(cache=True)
def _path(fam, u, hp, dt):
    hs = np.zeros(NSTATE)
    truth_init(fam, hs, hp)
    y = np.empty(u.size)
    for i in range(u.size):
        y[i] = truth_commit(fam, u[i], hs, hp, dt)
    return y


def truth_path(family: str, u, hp, dt: float = 2.5e-3) -> np.ndarray:
    """Output y [V] of a non-Preisach family along the input path u (one sample every ``dt`` seconds: the rate of
    the rate-dependent family) from the relaxed state (for tests, docs)."""
    fam = family_code(family)
    if fam == 0:
        raise ValueError("truth_path: use selfsense.sim.preisach.preisach_path for the Preisach family")
    hp = np.zeros(NPAR) if hp is None else _pad(hp)
    return _path(fam, np.ascontiguousarray(u, dtype=float), hp, float(dt))


def _pad(hp) -> np.ndarray:
    hp = np.asarray(hp, dtype=float).ravel()
    if hp.size > NPAR:
        raise ValueError(f"truth parameters: at most {NPAR} values, got {hp.size}")
    out = np.zeros(NPAR)
    out[:hp.size] = hp
    return out
