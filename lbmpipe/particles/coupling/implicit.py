"""The implicit velocity update of the free particles (stability at density ratio 1); lattice
units, ``dt = 1``. ``ladd.couple_free`` assembles the system per particle and solves it here.

The link force is linear in the particle's own velocity. Summed over the links,

    (F, T) = (F0, T0) - Z (U, Omega),   F0 = sum 2 e_i (f*_i(x) - w_i rho0),  T0 = sum r x (same),
    Z = sum_links 6 w_i rho0 [e_i; r x e_i] [e_i; r x e_i]^T     (6 x 6, symmetric, >= 0),

and an explicit update ``M dU = F`` is unstable once ``Z`` is comparable to the particle's mass
(light or small particles; neutrally buoyant particles without interior fluid). Velocities are
therefore advanced implicitly in this self-friction (Lowe, Frenkel & Masters 1995; Nguyen & Ladd
2002):

    (M + Z dt) V' = M V + (F0 + F_ext + P, T0 + L_P) dt,     V = (U, Omega_lab),

with ``M = diag(m, m, m, I_lab)``, ``I_lab = A diag(I) A^T``, ``F_ext`` the external force and
``(P, L_P)`` the impulse of the nodes covered and uncovered by the previous move (``remap``). The ghost
fill then uses the *new* velocity ``V'``, so the momentum the fluid loses through the links is
exactly what the particle gains, ``(F0, T0) - Z V'`` (plus the reference-pressure part, which
cancels between touching particles): fluid + particles conserve momentum to round-off. ``Z`` is
summed per direction from the link count, the sum of lever arms and the sum of their outer
products.

Time step (``dt = 1``): ``pre``: ``F0, T0, Z`` from ``f*(t)`` on the links at ``X(t)`` -> implicit
update to ``V(t+1)`` -> ghost fill with ``V(t+1)``; fluid sweep; ``post``: the torque-free motion
``rigid.drift_arrays`` over one step (``x += v``, the exact free rotation of Eqs. (13)-(15) that
carries the gyroscopic term and keeps ``|q| = 1``), then the remap. The kick is the implicit
angular-momentum update ``L' = L + T dt`` in the lab frame at the current orientation (Eq. (13)'s
torque term), the drift the rest: first order in time, like the link coupling itself.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def solve6(M):
    """Solve the 6x6 system held in ``M`` (6, 7) (matrix | right-hand side) in place by Gaussian
    elimination with partial pivoting; the solution ends in ``M[:, 6]``.

    Input: ``M`` (6, 7) float64, ``[M + Z | rhs]`` of the update above (symmetric positive definite
    for a particle with mass). Output: ``M[:, 6]`` the new ``(U, Omega_lab)``; the rest of ``M``
    is overwritten. No allocation: called once per particle inside the parallel coupling."""
    n = 6
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(M[r, col]) > abs(M[piv, col]):
                piv = r
        if piv != col:
            for c in range(n + 1):
                t = M[col, c]
                M[col, c] = M[piv, c]
                M[piv, c] = t
        d = M[col, col]
        for r in range(col + 1, n):
            fct = M[r, col] / d
            for c in range(col, n + 1):
                M[r, c] -= fct * M[col, c]
    for r in range(n - 1, -1, -1):
        acc = M[r, n]
        for c in range(r + 1, n):
            acc -= M[r, c] * M[c, n]
        M[r, n] = acc / M[r, r]

