"""ISPH's `isph.density: continuity` (experimental): each particle carries its own density, changed by the
divergence of its motion and of its shift, rho_a <- rho_a / det(I + grad u_a) (physics/density.py
deformation_density), instead of the summation density. docs/isph.md says what it does to a wave and a drop.
"""

import taichi as ti

from taichi_sph.physics.density import MIN_MOMENT_DETERMINANT, corrected_gradient_pair_terms, deformation_density
from taichi_sph.scene.bodies import FLUID


@ti.data_oriented
class ContinuityDensity:
    """`rho` (persistent, rho0 at the start) moved by `deform_by_motion(dt)` (in the correction kernel,
    before x += dt v) and `deform_by_shift()` (after the shift is computed, before it is applied)."""

    def __init__(self, solver) -> None:
        self.solver = solver
        P = solver.particles
        self.rho = P.add_scalar(persistent=True)
        self.rho.fill(solver.rho0)
        self.displacement = P.add_vector()  # the motion whose divergence changes rho

    @ti.func
    def deform_by_motion(self, dt):
        """u = dt v (this step's move) at the positions before it."""
        P = self.solver.particles
        for a in range(self.solver.n):
            if self.solver.live():
                self.displacement[a] = dt * P.v[a] if P.kind[a] == FLUID else ti.Vector.zero(float, self.solver.dim)
        self.deform()

    @ti.kernel
    def deform_by_shift(self):
        """u = the particle shift (computed, not yet applied): its divergence changes the volumes."""
        P = self.solver.particles
        for a in range(self.solver.n):
            if self.solver.live():
                self.displacement[a] = (self.solver.shifting.shift[a] if P.kind[a] == FLUID
                                        else ti.Vector.zero(float, self.solver.dim))
        self.deform()

    @ti.func
    def deform(self):
        """rho_a /= det(I + grad u_a): the corrected gradient over fluid and wall neighbours (walls do not move),
        the lattice-normalised one where the moment matrix is near singular."""
        S = self.solver
        P = S.particles
        for a in range(S.n):
            if S.live() and P.kind[a] == FLUID:
                sums = ti.Struct(u_a=self.displacement[a], s=ti.Matrix.zero(float, S.dim, S.dim),
                                 moment=ti.Matrix.zero(float, S.dim, S.dim))
                S.nsearch.for_each_neighbor(a, P.x, self.deformation_pair, sums)
                grad_u = sums.s * S.grad_norm
                if ti.abs(sums.moment.determinant()) > MIN_MOMENT_DETERMINANT:
                    grad_u = sums.s @ sums.moment.inverse()
                self.rho[a] = deformation_density(self.rho[a], grad_u)

    @ti.func
    def deformation_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s share of sum_b V_b (u_b - u_a) (x) grad W and of the moment matrix."""
        S = self.solver
        P = S.particles
        grad_w = S.kernel.grad_w(r_ab, r_ab.norm())
        u_b = ti.Vector.zero(float, S.dim)
        if P.kind[b] == FLUID:
            u_b = self.displacement[b]
        s_ab, m_ab = corrected_gradient_pair_terms(P.mass[b] / S.rho0, sums.u_a - u_b, r_ab, grad_w)
        sums.s += s_ab
        sums.moment += m_ab
