"""Small 3x3 linear algebra on Dr.Jit arrays that Dr.Jit does not ship.

Dr.Jit 1.5 has `dr.polar_decomp` (iterative) but no eigen- or singular-value decomposition.
`sym_eig3` is a cyclic Jacobi eigen-solver with a fixed number of sweeps (branch-free, so it
vectorises over particles and stays differentiable almost everywhere); the MPM's plasticity
return mapping uses it on the left Cauchy-Green tensor b = F Fᵀ.
"""

from __future__ import annotations

import drjit as dr

_PAIRS = ((0, 1, 2), (0, 2, 1), (1, 2, 0))  # (p, q, r): rotate in the p-q plane, r the other


def sym_eig3(A, sweeps: int = 5):
    """Eigen-decomposition of symmetric 3x3 matrices A = Q diag(λ) Qᵀ.

    A: Matrix3f [N] (only the upper triangle is read).
    Returns (λ: list of 3 Float [N], unsorted; Q: Matrix3f [N], eigenvectors in columns).
    Five sweeps reach float32 round-off for well-scaled matrices (quadratic convergence).
    """
    Matrix3f = type(A)
    a = [[A[i, j] for j in range(3)] for i in range(3)]
    for i in range(3):
        for j in range(i):
            a[i][j] = a[j][i]
    Q = dr.identity(Matrix3f)
    q = [[Q[i, j] for j in range(3)] for i in range(3)]
    for _ in range(sweeps):
        for p, s_, r in _PAIRS:
            apq = a[p][s_]
            small = dr.abs(apq) < 1e-30
            safe = dr.select(small, 1.0, apq)
            theta = (a[s_][s_] - a[p][p]) / (2.0 * safe)
            t = dr.copysign(1.0, theta) / (dr.abs(theta) + dr.sqrt(theta * theta + 1.0))
            t = dr.select(small, 0.0, t)
            c = dr.rsqrt(t * t + 1.0)
            s = t * c
            app, aqq = a[p][p] - t * apq, a[s_][s_] + t * apq
            arp, arq = a[r][p], a[r][s_]
            a[p][p], a[s_][s_] = app, aqq
            a[p][s_] = a[s_][p] = apq * 0.0  # (no width literal: safe under dr.freeze)
            a[r][p] = a[p][r] = c * arp - s * arq
            a[r][s_] = a[s_][r] = s * arp + c * arq
            for k in range(3):
                vkp, vkq = q[k][p], q[k][s_]
                q[k][p] = c * vkp - s * vkq
                q[k][s_] = s * vkp + c * vkq
    Q = Matrix3f(*[q[i][j] for i in range(3) for j in range(3)])
    return [a[0][0], a[1][1], a[2][2]], Q


def diag_conjugate(Q, d):
    """Q diag(d) Qᵀ for Q Matrix3f [N] and d a list of 3 Float [N]."""
    Matrix3f = type(Q)
    D = Matrix3f(d[0], 0, 0, 0, d[1], 0, 0, 0, d[2])
    return Q @ D @ Q.T


def outer(a, b, Matrix3f):
    """a bᵀ for Array3f a, b -> Matrix3f."""
    return Matrix3f(
        a.x * b.x, a.x * b.y, a.x * b.z,
        a.y * b.x, a.y * b.y, a.y * b.z,
        a.z * b.x, a.z * b.y, a.z * b.z,
    )  # fmt: skip
