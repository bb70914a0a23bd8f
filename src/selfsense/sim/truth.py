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

State vectors (``hs``, length ``NSTATE``) and parameter vectors (``hp``, length ``NPAR``) are plain float arrays
so that the kernel stays one compiled function; their layouts are documented per family below.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["FAMILIES", "NSTATE", "NPAR", "family_code", "truth_init", "truth_eval", "truth_commit", "truth_path"]

FAMILIES = ("preisach", "bouc_wen", "gpi", "jiles_atherton")
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


# ---- dispatch -----------------------------------------------------------------------------------------------------
@njit(cache=True)
def truth_eval(fam, u, hs, hp):
    """Output y [V] at input u without changing the state."""
    if fam == 1:
        return hp[4] * _bw_step(u, hs, hp)
    if fam == 2:
        return _gpi_out(u, hs, hp, False)
    if fam == 3:
        mi, M = _ja_step(u, hs, hp)
        return hp[6] * M
    return 0.0


@njit(cache=True)
def truth_commit(fam, u, hs, hp):
    """Move the state to input u; returns y [V]."""
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
    return truth_eval(fam, 0.0, hs, hp)


@njit(cache=True)
def _path(fam, u, hp):
    hs = np.zeros(NSTATE)
    truth_init(fam, hs, hp)
    y = np.empty(u.size)
    for i in range(u.size):
        y[i] = truth_commit(fam, u[i], hs, hp)
    return y


def truth_path(family: str, u, hp) -> np.ndarray:
    """Output y [V] of a non-Preisach family along the input path u from the relaxed state (for tests, docs)."""
    fam = family_code(family)
    if fam == 0:
        raise ValueError("truth_path: use selfsense.sim.preisach.preisach_path for the Preisach family")
    hp = np.zeros(NPAR) if hp is None else _pad(hp)
    return _path(fam, np.ascontiguousarray(u, dtype=float), hp)


def _pad(hp) -> np.ndarray:
    hp = np.asarray(hp, dtype=float).ravel()
    if hp.size > NPAR:
        raise ValueError(f"truth parameters: at most {NPAR} values, got {hp.size}")
    out = np.zeros(NPAR)
    out[:hp.size] = hp
    return out
