"""ISPH's first pass of a step: the summation density, which fluid particles are at the free surface (kernel sum,
cone scan, spray on a wall, one-sided ratio: physics/free_surface.py) and their Dirichlet pressure (physics/ppe_terms.py
free_surface_pressure), with the estimate of grad p = rho0 (g - a) that the rows near the surface continue the
pressure with. A mixin of ISPHSolver: its methods read the solver's fields and settings.
"""

import taichi as ti

from taichi_sph.linalg.ppe import DIRICHLET, N_DIRICHLET, NOT_IN_PPE, UNKNOWN
from taichi_sph.physics.density import MIN_MOMENT_DETERMINANT, corrected_gradient_pair_terms
from taichi_sph.physics.free_surface import (
    SURFACE_CANDIDATE,
    in_surface_cone,
    isolated_from_fluid,
    linear_fit_at_particle,
    projection_self_ratio,
    strained_surface_depth,
)
from taichi_sph.physics.momentum import particle_noise_rate, renormalised_velocity_gradient
from taichi_sph.physics.ppe_terms import free_surface_pressure
from taichi_sph.scene.bodies import FLUID, WALL


@ti.data_oriented
class FreeSurfaceDetection:
    """detect_free_surface (each step) and floor_surface_band_density (the initial state's density); a fluid
    that fills its container at the start is confined: no particle is ever free-surface (`find_confinement`)."""

    # decided from the scene's initial state by `find_confinement` (prepare, before a checkpoint is restored)
    transient_state = ("surface_possible",)

    def init_free_surface_detection(self) -> None:
        """The confinement flag (i32, 1 until `find_confinement` says otherwise)."""
        self.surface_possible = ti.field(ti.i32, shape=())
        self.surface_possible[None] = 1

    def find_confinement(self) -> None:
        """After the initial state's detection: no free-surface particle means the fluid fills its container
        (walls that do not move, periodic sides). Incompressible, it fills it for the whole run, so a particle
        that later looks free-surface (a transient void next to a wall, a corner the fluid is dragged away from)
        is not one; made a Dirichlet particle it would turn the pure-Neumann system into one pinned at that
        particle and drain the whole fluid's density-invariance source through it (the lid-driven cavity,
        nx 50: pressure level +86 in one step, 3.4 m/s under a 1 m/s lid, non-finite at t = 1.5 s)."""
        if self.ppe.scalars[N_DIRICHLET] == 0.0:
            self.surface_possible[None] = 0

    @property
    def confined(self) -> bool:
        """Whether the fluid fills its container (no free-surface detection: `find_confinement`)."""
        return self.surface_possible[None] == 0

    @ti.kernel
    def detect_free_surface(self):
        """Summation density, free-surface role and Dirichlet pressure (see the module doc)."""
        P = self.particles
        E = self.ppe
        if self.live():  # (a step a batch skips: live 0, isph_loop.py)
            E.scalars[N_DIRICHLET] = 0.0
        for a in range(self.n):
            if self.live():
                role = NOT_IN_PPE
                if P.kind[a] == FLUID:
                    xa = P.x[a]
                    sums = ti.Struct(rho=P.mass[a] * self.kernel.w0, grad_c=ti.Vector.zero(float, self.dim),
                                     moment=ti.Matrix.zero(float, self.dim, self.dim),
                                     grad_w_moment=ti.Matrix.zero(float, self.dim, self.dim),
                                     acc_sum=P.mass[a] * self.kernel.w0 * P.acc[a], w_fluid=P.mass[a] * self.kernel.w0,
                                     w_held=0.0,
                                     r_sum=ti.Vector.zero(float, self.dim),
                                     rr_sum=ti.Matrix.zero(float, self.dim, self.dim),
                                     acc_r_sum=ti.Matrix.zero(float, self.dim, self.dim),
                                     v_sum=ti.Vector.zero(float, self.dim),
                                     v_r_sum=ti.Matrix.zero(float, self.dim, self.dim),
                                     sum_dv=ti.Matrix.zero(float, self.dim, self.dim),
                                     m_fluid=ti.Matrix.zero(float, self.dim, self.dim), wall_in_reach=False)
                    self.nsearch.for_each_neighbor(a, P.x, self.free_surface_pair, sums)
                    rho, grad_c, moment, grad_w_moment = sums.rho, sums.grad_c, sums.moment, sums.grad_w_moment
                    acc_sum, w_fluid = sums.acc_sum, sums.w_fluid
                    # last step's acceleration, a weighted linear fit over the fluid neighbours evaluated at the
                    # particle: one particle's spike (a contact line, a near-singular gradient) must not become its
                    # own Dirichlet pressure, which spikes its next acceleration; the plain Shepard mean is the
                    # value at the neighbours' centroid, ~1 dx inside a surface particle (oscillating drop: half
                    # period -1.25% with it, -0.28% with the fit; docs/isph.md)
                    acc = linear_fit_at_particle(w_fluid, acc_sum, sums.r_sum, sums.rr_sum, sums.acc_r_sum)
                    if ti.static(self.features.switch_noise_source):
                        self.compression[a] = self.free_surface_noise_rate(a, sums)
                    rho /= self.lattice_sum
                    self.rho_summation[a] = rho
                    # a fluid that fills its container at the start has no free surface to find (confinement)
                    open_surface = self.surface_possible[None] != 0
                    candidate = open_surface and rho < SURFACE_CANDIDATE * self.rho0
                    # spray on a wall: the walls fill its kernel sum, no fluid holds its PPE row
                    spray = isolated_from_fluid(sums.w_held, 1.0 / self.rho0, self.lattice_sum)
                    surface = open_surface and (rho < self.surface_threshold * self.rho0 or spray)
                    if not surface and candidate:
                        cone = ti.Struct(outward=-grad_c.normalized(1e-12), surface=True)
                        self.nsearch.for_each_neighbor(a, P.x, self.surface_cone_pair, cone)
                        surface = cone.surface
                        if ti.static(self.one_sided):
                            if not surface and ti.abs(moment.determinant()) > MIN_MOMENT_DETERMINANT:
                                surface = projection_self_ratio(grad_c, moment, grad_w_moment,
                                                                P.mass[a] / self.rho0) > self.one_sided_ratio
                    self.grad_p_estimate[a] = self.rho0 * (self.body_force(xa) - acc)
                    role = UNKNOWN
                    if surface:
                        role = DIRICHLET
                        depth = self.surface_depth
                        if ti.static(self.strained_depth):
                            depth = self.surface_layer_depth(a, sums, grad_c)
                        P.p[a] = self.p_background + free_surface_pressure(self.rho0, depth, grad_c,
                                                                           self.body_force(xa), acc,
                                                                           ti.static(self.surface_tension))
                        ti.atomic_add(E.scalars[N_DIRICHLET], 1.0)
                    if ti.static(self.strained_depth):
                        if not surface:
                            self.depth[a] = 0.0
                    if candidate:  # (physics/free_surface.py) below it: floored at rho0
                        rho = ti.max(rho, self.rho0)  # a cut-off kernel sum is not expansion
                    if spray:  # its kernel sum is the walls', not a compression of fluid (isolated_from_fluid)
                        rho = self.rho0
                    P.rho[a] = rho
                if ti.static(self.extrapolated_walls):
                    if P.kind[a] == WALL:
                        role = DIRICHLET
                        if self.wet_wall_row(a):
                            role = UNKNOWN
                E.role[a] = role

    @ti.func
    def free_surface_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s share of the summation density, grad C, the moments of the self ratio and the
        weighted linear fits of last step's fluid acceleration and (the switch's noise source) of the velocity."""
        P = self.particles
        r = r_ab.norm()
        w = self.kernel.w(r)
        sums.rho += P.mass[b] * w
        grad_w = self.kernel.grad_w(r_ab, r)
        sums.grad_c += P.mass[b] / self.rho0 * grad_w
        if ti.static(self.one_sided):
            sums.moment -= P.mass[b] / self.rho0 * r_ab.outer_product(grad_w)
            sums.grad_w_moment += P.mass[b] / self.rho0 * grad_w.outer_product(grad_w)
        if P.kind[b] == FLUID:
            mw = P.mass[b] * w
            r_ba = -r_ab
            sums.acc_sum += mw * P.acc[b]
            sums.w_fluid += mw
            sums.w_held += P.mass[b] * self.kernel.w(ti.max(r, self.dx))  # a neighbour nearer than dx counts as one at dx
            sums.r_sum += mw * r_ba
            sums.rr_sum += mw * r_ba.outer_product(r_ba)
            sums.acc_r_sum += mw * P.acc[b].outer_product(r_ba)
            if ti.static(self.features.switch_noise_source):
                sums.v_sum += mw * P.v[b]
                sums.v_r_sum += mw * P.v[b].outer_product(r_ba)
            if ti.static(self.strained_depth):
                s_ab, m_ab = corrected_gradient_pair_terms(P.mass[b] / self.rho0, P.v[a] - P.v[b], r_ab, grad_w)
                sums.sum_dv += s_ab
                sums.m_fluid += m_ab
        elif ti.static(self.strained_depth):
            sums.wall_in_reach = True

    @ti.func
    def free_surface_noise_rate(self, a, sums: ti.template()) -> float:
        """isph.switch_noise x |v_a - v_fit| / h (physics/momentum.py particle_noise_rate), v_fit the weighted linear
        fit of a's fluid neighbours' velocities at x_a, a itself left out: the acceleration fit's geometric sums less
        a's own weight (its r and r r^T terms are zero). Left in `compression` for the predictor, which takes
        max(-div v, this) as the viscosity switch's source; 0 without fluid neighbours."""
        P = self.particles
        w_neighbours = sums.w_fluid - P.mass[a] * self.kernel.w0
        rate = 0.0
        if w_neighbours > 0.0:
            v_fit = linear_fit_at_particle(w_neighbours, sums.v_sum, sums.r_sum, sums.rr_sum, sums.v_r_sum)
            rate = self.switch_noise * particle_noise_rate(P.v[a], v_fit, self.h)
        return rate

    @ti.func
    def surface_layer_depth(self, a, sums: ti.template(), grad_c) -> float:
        """(isph.surface_depth: strained) a's depth under the surface, kept in `depth`: dx/2 where a joins the surface
        or has a wall in reach (a contact line's one-sided support: there the strained depth gained energy),
        else last step's, strained by the step's tangential divergence (physics/free_surface.py
        strained_surface_depth; the renormalised velocity gradient over the fluid neighbours, physics/momentum.py),
        within [dx/4, dx]."""
        depth = self.depth[a]
        if depth <= 0.0 or sums.wall_in_reach:
            depth = self.surface_depth
        else:
            grad_v = renormalised_velocity_gradient(sums.sum_dv, sums.m_fluid)
            depth = strained_surface_depth(depth, grad_v, -grad_c.normalized(1e-12), self.strain_dt[None])
            depth = ti.min(ti.max(depth, 0.5 * self.surface_depth), 2.0 * self.surface_depth)
        self.depth[a] = depth
        return depth

    @ti.func
    def surface_cone_pair(self, a, b, r_ab, cone: ti.template()):
        """A fluid neighbour in the scan cone around a's outward normal: a is not at the free surface."""
        r_ba = -r_ab
        dist = r_ba.norm()
        if self.particles.kind[b] == FLUID and in_surface_cone(r_ba, dist, cone.outward, self.support):
            cone.surface = False

    @ti.kernel
    def floor_surface_band_density(self):
        """rho_a = max(rho_a, rho0) at the fluid particles with a free-surface (Dirichlet) neighbour: the floor the
        PPE assembly applies every step (a support the free surface cuts off is not expansion), here for the state
        before the first step, so that the density written at t = 0 follows the rule of every later output."""
        P = self.particles
        E = self.ppe
        for a in range(self.n):
            if P.kind[a] == FLUID and E.role[a] == UNKNOWN:
                band = ti.Struct(near_surface=False)
                self.nsearch.for_each_neighbor(a, P.x, self.surface_neighbor_pair, band)
                if band.near_surface:
                    P.rho[a] = ti.max(P.rho[a], self.rho0)

    @ti.func
    def surface_neighbor_pair(self, a, b, r_ab, band: ti.template()):
        """band.near_surface: b is a free-surface (Dirichlet) fluid particle."""
        if self.particles.kind[b] == FLUID and self.ppe.role[b] == DIRICHLET:
            band.near_surface = True
