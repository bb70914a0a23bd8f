"""Direct solver for lumped spring networks (reference for the two-port algebra).

A network is a list of generalized springs ``(k, {dof: weight})``: elongation
``e = sum(weight * u[dof])`` (ground DOFs are simply omitted), energy ``k e^2 / 2``.
Thesis 000_18d138f03f1777c3.txt eqs. (1)-(3) are such a network with springs
k_BI: x_in - x_c, k_J: x_c, k_BO: a x_c - x_out.
"""
from __future__ import annotations

import numpy as np


class Network:
    def __init__(self):
        self.dofs: list[str] = []
        self.springs: list[tuple[float, dict]] = []
        self.blocks: list[tuple[np.ndarray, list[str]]] = []

    def dof(self, name: str) -> str:
        if name not in self.dofs:
            self.dofs.append(name)
        return name

    def spring(self, k: float, **w):
        for d in w:
            self.dof(d)
        self.springs.append((float(k), dict(w)))

    def element(self, K, names):
        """A 2-DOF (or n-DOF) stiffness block, e.g. a lever given by its compliance."""
        for d in names:
            self.dof(d)
        self.blocks.append((np.asarray(K, dtype=float), list(names)))

    def rhomboid(self, k_BI, k_BO, k_J, a, x_in, c, x_out_plus, x_out_minus=None):
        """Eqs. (1)-(3); output elongation = x_out_plus - x_out_minus (None = ground)."""
        self.spring(k_BI, **{x_in: 1.0, c: -1.0})
        self.spring(k_J, **{c: 1.0})
        w = {c: a, x_out_plus: -1.0}
        if x_out_minus is not None:
            w[x_out_minus] = 1.0
        self.spring(k_BO, **w)

    def K(self) -> np.ndarray:
        n = len(self.dofs)
        idx = {d: i for i, d in enumerate(self.dofs)}
        K = np.zeros((n, n))
        for k, w in self.springs:
            v = np.zeros(n)
            for d, wt in w.items():
                v[idx[d]] += wt
            K += k * np.outer(v, v)
        for Kb, names in self.blocks:
            ii = [idx[d] for d in names]
            K[np.ix_(ii, ii)] += Kb
        return K

    def solve(self, prescribed: dict, forces: dict | None = None):
        """Prescribe displacements of some DOFs, external forces on the others (default 0).
        Returns (u, F) dicts: all displacements and the external force at every DOF."""
        forces = forces or {}
        K = self.K()
        idx = {d: i for i, d in enumerate(self.dofs)}
        p = [idx[d] for d in prescribed]
        f = [i for i in range(len(self.dofs)) if i not in p]
        u = np.zeros(len(self.dofs))
        u[p] = [prescribed[d] for d in prescribed]
        rhs = np.array([forces.get(self.dofs[i], 0.0) for i in f]) - K[np.ix_(f, p)] @ u[p]
        u[f] = np.linalg.solve(K[np.ix_(f, f)], rhs)
        F = K @ u
        return dict(zip(self.dofs, u)), dict(zip(self.dofs, F))

    def port_stiffness(self, ports: list[str]) -> np.ndarray:
        """Port stiffness by direct solves: unit displacement at each port, others clamped,
        internal DOFs force-free (columns of the condensed stiffness)."""
        cols = []
        for j, pj in enumerate(ports):
            u, F = self.solve({p: (1.0 if p == pj else 0.0) for p in ports})
            cols.append([F[p] for p in ports])
        return np.array(cols).T
