"""Particle shifting (Lind et al. 2012 with the free-surface projection), used by ISPH and WCSPH.

dr_a = -D grad C_a,  grad C_a = sum_b V_b (1 + 0.2 (W_ab / W(dx))^4) grad_a W_ab,  D = A h U dt,
capped at `shifting.max_shift` dx. In the free-surface band (both models; Lind et al. 2012, Sun et al. 2017):
a surface particle (kernel sum below `isph.free_surface_threshold` x the lattice sum) keeps only the component
tangent to the surface, a particle with a surface particle within its support loses its outward component
(normal n = -sum_b V_b grad_a W_ab / |.|). The rows under the surface row have a truncated kernel too, and
-D grad C points out of the fluid there: shifted outward every step they lift the surface (the standing wave,
skillen with the outer-layer projection only: the second row up 3.9e-3 dx a step, the wave's energy +72% in
0.3 s; docs/isph.md). Where the solver has the kinematic wall condition (physics/walls.py) the shift obeys it as a
step's velocity does: no nearer a face than the clearance (before session 33 the shift, applied after the velocity's
cut, moved the dam-break front's particles to 0.07 dx off the floor; docs/isph.md).

With `shifting.walls: mirror` (ISPH's default, `auto`) a container wall (wall_box) enters the kernel sum, its gradient and grad C as
the images of the fluid in its faces rather than as its wall particles, whose part depends on how a fluid row sliding
along the wall sits against the wall rows (`mirror_images`; docs/isph.md: on the standing wave that near-wall shift
was ISPH's whole energy gain).

With `shifting.velocity_correction` the shifted particle's velocity is Taylor-corrected to its new position,
v_a += <grad v>_a . dr_a with the renormalised gradient over fluid neighbours (physics/shifting.py
taylor_correction); without it a particle keeps the velocity of the point it left (Taylor-Green, t = 0.5, WCSPH
with the corrected pressure gradient: L1 0.0057 / 0.0026 at dx 0.02 / 0.01 without, 0.0050 / 0.0017 with).

WCSPH's continuity density follows the shift (`shifting.density: continuity`): drho_a = sum_b m_b (dr_a - dr_b) .
grad_a W_ab, the continuity equation with the displacements for v dt. The energy E = sum m (v^2 / 2 - g . x + e(rho))
then changes by sum_a m_a (p_a / rho_a^2) drho_a - sum_a m_a g . dr_a = -sum_a m_a a_a . dr_a (the pair sum
rearranged as the symmetric pressure gradient): nothing at rest, whatever the shift. A density that stays
(`fixed`) or is carried as a field (`taylor`) lets the shift change the volume the particles fill: under gravity
that is potential energy (the standing wave: +9% of its energy a period, a mean level rise of ~1e-5 of the depth).

The speed U (`shifting.model`; ISPH may set its own, `isph.shifting_model`):
- `skillen` (Skillen et al. 2013): the particle's own |v_a|. It vanishes at a stagnation point. In a
  body stretched by u = A0 (x, -y) (configs/elliptical_drop_2d.yaml) the centre is one, so the lattice
  there is stretched as it is, into columns 2 dx apart of particles dx/2 apart, while the faster
  particles around it are shifted into a disordered isotropic arrangement. At the seam between the
  two, and along the symmetry line x = 0 (which no shift crosses), the summation density climbs: ISPH
  reached a 15% density error and a hole in the particle arrangement opened around the centre.
- `sun` (Sun et al. 2017, delta+-SPH): the largest fluid speed of the step, so the whole body is kept
  isotropic, stagnation points included. Their dr = -CFL Ma (2h)^2 grad C with CFL = c0 dt / h is
  D = 4 h U_max dt: A = 4 here. As theirs, the projection acts in the whole surface band (a surface
  particle or one with a surface particle within its support), with the normal of the kernel sum
  n = -sum_b V_b grad_a W_ab / |.| rather than grad C (with the outer-layer projection only, on grad C, the
  layers below were pushed outward, and a WCSPH body, whose continuity density does not see a shift, grew
  in area: stretching drop at t = 0.4 s +6.6%); `skillen` now projects in the same band.
"""


import numpy as np
import taichi as ti

from taichi_sph.physics.shifting import (
    lind_concentration_gradient_term,
    mirror_image,
    no_outward_part,
    renormalised_displacement,
    shifting_diffusion,
    tangential_part,
    taylor_correction,
)
from taichi_sph.scene.bodies import FLUID
from taichi_sph.scene.lattice import lattice_kernel_sum

MAX_FACES = 3  # container faces a particle's support may meet (a 3D corner)


@ti.data_oriented
class ParticleShifting:
    """The shift of every fluid particle (see the module docstring): `apply(dt, max_speed)`."""

    def __init__(self, solver) -> None:
        cfg = solver.cfg  # the solver's config, its 'auto' shift decided (scene/confinement.py)
        self.solver = solver
        self.coefficient = cfg.shifting_coefficient
        self.global_speed = cfg.shifting_model == "sun"
        self.max_shift = cfg.shifting.max_shift * cfg.particles.dx
        self.lattice_sum = lattice_kernel_sum(cfg, solver.kernel.w_np)
        self.threshold = cfg.isph.free_surface_threshold
        self.w_dx = float(solver.kernel.w_np(np.array([cfg.particles.dx]))[0])
        self.shift = solver.particles.add_vector()
        self.mirror = cfg.shifting_walls == "mirror"
        # ISPH: grad C over the rest volumes m / rho0 in a confined fluid (concentration_volume)
        self.rest_volumes = cfg.solver == "isph"
        # shifting.velocity_correction: the Taylor update of v for the shift; shifting.density: WCSPH's continuity
        # density after it (taylor: the Taylor update, continuity: the displacements' continuity sum)
        density = solver.features.shifting_density
        self.correct = solver.features.shifting_correction
        self.correct_rho = density == "taylor"
        self.follow_rho = density == "continuity"
        self.taylor = self.correct or self.correct_rho  # the renormalised sums are needed
        self.dv = solver.particles.add_vector() if self.correct else None
        self.drho = solver.particles.add_scalar() if self.correct_rho or self.follow_rho else None
        # surface flags of this step (the projection band is found from the neighbours' flags); a WCSPH fluid that
        # fills its container has none to flag (scene/confinement.py), and skips the kernel-sum pass that finds them
        self.surface = solver.particles.add_scalar(dtype=ti.i32)
        self.no_surface = cfg.solver == "wcsph" and getattr(solver, "fills_container", False)
        # sun: 1 in the free-surface region (a surface particle within the support, itself included), for
        # WCSPH's tensile instability control; persistent: the neighbour rebuild between the shift and the force
        # pass that reads it may reorder the particles
        self.keep_region = self.global_speed and solver.features.tensile_instability_control
        self.surface_region = (solver.particles.add_scalar(persistent=True, dtype=ti.i32) if self.keep_region
                               else None)
        if self.keep_region:
            self.surface_region.fill(1)  # before the first shift: the conservative (symmetric) form everywhere

    @ti.func
    def kernel_sum(self, a):
        """sum_b V_b W_ab (a included) over this step's neighbour lists; 1 on a full lattice x lattice_sum."""
        S = self.solver
        P = S.particles
        ksum = P.mass[a] / P.rho[a] * S.kernel.w0
        if ti.static(self.mirrors_walls()):
            images = self.mirror_images(a)
            ksum += images.ksum
        S.nsearch.for_each_neighbor(a, P.x, self.kernel_sum_pair, ksum)
        return ksum

    @ti.func
    def kernel_sum_pair(self, a, b, r_ab, ksum: ti.template()):
        """ksum += V_b W_ab (a mirrored wall's particles: their images instead)."""
        P = self.solver.particles
        if not self.is_mirrored(b):
            ksum += P.mass[b] / P.rho[b] * self.solver.kernel.w(r_ab.norm())

    @ti.kernel
    def compute(self, dt: float, max_speed: float):
        self.flag_surface_pass(False)
        self.compute_pass(dt, max_speed, False)

    @ti.kernel
    def move(self):
        self.move_pass(False)

    @ti.func
    def flag_surface_pass(self, serial: ti.template()):
        """surface[a] = 1 for fluid particles whose kernel sum is below the free-surface threshold."""
        S = self.solver
        P = S.particles
        ti.loop_config(serialize=serial)
        for a in range(S.n):  # a constant end, the step's flag inside (SolverBase.live)
            if S.live():
                self.surface[a] = 0
                if ti.static(not self.no_surface):
                    if P.kind[a] == FLUID:
                        if self.kernel_sum(a) < self.threshold * self.lattice_sum:
                            self.surface[a] = 1

    @ti.func
    def compute_pass(self, dt, max_speed, serial: ti.template()):
        """shift_a for every fluid particle (the pass a solver's own kernels call; run flag_surface_pass first)."""
        S = self.solver
        P = S.particles
        ti.loop_config(serialize=serial)
        for a in range(S.n):
            if S.live():
                self.shift[a] = ti.Vector.zero(float, S.dim)
                if P.kind[a] == FLUID:
                    sums = ti.Struct(grad_c=ti.Vector.zero(float, S.dim), grad_sum=ti.Vector.zero(float, S.dim),
                                     ksum=P.mass[a] / P.rho[a] * S.kernel.w0, band=0, va=P.v[a], rho_a=P.rho[a],
                                     sum_dv=ti.Matrix.zero(float, S.dim, S.dim), sum_drho=ti.Vector.zero(float, S.dim),
                                     moment=ti.Matrix.zero(float, S.dim, S.dim))
                    if ti.static(self.mirrors_walls()):
                        images = self.mirror_images(a)
                        sums.ksum += images.ksum
                        sums.grad_sum += images.grad_sum
                        sums.grad_c += images.grad_c
                    S.nsearch.for_each_neighbor(a, P.x, self.gradient_pair, sums)
                    grad_c, grad_sum, ksum, band = sums.grad_c, sums.grad_sum, sums.ksum, sums.band
                    if ti.static(self.keep_region):
                        self.surface_region[a] = ti.max(band, self.surface[a])
                    speed = P.v[a].norm()
                    if ti.static(self.global_speed):
                        speed = max_speed
                    dr = -shifting_diffusion(self.coefficient, S.h, speed, dt) * grad_c
                    if ksum < self.threshold * self.lattice_sum:
                        dr = tangential_part(dr, grad_sum.normalized(1e-12))
                    elif band == 1:
                        dr = no_outward_part(dr, -grad_sum.normalized(1e-12))
                    length = dr.norm()
                    if length > self.max_shift:
                        dr *= self.max_shift / length
                    if ti.static(getattr(S, "kinematic_walls", False)):
                        # a shift keeps the wall clearance as a step does (the faces do not move during it)
                        dr, _ = S.kinematic_wall_cut(a, dr, 1.0, False)
                    self.shift[a] = dr
                    if ti.static(self.taylor):
                        y = renormalised_displacement(sums.moment, dr)
                        if ti.static(self.correct):
                            self.dv[a] = taylor_correction(sums.sum_dv, y)
                        if ti.static(self.correct_rho):
                            self.drho[a] = sums.sum_drho.dot(y)

    @ti.func
    def concentration_volume(self, b, vol_b: float) -> float:
        """V_b in grad C. m_b / rho0 in a confined ISPH fluid (no free surface, find_confinement): incompressible,
        a particle's volume is m / rho0 and C_a = sum_b m_b W_ab / rho0 = rho_a / rho0 is the arrangement's own
        error, so the shift moves particles down the summation density's gradient at any wavelength. m_b / rho_b
        otherwise: with rho the summation density C is then the Shepard sum, ~1 even where a free surface cuts the
        support (a geometric deficit, not an error); and WCSPH's rho is the fluid's compression, which m / rho0 would
        read as a concentration gradient (a column under gravity shifted upward). Taylor-Green at dx 0.01, ISPH:
        L1 0.0046 and max density error 11% with m / rho_b, 0.0024 and 6.7% with m / rho0; with m / rho0 in
        free-surface flows too, dam_break_buchner_2d's ISPH lost energy stability in 2 of 3 starts (docs/isph.md)."""
        vol = vol_b
        if ti.static(self.rest_volumes):
            if self.solver.surface_possible[None] == 0:
                vol = self.solver.particles.mass[b] / self.solver.rho0
        return vol

    @ti.func
    def gradient_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s share of the kernel sum, sum_b V_b grad W, Lind's grad C and (sun) the surface band."""
        S = self.solver
        P = S.particles
        r = r_ab.norm()
        w = S.kernel.w(r)
        vol_b = P.mass[b] / P.rho[b]
        grad_w = S.kernel.grad_w(r_ab, r)
        if not self.is_mirrored(b):
            sums.ksum += vol_b * w
            sums.grad_sum += vol_b * grad_w
            sums.grad_c += lind_concentration_gradient_term(self.concentration_volume(b, vol_b), w, self.w_dx, grad_w)
        # the surface band: a neighbour within the support flagged surface (only fluid is flagged). Without a branch:
        # as `if kind == FLUID and r < support` the pass took 3x as long (a channel of 5000 particles, one thread,
        # Taichi's kernel profiler: 3.3 -> 1.1 ms; WCSPH's step with the shift 1.22 -> 0.79 ms)
        sums.band = ti.max(sums.band, self.surface[b] * ti.cast(r < S.support, ti.i32))
        if ti.static(self.taylor):
            if P.kind[b] == FLUID:
                sums.sum_dv += vol_b * (P.v[b] - sums.va).outer_product(grad_w)
                sums.moment -= vol_b * r_ab.outer_product(grad_w)
                if ti.static(self.correct_rho):
                    sums.sum_drho += vol_b * (P.rho[b] - sums.rho_a) * grad_w

    def mirrors_walls(self) -> bool:
        """`shifting.walls: mirror` on a solver with wall faces (read when the kernels compile)."""
        return self.mirror and hasattr(self.solver, "wall_container")

    @ti.func
    def is_mirrored(self, b):
        """Is b a particle of a container wall whose part the fluid's images take (`shifting.walls: mirror`)?"""
        mirrored = False
        if ti.static(self.mirrors_walls()):
            P = self.solver.particles
            mirrored = P.kind[b] != FLUID and self.solver.wall_container[b] == 1
        return mirrored

    @ti.func
    def face_pair(self, a, b, r_ab, faces: ti.template()):
        """Add a container wall neighbour's face (unit normal into the fluid, offset) to a's list unless known."""
        S = self.solver
        if self.is_mirrored(b):
            normal, offset = S.wall_normal[b], S.wall_offset[b]
            known = False
            for k in ti.static(range(MAX_FACES)):
                if k < faces.n:
                    n_k = ti.Vector([faces.normals[k, d] for d in ti.static(range(S.dim))])
                    if n_k.dot(normal) > 0.99 and ti.abs(faces.offsets[k] - offset) < 1e-3 * S.dx:
                        known = True
            if not known and faces.n < MAX_FACES:
                for k in ti.static(range(MAX_FACES)):
                    if k == faces.n:
                        for d in ti.static(range(S.dim)):
                            faces.normals[k, d] = normal[d]
                        faces.offsets[k] = offset
                faces.n += 1

    @ti.func
    def mirror_images(self, a):
        """The container walls as the fluid's mirror: the kernel sum, sum V grad W and Lind's grad C of the images
        of a and of its fluid neighbours in every product of the reflections in the faces its wall neighbours lie
        behind. A free-slip wall's particles would add a part that depends on how the fluid rows sit against the
        wall rows as they slide along it; the images move with the fluid."""
        S = self.solver
        P = S.particles
        faces = ti.Struct(normals=ti.Matrix.zero(float, MAX_FACES, S.dim), offsets=ti.Vector.zero(float, MAX_FACES),
                          n=0)
        S.nsearch.for_each_neighbor(a, P.x, self.face_pair, faces)
        state = ti.Struct(xa=P.x[a], ksum=0.0, grad_sum=ti.Vector.zero(float, S.dim),
                          grad_c=ti.Vector.zero(float, S.dim), normals=faces.normals, offsets=faces.offsets,
                          n_faces=faces.n)
        if faces.n > 0:
            self.mirror_pair(a, a, ti.Vector.zero(float, S.dim), state)
            S.nsearch.for_each_neighbor(a, P.x, self.mirror_pair, state)
        return state

    @ti.func
    def mirror_pair(self, a, b, r_ab, state: ti.template()):
        """The images of fluid particle b (x_b = x_a - r_ab) in every combination of the faces."""
        S = self.solver
        P = S.particles
        if P.kind[b] == FLUID:
            x_b = state.xa - r_ab
            vol_b = P.mass[b] / P.rho[b]
            for mask in ti.static(range(1, 2 ** MAX_FACES)):
                if mask < (1 << state.n_faces):
                    y = x_b
                    for k in ti.static(range(MAX_FACES)):
                        if ti.static(mask & (1 << k)):
                            n_k = ti.Vector([state.normals[k, d] for d in ti.static(range(S.dim))])
                            y = mirror_image(y, n_k, state.offsets[k])
                    r = state.xa - y
                    dist = r.norm()
                    if dist < S.support:
                        w = S.kernel.w(dist)
                        grad_w = S.kernel.grad_w(r, dist)
                        state.ksum += vol_b * w
                        state.grad_sum += vol_b * grad_w
                        state.grad_c += lind_concentration_gradient_term(self.concentration_volume(b, vol_b), w,
                                                                         self.w_dx, grad_w)

    @ti.func
    def density_follows_pass(self, serial: ti.template()):
        """drho_a = sum_b m_b (dr_a - dr_b) . grad_a W_ab over fluid and wall neighbours (a wall's dr is 0), before
        the particles move (`shifting.density: continuity`)."""
        S = self.solver
        P = S.particles
        ti.loop_config(serialize=serial)
        for a in range(S.n):
            if S.live() and P.kind[a] == FLUID:
                sums = ti.Struct(dr_a=self.shift[a], drho=0.0)
                S.nsearch.for_each_neighbor(a, P.x, self.density_follows_pair, sums)
                self.drho[a] = sums.drho

    @ti.func
    def density_follows_pair(self, a, b, r_ab, sums: ti.template()):
        """drho += the WCSPH continuity equation's pair with the displacements dr_a - dr_b for v_ab dt (its
        continuity_pair_rate: the corrected divergence with `corrected_symmetric`)."""
        S = self.solver
        dr_b = ti.Vector.zero(float, S.dim)
        if S.particles.kind[b] == FLUID:
            dr_b = self.shift[b]
        sums.drho += S.continuity_pair_rate(a, b, r_ab, sums.dr_a - dr_b)

    @ti.func
    def move_pass(self, serial: ti.template()):
        """x_a += shift_a (fluid); with the Taylor correction also v_a += dv_a; rho_a += drho_a, p_a = EOS where
        WCSPH's continuity density follows the shift (its continuity sum or its Taylor update)."""
        S = self.solver
        P = S.particles
        if ti.static(self.follow_rho):
            self.density_follows_pass(serial)
        ti.loop_config(serialize=serial)
        for a in range(S.n):
            if S.live() and P.kind[a] == FLUID:
                P.x[a] += self.shift[a]
                if ti.static(self.correct):
                    P.v[a] += self.dv[a]
                if ti.static(self.correct_rho or self.follow_rho):
                    P.rho[a] += self.drho[a]
                    P.p[a] = S.tait(P.rho[a])

    def apply(self, dt: float, max_speed: float = 0.0) -> None:
        """Shift fluid particles using the neighbour lists of this step (each by at most max_shift);
        `max_speed`: the largest fluid speed, the U of the `sun` model."""
        self.compute(dt, max_speed)
        self.move()
