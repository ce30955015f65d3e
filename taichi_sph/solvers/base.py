"""What every solver shares: particles, kernel, neighbour search, wall extrapolation, reductions, dt.

The kinematic wall condition (wall_condition.py) and the checkpoint state (state.py) are mixins of
SolverBase; the CPU loop schedule is schedule.py."""

import math

import numpy as np
import taichi as ti

from taichi_sph.config.schema import AUTO, Config
from taichi_sph.physics.body_force import harmonic_central_force
from taichi_sph.physics.eos import tait_density, tait_pressure
from taichi_sph.physics.momentum import morris_monaghan_alpha, renormalised_velocity_gradient
from taichi_sph.physics.walls import adami_wall_pressure, adami_wall_velocity
from taichi_sph.scene.bodies import FLUID, WALL, ParticleArrays, tait_b
from taichi_sph.scene.confinement import confined_shifting, fills_container
from taichi_sph.scene.lattice import lattice_gradient_sum, lattice_kernel_sum, max_neighbors_for
from taichi_sph.solvers.clock import DeviceClock
from taichi_sph.solvers.state import CheckpointState
from taichi_sph.solvers.wall_condition import KinematicWalls
from taichi_sph.solvers.wall_motion import WallMotion
from taichi_sph.sph.features import Features
from taichi_sph.sph.kernels import make_kernel
from taichi_sph.sph.neighbors import NeighborSearch
from taichi_sph.sph.particles import ParticleFields, np_float
from taichi_sph.sph.precision import wide_float


class SolverBase(KinematicWalls, WallMotion, CheckpointState):
    """Common state and passes. Subclasses implement `prepare()` and `step() -> dt`.

    Not decorated with `ti.data_oriented` itself: the concrete solvers are, and that decorator routes
    every attribute access through a Python hook, once per decorated class in the hierarchy (twice
    here would cost ~50 us per step of a small scene)."""

    name = "base"
    wall_wall_pairs = True  # solvers that never couple two wall particles set False: shorter wall lists

    def __init__(self, cfg: Config, arrays: ParticleArrays) -> None:
        # a fluid that fills its container keeps no free surface (scene/confinement.py): shifting's default for it
        self.fills_container = fills_container(cfg, arrays)
        cfg = self.cfg = confined_shifting(cfg, arrays, self.fills_container)
        # the clock's and the PPE stopping test's float: f64 unless the device has none (or float64: false)
        self.wide = wide_float(cfg.float64, cfg.precision)
        self.features = Features.from_config(cfg, arrays.n_wall, wide="f64" if self.wide == ti.f64 else "f32")
        f = self.features
        self.dim = cfg.dim
        self.kernel = make_kernel(cfg.particles.kernel, cfg.dim, cfg.h)
        self.h = cfg.h
        self.dx = cfg.particles.dx
        self.support = self.kernel.support_radius
        self.rho0 = cfg.fluid.rho0
        self.c0 = cfg.sound_speed
        self.gamma = cfg.fluid.gamma
        self.B = tait_b(self.rho0, self.c0, self.gamma)
        self.p_background = cfg.fluid.background_pressure
        self.nu = cfg.fluid.nu
        self.eta2 = 0.01 * self.h * self.h
        # fluid.laplacian: normalised: the Morris viscosity over its lattice sum (1.0 multiplies nothing)
        self.lap_moment = lattice_gradient_sum(cfg, self.kernel.dw_dr_np, self.eta2)
        self.visc_norm = 1.0 / self.lap_moment if cfg.fluid.laplacian != "morris" else 1.0
        self.renormalised_laplacian = cfg.fluid.laplacian in ("renormalised", "consistent") and cfg.solver == "wcsph"
        # consistent: the velocity differences less <grad v>_a r_ab (velocity_gradient_pass), WCSPH only: ISPH takes
        # 'normalised' for it (its predictor at the viscous step limit with it: Taylor-Green L1 0.024, 0.012 without)
        self.consistent_laplacian = cfg.fluid.laplacian == "consistent" and cfg.solver == "wcsph"
        if self.renormalised_laplacian:
            self.visc_norm = 1.0  # the sum is divided by each particle's own moment instead
        self.lattice_volume = cfg.wall_dx ** cfg.dim  # a wall particle's volume: (dx / walls.refinement)^dim
        self.inv_lattice_sum = 1.0 / lattice_kernel_sum(cfg, self.kernel.w_np)
        self.particles = ParticleFields(arrays, cfg.dim)
        self.n = self.particles.n
        # Verlet skin: lists hold pairs closer than support + skin; kernels are zero beyond the support
        self.skin = cfg.skin_fraction * self.support
        self.list_radius = self.support + self.skin
        self.max_neighbors = max_neighbors_for(cfg, self.list_radius)
        self.nsearch = NeighborSearch(cfg.dim, self.n, cfg.domain.lo, cfg.domain.hi, self.list_radius,
                                      f.periodic, self.max_neighbors,
                                      group=None if self.wall_wall_pairs else self.particles.kind,
                                      access=cfg.particles.neighbor_access)
        self.x_ref = ti.Vector.field(cfg.dim, float, self.n) if self.skin > 0.0 else None
        # fluid.laplacian consistent, isph.frame eulerian: <grad v>_a, set before the viscous pass (not permuted)
        self.eulerian = cfg.solver == "isph" and cfg.isph.frame == "eulerian"  # isph.frame: the advection needs <grad v>_a
        self.grad_v = (ti.Matrix.field(cfg.dim, cfg.dim, float, self.n) if self.consistent_laplacian or self.eulerian
                       else None)
        self.builds = 0
        self.central_omega = cfg.central_force.omega
        self.central_center = None
        if f.central_force:
            self.central_center = ti.Vector.field(cfg.dim, float, shape=())
            self.central_center[None] = list(cfg.central_force_center)
        self.gravity = ti.Vector.field(cfg.dim, float, shape=())
        self.gravity[None] = list(cfg.gravity_vector)
        if cfg.gravity_ramp > 0.0:
            self.gravity[None] = [0.0] * cfg.dim
        self.stats = ti.field(float, shape=5)
        # host mirror the kernels copy the stats into (a numpy array passed as an ndarray argument: on
        # the CPU no copy at all, where five scalar field reads cost ~80 us per step)
        self.stats_host = np.zeros(5, dtype=np_float())
        if f.walls:
            # Adami ghost velocity for the no-slip laminar viscosity; prescribed wall velocity stays in v
            self.v_ghost = self.particles.add_vector() if f.ghost_velocity else None
        self.domain_lo = tuple(cfg.domain.lo)
        self.domain_hi = tuple(cfg.domain.hi)
        self.restitution = cfg.reflecting.restitution
        self.t = 0.0
        self.step_count = 0
        self.last_dt_limit = ""
        self.dt_cap = math.inf  # the run loop caps the step so that t lands on t_end
        # t, dt and `live` on the device: the step passes test `live()` for each particle, so that a step a
        # device-resident loop does not take is empty (solvers stepping from the host leave live at 1)
        self.clock = DeviceClock(wide=self.wide)

    # -- neighbours ---------------------------------------------------------------------
    def init_viscosity_switch(self, cfg: Config, alpha: float) -> None:
        """Morris & Monaghan's switch (`wcsph.artificial_viscosity.switch`): each particle's alpha, starting at and
        decaying to the run's `alpha` (walls keep it), and its compression rate -div v, which the solver's viscous
        pass sums (physics/momentum.py compression_rate) and `step_switch_alpha` reads."""
        av = cfg.wcsph.artificial_viscosity
        self.switch_floor, self.alpha_max, self.switch_tau = alpha, av.alpha_max, self.h / (av.decay * self.c0)
        on = self.features.viscosity_switch
        self.av_alpha = self.particles.add_scalar(persistent=True) if on else None
        self.compression = self.particles.add_scalar() if on else None
        if on:
            self.av_alpha.fill(alpha)

    @ti.func
    def pair_alpha(self, alpha_a, b):
        """The Monaghan alpha of pair (a, b): the run's, or (switch) the mean of the two particles'."""
        alpha = self.switch_floor
        if ti.static(self.features.viscosity_switch):
            alpha = 0.5 * (alpha_a + self.av_alpha[b])
        return alpha

    @ti.func
    def step_switch_alpha(self, a, dt):
        """alpha_a after a step dt of the switch's equation at a's last compression rate (physics/momentum.py)."""
        if ti.static(self.features.viscosity_switch):
            self.av_alpha[a] = morris_monaghan_alpha(self.av_alpha[a], self.compression[a], dt, self.switch_tau,
                                                     self.switch_floor, self.alpha_max)

    def rebuild_neighbors(self, serial: bool = False) -> None:
        """Cell sort, reorder every persistent field, rebuild neighbour lists (`serial`: on one thread)."""
        self.nsearch.build(self.particles.x, self.particles.persistent_fields, serial)
        if self.x_ref is not None:
            self.x_ref.copy_from(self.particles.x)
        self.builds += 1

    @ti.func
    def displacement_since_build(self, a):
        d = 0.0
        if ti.static(self.skin > 0.0):
            d = self.nsearch.pair_vector(self.particles.x[a], self.x_ref[a]).norm()
        return d

    @ti.func
    def live(self):
        """1 while this step runs, 0 for a step a device loop skips. The particle loops run to the constant n and
        test it inside: a loop end known only at run time (n * live) makes a GPU backend dispatch 131072 threads
        striding over it (linalg/reduction.py), which costs a software Vulkan ~5 ms a loop."""
        return self.clock.live[None]

    @ti.func
    def velocity_gradient_pass(self, serial: ti.template()):
        """<grad v>_a = S_a M_a^-1 over fluid neighbours (physics/momentum.py renormalised_velocity_gradient), for the
        consistent Laplacian (fluid.laplacian: consistent)."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    sums = ti.Struct(va=P.v[a], s=ti.Matrix.zero(float, self.dim, self.dim),
                                     moment=ti.Matrix.zero(float, self.dim, self.dim))
                    self.nsearch.for_each_neighbor(a, P.x, self.velocity_gradient_pair, sums)
                    self.grad_v[a] = renormalised_velocity_gradient(sums.s, sums.moment)

    @ti.func
    def velocity_gradient_pair(self, a, b, r_ab, sums: ti.template()):
        """sums.s += V_b (v_b - v_a) (x) grad_a W_ab and sums.moment += V_b (x_b - x_a) (x) grad_a W_ab, fluid b only."""
        P = self.particles
        if P.kind[b] == FLUID:
            grad_w = self.kernel.grad_w(r_ab, r_ab.norm())
            vol_b = P.mass[b] / P.rho[b]
            sums.s += vol_b * (P.v[b] - sums.va).outer_product(grad_w)
            sums.moment -= vol_b * r_ab.outer_product(grad_w)

    # -- shared passes ---------------------------------------------------------------------
    @ti.kernel
    def summation_density(self):
        self.summation_density_pass()

    @ti.kernel
    def tait_equation_of_state(self):
        self.tait_pass()

    @ti.kernel
    def adami_wall_extrapolation(self):
        self.adami_wall_pass()

    @ti.kernel
    def reduce_stats(self, out: ti.types.ndarray()):
        self.stats_pass()
        self.export_stats(out)

    # Passes are @ti.func with one top-level loop each; a kernel that calls several in a row runs them
    # one after the other, each in parallel (one launch instead of several).
    @ti.func
    def summation_density_pass(self, serial: ti.template() = False):
        """rho_a = (m_a W(0) + sum_b m_b W_ab) / S over fluid and wall neighbours (fluid particles only),
        S = sum_b V W_ab on the full initial lattice (1.0105 for Wendland C2 at h = 1.3 dx): a particle
        inside the lattice reads its initial density, not 1% more (which the EOS turns into ~7% of B)."""
        P = self.particles
        NS = self.nsearch
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    rho = P.mass[a] * self.kernel.w0
                    NS.for_each_neighbor(a, P.x, self.summation_density_pair, rho)
                    P.rho[a] = rho * self.inv_lattice_sum

    @ti.func
    def summation_density_pair(self, a, b, r_ab, rho: ti.template()):
        """rho += m_b W_ab."""
        rho += self.particles.mass[b] * self.kernel.w(r_ab.norm())

    @ti.func
    def tait(self, rho):
        """p = B ((rho/rho0)^gamma - 1) + p_b (optionally clamped at 0)."""
        p = tait_pressure(rho, self.rho0, self.B, self.gamma, self.p_background)
        if ti.static(self.features.clamp_negative_pressure):
            p = ti.max(p, 0.0)
        return p

    @ti.func
    def tait_pass(self, serial: ti.template() = False):
        """Tait pressure for every fluid particle."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    P.p[a] = self.tait(P.rho[a])

    @ti.func
    def body_force(self, x):
        """Acceleration of the body forces at x: gravity and the harmonic central force, as compiled in."""
        acc = ti.Vector.zero(float, self.dim)
        if ti.static(self.features.gravity):
            acc = self.gravity[None]  # assigned, not added to zero: 0 + g is not folded (-0.0), bits would differ
        if ti.static(self.features.central_force):
            acc += harmonic_central_force(x, self.central_center[None], self.central_omega)
        return acc

    @ti.func
    def adami_wall_pass(self, serial: ti.template() = False):
        """Wall pressure (and density, and no-slip ghost velocity) from the fluid around each wall particle."""
        P = self.particles
        NS = self.nsearch
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == WALL:
                    xa = P.x[a]
                    sums = ti.Struct(w=0.0, pw=0.0, rho_rw=ti.Vector.zero(float, self.dim),
                                     vw=ti.Vector.zero(float, self.dim))
                    NS.for_each_neighbor(a, P.x, self.adami_wall_pair, sums)
                    sum_w, sum_pw, sum_rho_rw, sum_vw = sums.w, sums.pw, sums.rho_rw, sums.vw
                    body_acc = self.body_force(xa) - self.wall_acceleration(a)  # g - a_w
                    # walls push, never pull: a negative extrapolated pressure (wall above a free surface)
                    # would glue fluid to the wall
                    p = ti.max(adami_wall_pressure(sum_pw, sum_rho_rw, sum_w, body_acc), 0.0)
                    if sum_w == 0.0:
                        p = self.p_background
                    P.p[a] = p
                    rho_w = tait_density(p, self.rho0, self.B, self.gamma, self.p_background)
                    P.rho[a] = rho_w
                    P.mass[a] = rho_w * self.lattice_volume  # a wall particle stands for its (dx / r)^dim of ghost fluid
                    if ti.static(self.features.ghost_velocity):
                        self.v_ghost[a] = adami_wall_velocity(P.v[a], sum_vw, sum_w)
                    self.fold_moving_wall_stats(a)

    @ti.func
    def adami_wall_pair(self, a, b, r_ab, sums: ti.template()):
        """A fluid neighbour's share of the Adami sums: W, p W, rho r W (r = x_w - x_f) and (no-slip) v W."""
        P = self.particles
        if P.kind[b] == FLUID:
            w = self.kernel.w(r_ab.norm())
            sums.w += w
            sums.pw += P.p[b] * w
            sums.rho_rw += P.rho[b] * r_ab * w
            if ti.static(self.features.ghost_velocity):
                sums.vw += P.v[b] * w

    @ti.func
    def stats_pass(self):
        """stats = [max |v|, max |a|, max |rho - rho0| / rho0, number of non-finite values, max displacement
        since the last neighbour build] over fluid."""
        self.reset_stats()
        for a in range(self.n):
            if self.particles.kind[a] == FLUID:
                self.accumulate_stats(a)

    @ti.func
    def export_stats(self, out: ti.template()):
        """out[:] = stats (serial: 5 values)."""
        ti.loop_config(serialize=True)
        for s in range(5):
            out[s] = self.stats[s]

    @ti.func
    def reset_stats_live(self):
        """reset_stats, unless this step is skipped (the stats then keep describing the current state)."""
        ti.loop_config(serialize=True)
        for s in range(5 * self.clock.live[None]):
            self.stats[s] = 0.0

    @ti.func
    def reset_stats(self):
        ti.loop_config(serialize=True)  # 5 values: a serial task, no thread-pool wake-up (~70 us here)
        for s in range(5):
            self.stats[s] = 0.0

    @ti.func
    def accumulate_stats(self, a):
        """Fold fluid particle a into the stats (callable from inside any particle loop)."""
        P = self.particles
        bad = 0.0
        for d in ti.static(range(self.dim)):
            if not (ti.abs(P.x[a][d]) < 1e30 and ti.abs(P.v[a][d]) < 1e30):
                bad = 1.0
        if not (ti.abs(P.rho[a]) < 1e30):
            bad = 1.0
        ti.atomic_max(self.stats[0], P.v[a].norm())
        ti.atomic_max(self.stats[1], P.acc[a].norm())
        derr = ti.abs(P.rho[a] - self.rho0) / self.rho0
        if ti.static(self.features.density == "summation" and self.features.solver == "wcsph"):
            # summed density is short near a free surface by construction: only compression counts
            derr = ti.max(P.rho[a] - self.rho0, 0.0) / self.rho0
        ti.atomic_max(self.stats[2], derr)
        ti.atomic_add(self.stats[3], bad)
        ti.atomic_max(self.stats[4], self.displacement_since_build(a))

    def read_stats(self, reduce: bool = True) -> dict:
        """The stats as a dict (reduced now, unless a fused kernel just did it and exported them)."""
        if reduce:
            self.reduce_stats(self.stats_host)
        s = self.stats_host
        return {"max_speed": float(s[0]), "max_acc": float(s[1]), "max_density_error": float(s[2]),
                "non_finite": int(s[3]), "max_displacement": float(s[4])}

    @ti.func
    def reflect(self, a):
        """Reflect a particle at non-periodic domain faces: mirror position, v_n -> -e v_n."""
        P = self.particles
        for d in ti.static(range(self.dim)):
            if ti.static(not self.features.periodic[d]):
                lo = ti.static(self.domain_lo[d])
                hi = ti.static(self.domain_hi[d])
                if P.x[a][d] < lo:
                    P.x[a][d] = 2.0 * lo - P.x[a][d]
                    P.v[a][d] = -self.restitution * P.v[a][d]
                if P.x[a][d] > hi:
                    P.x[a][d] = 2.0 * hi - P.x[a][d]
                    P.v[a][d] = -self.restitution * P.v[a][d]

    def update_body_force(self, t: float | None = None) -> None:
        """Gravity ramp at time t (default: now): g(t) = g (1 - cos(pi t / t_ramp)) / 2 for t < t_ramp."""
        ramp = self.cfg.gravity_ramp
        if ramp > 0.0 and self.features.gravity:
            t = self.t if t is None else t
            factor = 0.5 * (1.0 - math.cos(math.pi * min(t / ramp, 1.0)))
            self.gravity[None] = [factor * g for g in self.cfg.gravity_vector]

    # -- time step --------------------------------------------------------------------------
    def choose_dt(self, max_speed: float, max_acc: float, sound_speed: float) -> float:
        """The step: uncapped_dt, shortened to the run loop's cap (dt_cap: landing on an output or end time)."""
        return min(self.uncapped_dt(max_speed, max_acc, sound_speed), self.dt_cap)

    def uncapped_dt(self, max_speed: float, max_acc: float, sound_speed: float) -> float:
        """dt = min(CFL h / (c + |v|max), CFL sqrt(h / |a|max), 0.125 h^2 / nu, dt_max), or the fixed dt;
        last_dt_limit names the winner."""
        tc = self.cfg.time
        if tc.dt != AUTO:
            self.last_dt_limit = "fixed"
            return float(tc.dt)
        limits = {}
        speed = sound_speed + max_speed
        if speed > 0:
            limits["cfl"] = self.cfg.cfl * self.h / speed
        if max_acc > 0:
            limits["force"] = self.cfg.cfl * math.sqrt(self.h / max_acc)
        if self.nu > 0:
            limits["viscous"] = 0.125 * self.h * self.h / self.nu
        if tc.dt_max is not None:
            limits["dt_max"] = tc.dt_max
        if not limits:
            limits["cfl"] = self.cfg.cfl * self.h / max(self.cfg.expected_speed, 1e-12)
        self.last_dt_limit = min(limits, key=limits.get)
        return float(limits[self.last_dt_limit])

    def free_dt(self, stats: dict) -> float:
        """The next step's dt from the stats, before the run loop's cap (with the sound speed c0)."""
        return self.uncapped_dt(stats["max_speed"], stats["max_acc"], self.c0)

    def next_dt(self) -> float:
        """The dt the next step will take (uncapped), from the current state: for a caller that paces steps."""
        return self.free_dt(self.read_stats())

    # -- interface ----------------------------------------------------------------------------
    def prepare(self) -> None:
        raise NotImplementedError

    def step(self) -> float:
        raise NotImplementedError

    def advance(self, max_steps: int, t_stop: float = math.inf, t_end: float = math.inf) -> list[float]:
        """Up to `max_steps` steps while t < t_stop (the first step always runs) and t < t_end, the last
        step cut to land on t_end; returns the dts taken. Here: one host-driven `step()` at a time
        (solvers with a device-resident loop override it)."""
        dts: list[float] = []
        for i in range(max_steps):
            if self.t >= t_end - 1e-12 or (i > 0 and self.t >= t_stop - 1e-12):
                break
            self.dt_cap = t_end - self.t
            dts.append(self.step())
        self.dt_cap = math.inf
        return dts

    def extra_summary(self) -> dict:
        """Solver-specific summary entries (ISPH: ppe)."""
        return {}

    def extra_timeseries(self) -> dict:
        return {}

    def host_state(self) -> dict[str, np.ndarray]:
        return self.particles.to_numpy()
