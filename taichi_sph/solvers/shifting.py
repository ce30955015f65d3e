"""Particle shifting (Lind et al. 2012; Skillen et al. 2013 diffusion coefficient), free-surface aware."""


import taichi as ti

from ..geometry import FLUID, lattice_kernel_sum


@ti.data_oriented
class ParticleShifting:
    """dr_a = -D grad C_a, grad C_a = sum_b V_b grad W_ab (1 + 0.2 (W_ab / W(dx))^4), D = A h |v_a| dt.

    Particles whose kernel sum falls below `free_surface_threshold` x the full-lattice sum are at the
    free surface: their shift keeps only the component tangent to the surface (normal ~ grad C).
    """

    def __init__(self, solver, coefficient: float) -> None:
        cfg = solver.cfg
        self.solver = solver
        self.coefficient = coefficient
        self.max_shift = cfg.shifting.max_shift * cfg.particles.dx
        self.lattice_sum = lattice_kernel_sum(cfg, solver.kernel.w_np)
        self.threshold = cfg.isph.free_surface_threshold
        import numpy as np
        self.w_dx = float(solver.kernel.w_np(np.array([cfg.particles.dx]))[0])
        self.shift = solver.particles.add_vector()

    @ti.kernel
    def compute(self, dt: float):
        self.compute_pass(dt, False)

    @ti.kernel
    def move(self):
        self.move_pass(False)

    @ti.func
    def compute_pass(self, dt, serial: ti.template()):
        """shift_a for every fluid particle (the pass a solver's own kernels call)."""
        S = self.solver
        P = S.particles
        NS = S.nsearch
        ti.loop_config(serialize=serial)
        for a in range(S.live_n()):
            self.shift[a] = ti.Vector.zero(float, S.dim)
            if P.kind[a] == FLUID:
                xa = P.x[a]
                grad_c = ti.Vector.zero(float, S.dim)
                ksum = P.mass[a] / P.rho[a] * S.kernel.w0
                for k in range(NS.count[a]):
                    b = NS.neighbors[a, k]
                    r_ab = NS.pair_vector(xa, P.x[b])
                    r = r_ab.norm()
                    w = S.kernel.w(r)
                    vol_b = P.mass[b] / P.rho[b]
                    ksum += vol_b * w
                    grad_c += vol_b * (1.0 + 0.2 * ti.pow(w / self.w_dx, 4.0)) * S.kernel.grad_w(r_ab, r)
                d = self.coefficient * S.h * P.v[a].norm() * dt
                dr = -d * grad_c
                if ksum < self.threshold * self.lattice_sum:
                    n = grad_c.normalized(1e-12)
                    dr -= dr.dot(n) * n
                length = dr.norm()
                if length > self.max_shift:
                    dr *= self.max_shift / length
                self.shift[a] = dr

    @ti.func
    def move_pass(self, serial: ti.template()):
        """x_a += shift_a (fluid)."""
        S = self.solver
        P = S.particles
        ti.loop_config(serialize=serial)
        for a in range(S.live_n()):
            if P.kind[a] == FLUID:
                P.x[a] += self.shift[a]

    def apply(self, dt: float) -> None:
        """Shift fluid particles using the neighbour lists of this step (positions moved by at most 0.1 dx)."""
        self.compute(dt)
        self.move()
