"""Steady Stokes flow through a periodic channel past a square obstacle, on a MAC grid: the reference for the
channel scene in docs/notes/user_scenes.md (a flow no SPH scene here had an answer for).

    python scripts/stokes_channel_reference.py N [L H nu g x0 x1 y0 y1]

nu lap u - grad p + g e_x = 0, div u = 0 (rho = 1), periodic in x over L, no-slip walls at y = 0 and H and on the
obstacle [x0, x1] x [y0, y1] (grid-aligned: pick N so that h = L / N divides them). N x (H / h) cells; u on the
vertical faces, v on the horizontal ones, p at the centres; a wall halfway between two faces is the ghost -u, a
face on the obstacle's side holds 0. One sparse direct solve (scipy, not a dependency of the package). Prints the
flux, the fluid-mean u (what the SPH runs' mean over fluid particles measures: Q L / A_fluid) and the kinetic
energy per unit depth at rho0 1000. Defaults: the user scene (0.1 x 0.04 m, nu 1e-3, g 0.25, obstacle 0.045-0.055 x
0.015-0.025); N 100 / 200 / 400 / 800 give fluid-mean u 0.011649 / 0.011445 / 0.011362 / 0.011326 (first order
towards ~0.01130: the obstacle's corners) and an empty channel's Poiseuille mean g H^2 / (12 nu) to 0.1% at N 100.
"""

from __future__ import annotations

import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def solve(n_x: int, length: float, height: float, nu: float, g: float, obstacle: tuple[float, float, float, float]):
    """(u on vertical faces (n_x, n_y), v on horizontal faces (n_x, n_y + 1), solid cell mask, h)."""
    h = length / n_x
    n_y = int(round(height / h))
    xc, yc = (np.arange(n_x) + 0.5) * h, (np.arange(n_y) + 0.5) * h
    solid = np.zeros((n_x, n_y), bool)
    x0, x1, y0, y1 = obstacle
    solid[np.ix_((xc > x0) & (xc < x1), (yc > y0) & (yc < y1))] = True
    n_u, n_v = n_x * n_y, n_x * (n_y + 1)

    def uid(i, j):
        return (i % n_x) * n_y + j

    def vid(i, j):
        return n_u + (i % n_x) * (n_y + 1) + j

    def pid(i, j):
        return n_u + n_v + (i % n_x) * n_y + j

    def u_kind(i, j):  # 0 fluid face, 1 on the obstacle's side (u = 0 there), 2 inside it, 3 beyond a wall
        if j < 0 or j >= n_y:
            return 3
        return int(solid[(i - 1) % n_x, j]) + int(solid[i % n_x, j])

    def v_kind(i, j):
        if j < 0 or j > n_y:
            return 3
        if j == 0 or j == n_y:
            return 1
        return int(solid[i % n_x, j - 1]) + int(solid[i % n_x, j])

    rows, cols, vals = [], [], []
    size = n_u + n_v + n_x * n_y
    rhs = np.zeros(size)

    def add(r, c, v):
        rows.append(r)
        cols.append(c)
        vals.append(v)

    c = nu / h ** 2
    for kind, ident, n_j, pressure_pair, force in ((u_kind, uid, n_y, lambda i, j: (pid(i, j), pid(i - 1, j)), -g),
                                                  (v_kind, vid, n_y + 1, lambda i, j: (pid(i, j), pid(i, j - 1)), 0.0)):
        for i in range(n_x):
            for j in range(n_j):
                r = ident(i, j)
                if kind(i, j) > 0:
                    add(r, r, 1.0)
                    continue
                diag = -4.0 * c
                for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                    k = kind(i + di, j + dj)
                    if k == 0:
                        add(r, ident(i + di, j + dj), c)
                    elif k >= 2:
                        diag -= c  # a wall halfway: the ghost value -u
                add(r, r, diag)
                hi, lo = pressure_pair(i, j)
                add(r, hi, -1.0 / h)
                add(r, lo, 1.0 / h)
                rhs[r] = force
    pinned = False
    for i in range(n_x):
        for j in range(n_y):
            r = pid(i, j)
            if solid[i, j] or not pinned:
                add(r, r, 1.0)  # no pressure in the obstacle; one fluid cell pins the constant
                pinned = pinned or not solid[i, j]
                continue
            add(r, uid(i + 1, j), 1.0 / h)
            add(r, uid(i, j), -1.0 / h)
            add(r, vid(i, j + 1), 1.0 / h)
            add(r, vid(i, j), -1.0 / h)
    x = spla.spsolve(sp.csr_matrix((vals, (rows, cols)), shape=(size, size)).tocsc(), rhs)
    return x[:n_u].reshape(n_x, n_y), x[n_u:n_u + n_v].reshape(n_x, n_y + 1), solid, h


def main(argv: list[str]) -> None:
    n_x = int(argv[0]) if argv else 200
    length, height, nu, g, *obstacle = [float(a) for a in argv[1:]] or [0.1, 0.04, 1e-3, 0.25, 0.045, 0.055, 0.015, 0.025]
    u, v, solid, h = solve(n_x, length, height, nu, g, tuple(obstacle))
    flux = float(u[0].sum() * h)
    area = length * height - (obstacle[1] - obstacle[0]) * (obstacle[3] - obstacle[2])
    uc, vc = 0.5 * (u + np.roll(u, -1, axis=0)), 0.5 * (v[:, :-1] + v[:, 1:])
    ke = 0.5 * 1000.0 * float(((uc ** 2 + vc ** 2) * h * h)[~solid].sum())
    print(f"N {n_x} h {h:g}: flux {flux:.6e} m^2/s, fluid-mean u {flux * length / area:.6f} m/s, max u {u.max():.5f} "
          f"m/s, kinetic energy (rho 1000) {ke:.4e} J/m; empty channel's mean {g * height ** 2 / (12 * nu):.5f}")


if __name__ == "__main__":
    main(sys.argv[1:])
