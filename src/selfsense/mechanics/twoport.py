"""Two-port (quasistatic) models of the nested strain-amplification mechanism.

Seeds: thesis ``000_18d138f03f1777c3.txt`` eqs. (1)-(21).

Sign convention (used everywhere in this module; it is the one that makes the thesis'
symmetric matrix (8) a real stiffness matrix):

* Each port has a displacement ``x`` [m] and an *external* force ``F`` [N] applied by the
  outside world ON the mechanism at that port, positive in the direction of ``x``.
* The output displacement of a rhomboid is positive in the direction the output moves
  when the input (PZT) expands with the output free.
* Stiffness form (thesis eq. 8 read with this convention)::

      [F_in ]   [s1 s3] [x_in ]
      [F_out] = [s3 s2] [x_out]        K = [[s1, s3], [s3, s2]] symmetric PSD

  so ``s1 > 0``, ``s2 > 0`` and, for an amplifier that moves its output "forward",
  ``s3 < 0`` (thesis Table 2(b): S1 > 0, S2 > 0, S3 < 0).
* Transmission form (thesis eq. 17 form) maps ``[x_in, F_in] -> [x_out, F_out]``::

      T(s) = [[-s1/s3,            1/s3 ],
              [ s3 - s1*s2/s3,    s2/s3]]            det T = -1

Deviations from the printed thesis (documented in docs/mechanics.md):

* eq. (6)/(9): the printed s1 has the wrong overall sign (the force the PZT applies on
  the rhomboid is ``+k_BI (x_pzt - x_c)``) and a missing square (``k_BI**2 / D``).
  With the printed (negative) s1 and s2, matrix (8) is ``-K``; we return ``+K``.
* eq. (19): the printed lever matrix is the *stiffness*-form formula (17) applied to the
  *compliance* matrix (13); it does not satisfy (13). :func:`lever_transmission`
  returns the transmission that does.
* eq. (20): at a junction the force the upstream layer feels (``F_out`` of layer i) is
  minus the force applied on the downstream layer (``F_in`` of layer i+1), so a cascade
  is ``T_N J ... J T_2 J T_1`` with ``J = diag(1, -1)``, not the plain product printed
  in (20). (``J T(s) J = T(-s)``: the plain product is right only if every other layer's
  s-parameters are negated.)  :func:`cascade` inserts ``J``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "rhomboid_s_parameters",
    "stiffness_to_transmission",
    "transmission_to_stiffness",
    "series_identical",
    "series_general",
    "lever_compliances",
    "lever_transmission",
    "lever_transmission_printed",
    "cascade",
    "JUNCTION",
    "TwoPort",
]

#: Sign flip applied between cascaded stages (force continuity F_in[i+1] = -F_out[i]).
JUNCTION = np.diag([1.0, -1.0])


def rhomboid_s_parameters(k_BI: float, k_BO: float, k_J: float, a: float) -> tuple[float, float, float]:
    """Condensed stiffness (s1, s2, s3) [N/m] of the Ueda-Secord-Asada lumped rhomboid.

    Thesis ``000_18d138f03f1777c3.txt`` eqs. (1)-(11). Lumped springs [N/m]: ``k_BI`` (input
    beam), ``k_BO`` (output beam), ``k_J`` (joint to ground); ``a`` [-] is the kinematic
    amplification of the internal node x_c. Strain energy
    ``U = k_BI (x_in - x_c)^2/2 + k_J x_c^2/2 + k_BO (a x_c - x_out)^2/2``; eq. (2) is
    ``dU/dx_c = 0`` (eq. 4), and the port forces are ``F = dU/dx``. With
    ``D = k_J + k_BI + a^2 k_BO``::

        s1 = k_BI - k_BI^2/D          (printed eq. 9: -k_BI + k_BI/D, sign and square wrong)
        s2 = k_BO - a^2 k_BO^2/D      (eq. 10 negated: external-force convention)
        s3 = -a k_BO k_BI / D         (eq. 11 negated)

    Returned in the module's external-force convention (K = [[s1, s3], [s3, s2]] PSD).
    """
    D = k_J + k_BI + a * a * k_BO
    s1 = k_BI - k_BI * k_BI / D
    s2 = k_BO - a * a * k_BO * k_BO / D
    s3 = -a * k_BO * k_BI / D
    return float(s1), float(s2), float(s3)


def stiffness_to_transmission(s1: float, s2: float, s3: float) -> np.ndarray:
    """Transmission matrix (thesis eq. 17 form): ``[x_in, F_in] -> [x_out, F_out]``.

    ``T = [[-s1/s3, 1/s3], [s3 - s1 s2/s3, s2/s3]]``; requires ``s3 != 0``; ``det T = -1``.
    Units: T11 [-], T12 [m/N], T21 [N/m], T22 [-].
    """
    if s3 == 0:
        raise ValueError("s3 == 0: ports are decoupled, no transmission matrix exists")
    return np.array([[-s1 / s3, 1.0 / s3], [s3 - s1 * s2 / s3, s2 / s3]], dtype=float)


def transmission_to_stiffness(T) -> tuple[float, float, float]:
    """Inverse of :func:`stiffness_to_transmission`: ``T -> (s1, s2, s3)``.

    Raises ``ValueError`` if ``det T != -1`` (to 1e-9 relative), i.e. if T is not the
    transmission of a reciprocal (symmetric-stiffness) two-port in this convention.
    """
    T = np.asarray(T, dtype=float)
    if T.shape != (2, 2):
        raise ValueError(f"T must be 2x2, got {T.shape}")
    a, b, c, d = T[0, 0], T[0, 1], T[1, 0], T[1, 1]
    if b == 0:
        raise ValueError("T[0,1] == 0: not the transmission of a coupled two-port")
    det = a * d - b * c
    scale = max(abs(a * d), abs(b * c), 1.0)
    if abs(det + 1.0) > 1e-9 * scale:
        raise ValueError(f"det T = {det!r} != -1: not a reciprocal two-port in this convention")
    s3 = 1.0 / b
    return float(-a * s3), float(d * s3), float(s3)


def series_identical(s1: float, s2: float, s3: float, n: int) -> tuple[float, float, float]:
    """n identical rhomboids: inputs in parallel (common x_in), outputs in series.

    Thesis ``000_18d138f03f1777c3.txt`` text around eq. (20) (Figs. 10-11):
    ``(s1, s2, s3) -> (n s1, s2/n, s3)``. Input force = sum of the n input forces,
    input displacement = the common x_in, output displacement = sum of the n output
    strokes, output force = the common series force.

    Exact (verified in tests against the full lumped network with one internal node per
    rhomboid) **iff** the n rhomboids have identical s-parameters and identical input
    displacements (common rigid input, or identical PZTs at identical voltage: then the
    symmetric solution is the unique one). For non-identical rhomboids with a common input,
    see :func:`series_general` (the claim then fails).
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    return float(n * s1), float(s2 / n), float(s3)


def series_general(params) -> tuple[float, float, float]:
    """Rhomboids with common input displacement and outputs in series, possibly different.

    ``params``: iterable of (s1, s2, s3). Each carries the same output force F:
    ``x_out_i = (F - s3_i x_in)/s2_i``. Result:
    ``S2 = 1/sum(1/s2_i)``, ``S3 = S2 sum(s3_i/s2_i)``,
    ``S1 = sum(s1_i) - sum(s3_i^2/s2_i) + S3^2/S2``. Reduces to :func:`series_identical`
    when all are equal.
    """
    p = np.asarray(list(params), dtype=float).reshape(-1, 3)
    s1, s2, s3 = p[:, 0], p[:, 1], p[:, 2]
    S2 = 1.0 / np.sum(1.0 / s2)
    S3 = S2 * np.sum(s3 / s2)
    S1 = np.sum(s1) - np.sum(s3 * s3 / s2) + S3 * S3 / S2
    return float(S1), float(S2), float(S3)


def lever_compliances(C_A, C_B, E: float, I) -> tuple[float, float, float]:
    """Lever-arm compliances (Q1, Q2, Q3) [m/N], thesis eqs. (14)-(16).

    ``C_A = (C_A1, C_A2, C_A3, C_A4)``, ``C_B = (C_B1, ..., C_B4[, C_B5])`` are the
    Castigliano coefficients [m^3] (C_B5 is listed in the thesis but unused by (16)),
    ``E`` [Pa], ``I = (I1, I2, I3)`` [m^4]::

        Q1 = C_A2/(2 E I1) + C_A4/(2 E I3)
        Q3 = C_A1/(2 E I1) + C_A3/(2 E I3)
        Q2 = C_B1/(2 E I1) + C_B3/(2 E I2) + C_B4/(2 E I3)
    """
    CA1, CA2, CA3, CA4 = (float(v) for v in list(C_A)[:4])
    CB = [float(v) for v in C_B]
    I1, I2, I3 = (float(v) for v in I)
    Q1 = CA2 / (2 * E * I1) + CA4 / (2 * E * I3)
    Q3 = CA1 / (2 * E * I1) + CA3 / (2 * E * I3)
    Q2 = CB[0] / (2 * E * I1) + CB[2] / (2 * E * I2) + CB[3] / (2 * E * I3)
    return Q1, Q2, Q3


def lever_transmission(Q1: float, Q2: float, Q3: float) -> np.ndarray:
    """Transmission ``[x_2, f_2] -> [x_tip, f_tip]`` of the compliance two-port (13).

    Thesis eq. (13): ``[x_2, x_tip] = [[Q1, Q3], [Q3, Q2]] [f_2, f_tip]`` (Castigliano:
    external forces, displacements along them). Solving (13)::

        T = [[Q2/Q3, Q3 - Q1 Q2/Q3],
             [1/Q3,  -Q1/Q3       ]]  == stiffness_to_transmission(*inv(Q))

    The printed eq. (19) (see :func:`lever_transmission_printed`) instead applies the
    stiffness formula (17) to the compliances and does not satisfy (13).
    """
    if Q3 == 0:
        raise ValueError("Q3 == 0: lever ports decoupled")
    return np.array([[Q2 / Q3, Q3 - Q1 * Q2 / Q3], [1.0 / Q3, -Q1 / Q3]], dtype=float)


def lever_transmission_printed(Q1: float, Q2: float, Q3: float) -> np.ndarray:
    """Thesis eq. (19) exactly as printed (kept only to document that it is inconsistent)."""
    return stiffness_to_transmission(Q1, Q2, Q3)


def cascade(*transmissions) -> np.ndarray:
    """Cascade transmissions, first (innermost, PZT side) first: thesis eqs. (20)-(21).

    Returns ``T_N J ... J T_2 J T_1`` with ``J = diag(1, -1)``: at each junction the
    external force on the downstream input equals minus the external force on the upstream
    output (action-reaction). Verified in tests against the direct solve of two and three
    nested lumped networks. The printed (20) omits ``J`` (see module docstring).
    """
    if not transmissions:
        raise ValueError("cascade needs at least one transmission matrix")
    out = np.asarray(transmissions[0], dtype=float)
    for T in transmissions[1:]:
        out = np.asarray(T, dtype=float) @ JUNCTION @ out
    return out


@dataclass(frozen=True)
class TwoPort:
    """Reciprocal quasistatic two-port with stiffness ``[[s1, s3], [s3, s2]]`` [N/m].

    External-force convention of this module (``F = K x``, both forces applied on the
    mechanism). Thesis ``000_18d138f03f1777c3.txt`` eqs. (8), (17), (20)-(21).
    """

    s1: float
    s2: float
    s3: float

    @classmethod
    def rhomboid(cls, k_BI, k_BO, k_J, a) -> "TwoPort":
        return cls(*rhomboid_s_parameters(k_BI, k_BO, k_J, a))

    @classmethod
    def from_transmission(cls, T) -> "TwoPort":
        return cls(*transmission_to_stiffness(T))

    @classmethod
    def from_compliance(cls, Q1, Q2, Q3) -> "TwoPort":
        K = np.linalg.inv(np.array([[Q1, Q3], [Q3, Q2]], dtype=float))
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 1]))

    def stiffness_matrix(self) -> np.ndarray:
        return np.array([[self.s1, self.s3], [self.s3, self.s2]], dtype=float)

    def transmission(self) -> np.ndarray:
        return stiffness_to_transmission(self.s1, self.s2, self.s3)

    def series(self, n: int) -> "TwoPort":
        return TwoPort(*series_identical(self.s1, self.s2, self.s3, n))

    def then(self, other: "TwoPort") -> "TwoPort":
        """``self`` drives ``other`` (self's output is other's input)."""
        return TwoPort.from_transmission(cascade(self.transmission(), other.transmission()))

    def is_passive(self, rtol: float = 1e-12) -> bool:
        """True if the stiffness matrix is positive semidefinite (stores no energy source)."""
        ev = np.linalg.eigvalsh(self.stiffness_matrix())
        return bool(ev.min() >= -rtol * max(abs(ev).max(), 1e-300))

    def tuple(self) -> tuple[float, float, float]:
        return (self.s1, self.s2, self.s3)
