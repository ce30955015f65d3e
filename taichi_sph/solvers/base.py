"""What every solver shares: particles, kernel, neighbour search, wall extrapolation, reductions, dt."""


import math

import numpy as np
import taichi as ti

from taichi_sph.config.schema import AUTO, Config
from taichi_sph.physics.body_force import harmonic_central_force
from taichi_sph.physics.eos import tait_density, tait_pressure
from taichi_sph.physics.walls import adami_wall_pressure, adami_wall_velocity, kinematic_wall_condition
from taichi_sph.scene.bodies import FLUID, WALL, ParticleArrays, tait_b, wall_face_planes
from taichi_sph.scene.lattice import lattice_kernel_sum, max_neighbors_for
from taichi_sph.solvers.clock import DeviceClock
from taichi_sph.sph.features import Features
from taichi_sph.sph.kernels import make_kernel
from taichi_sph.sph.neighbors import NeighborSearch
from taichi_sph.sph.particles import ParticleFields, np_float


def _is_plain(value) -> bool:
    """Numbers, strings, None and (nested) lists, tuples and dicts of them: safe to pickle and restore."""
    if value is None or isinstance(value, (bool, int, float, str, np.generic)):
        return True
    if isinstance(value, (list, tuple)):
        return all(_is_plain(v) for v in value)
    if isinstance(value, dict):
        return all(_is_plain(k) and _is_plain(v) for k, v in value.items())
    return False


def _is_project_object(value) -> bool:
    """An instance of one of this project's classes that holds state (not a frozen config dataclass)."""
    import dataclasses
    module = type(value).__module__ or ""
    return (module.startswith("taichi_sph") and hasattr(value, "__dict__") and not isinstance(value, type)
            and not dataclasses.is_dataclass(value))


class LoopSchedule:
    """Whether a solver's step loops run on one thread: decided on the CPU by timing steps.

    Each parallel loop costs a thread-pool round (~70 us on this project's 2-core VM, a few us on an
    idle many-core CPU): on that VM a whole WCSPH step of PySPH's 3.8k-particle dam break ran ~30%
    faster on one thread, dam_break_2d's 16.5k particles at h = 2 dx ~40% slower. The first steps run
    one schedule, then the other, `warmup + probes` steps each (alternating step by step made both
    look alike: each switch costs cache and thread wake-ups), and the faster median of the last
    `probes` wins. Results do not depend on the choice: the loops concerned write per particle, and
    reductions are max or integer counts. On a GPU the loops always run in parallel."""

    def __init__(self, probes: int = 6, warmup: int = 3) -> None:
        cpu = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
        self.serial: bool | None = None if cpu else False
        self.probes = probes
        self.warmup = warmup
        self.samples: dict[bool, list[float]] = {True: [], False: []}

    @property
    def deciding(self) -> bool:
        return self.serial is None

    def next(self) -> bool:
        """The schedule for the next step."""
        if self.serial is not None:
            return self.serial
        return len(self.samples[True]) < self.warmup + self.probes

    def record(self, serial: bool, seconds: float) -> None:
        """Wall time of a step run with `serial` (only while deciding)."""
        self.samples[serial].append(seconds)
        if min(len(v) for v in self.samples.values()) >= self.warmup + self.probes:
            median = {k: float(np.median(v[self.warmup:])) for k, v in self.samples.items()}
            self.serial = median[True] < median[False]


class SolverBase:
    """Common state and passes. Subclasses implement `prepare()` and `step() -> dt`.

    Not decorated with `ti.data_oriented` itself: the concrete solvers are, and that decorator routes
    every attribute access through a Python hook, once per decorated class in the hierarchy (twice
    here would cost ~50 us per step of a small scene)."""

    name = "base"
    wall_wall_pairs = True  # solvers that never couple two wall particles set False: shorter wall lists

    def __init__(self, cfg: Config, arrays: ParticleArrays) -> None:
        self.cfg = cfg
        self.features = Features.from_config(cfg, arrays.n_wall)
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
        self.lattice_volume = self.dx ** cfg.dim
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
            # Adami ghost velocity for no-slip viscous terms; prescribed wall velocity stays in v
            self.v_ghost = self.particles.add_vector() if f.no_slip else None
        self.domain_lo = tuple(cfg.domain.lo)
        self.domain_hi = tuple(cfg.domain.hi)
        self.restitution = cfg.reflecting.restitution
        self.t = 0.0
        self.step_count = 0
        self.last_dt_limit = ""
        self.dt_cap = math.inf  # the run loop caps the step so that t lands on t_end
        # t, dt and `live` on the device: the step passes loop over `live_n()` particles, so that a step a
        # device-resident loop does not take is empty (solvers stepping from the host leave live at 1)
        self.clock = DeviceClock()

    # -- kinematic wall condition -----------------------------------------------------------
    def init_kinematic_walls(self, arrays: ParticleArrays, clearance_dx: float | None) -> None:
        """Each wall particle's face (unit normal into the fluid, plane offset; permuted with it) for the
        kinematic wall condition (physics/walls.py), kept `clearance_dx` dx off the faces; None: off."""
        self.kinematic_walls = self.features.walls and clearance_dx is not None
        if self.kinematic_walls:
            P = self.particles
            self.wall_clearance = clearance_dx * self.dx
            normal, offset = wall_face_planes(self.cfg, arrays.x, arrays.kind)
            self.wall_normal = P.add_vector(persistent=True)
            self.wall_offset = P.add_scalar(persistent=True)
            self.wall_normal.from_numpy(normal.astype(np_float()))
            self.wall_offset.from_numpy(offset.astype(np_float()))
            self.wall_cuts = ti.field(ti.i32, shape=())  # particle-steps the condition cut (over the run)

    @ti.func
    def kinematic_wall_cut(self, a, v, dt):
        """v of fluid particle a after the kinematic condition of each wall neighbour's face (only faces
        it is on the fluid side of, or at most dx/2 past); returns (v, 1 if some face cut it)."""
        P = self.particles
        NS = self.nsearch
        xa = P.x[a]
        out = v
        cut = 0
        for s in range(NS.slots()):
            k0, k1 = NS.span(a, s)
            for k in range(k0, k1):
                b = NS.at(a, k)
                if P.kind[b] == WALL and NS.listed(NS.pair_vector(xa, P.x[b])):
                    distance = xa.dot(self.wall_normal[b]) - self.wall_offset[b]
                    if distance > -0.5 * self.dx:
                        w, c = kinematic_wall_condition(out, self.wall_normal[b], distance, self.wall_clearance, dt)
                        out = w
                        cut = ti.max(cut, c)
        return out, cut

    def kinematic_walls_summary(self) -> dict:
        """summary.json `kinematic_walls`: the clearance and how often the condition acted."""
        if not getattr(self, "kinematic_walls", False):
            return {}
        return {"kinematic_walls": {"clearance_dx": self.wall_clearance / self.dx,
                                    "particle_steps_cut": int(self.wall_cuts[None])}}

    # -- neighbours ---------------------------------------------------------------------
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
    def live_n(self):
        """The particle loops' length: n while this step runs, 0 for a step a device loop skips."""
        return self.n * self.clock.live[None]

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
        for a in range(self.live_n()):
            if P.kind[a] == FLUID:
                xa = P.x[a]
                rho = P.mass[a] * self.kernel.w0
                for s in range(NS.slots()):
                    k0, k1 = NS.span(a, s)
                    for k in range(k0, k1):
                        b = NS.at(a, k)
                        r_ab = NS.pair_vector(xa, P.x[b])
                        if NS.listed(r_ab):  # compiled out with lists
                            r = r_ab.norm()
                            rho += P.mass[b] * self.kernel.w(r)
                P.rho[a] = rho * self.inv_lattice_sum

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
        for a in range(self.live_n()):
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
        for a in range(self.live_n()):
            if P.kind[a] == WALL:
                xa = P.x[a]
                sum_w = 0.0
                sum_pw = 0.0
                sum_rho_rw = ti.Vector.zero(float, self.dim)
                sum_vw = ti.Vector.zero(float, self.dim)
                for s in range(NS.slots()):
                    k0, k1 = NS.span(a, s)
                    for k in range(k0, k1):
                        b = NS.at(a, k)
                        r_ab = NS.pair_vector(xa, P.x[b])
                        if NS.listed(r_ab):  # compiled out with lists
                            if P.kind[b] == FLUID:
                                w = self.kernel.w(r_ab.norm())
                                sum_w += w
                                sum_pw += P.p[b] * w
                                sum_rho_rw += P.rho[b] * r_ab * w
                                if ti.static(self.features.no_slip):
                                    sum_vw += P.v[b] * w
                body_acc = self.body_force(xa)  # (g - a_wall); walls do not accelerate
                # walls push, never pull: a negative extrapolated pressure (wall above a free surface)
                # would glue fluid to the wall
                p = ti.max(adami_wall_pressure(sum_pw, sum_rho_rw, sum_w, body_acc), 0.0)
                if sum_w == 0.0:
                    p = self.p_background
                P.p[a] = p
                rho_w = tait_density(p, self.rho0, self.B, self.gamma, self.p_background)
                P.rho[a] = rho_w
                P.mass[a] = rho_w * self.lattice_volume  # a wall particle stands for dx^dim of ghost fluid
                if ti.static(self.features.no_slip):
                    self.v_ghost[a] = adami_wall_velocity(P.v[a], sum_vw, sum_w)

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
        """dt = min(CFL h / (c + |v|max), CFL sqrt(h / |a|max), 0.125 h^2 / nu, dt_max), or the fixed dt."""
        tc = self.cfg.time
        if tc.dt != AUTO:
            self.last_dt_limit = "fixed"
            return min(float(tc.dt), self.dt_cap)
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
        return min(float(limits[self.last_dt_limit]), self.dt_cap)

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

    # -- checkpoints ------------------------------------------------------------------------------
    def state_items(self) -> tuple[dict[str, ti.Field], dict[str, np.ndarray], dict[str, dict]]:
        """Everything a bit-identical restart needs, found generically: every Taichi field, numpy array
        and plain Python value (numbers, strings, lists, dicts) held by the solver or by a project object
        it holds (particles, neighbour search, PPE, shifting, loop schedule), current particle order and
        neighbour lists included. Returns (fields, arrays, plain values per owner), keyed `owner.attr`."""
        fields: dict[str, ti.Field] = {}
        arrays: dict[str, np.ndarray] = {}
        plain: dict[str, dict] = {}
        seen: set[int] = set()

        def walk(obj, prefix: str) -> None:
            seen.add(id(obj))
            values = {}
            for name, value in vars(obj).items():
                key = f"{prefix}.{name}"
                if isinstance(value, ti.Field):
                    fields[key] = value
                elif isinstance(value, np.ndarray):
                    arrays[key] = value
                elif _is_plain(value):
                    values[name] = value
                elif _is_project_object(value) and id(value) not in seen:
                    walk(value, key)
            plain[prefix] = values

        walk(self, "solver")
        return fields, arrays, plain

    def restore_state(self, fields: dict[str, np.ndarray], plain: dict[str, dict]) -> None:
        """Put back what `state_items` saved (fields and numpy arrays by key, plain values by owner)."""
        own_fields, own_arrays, own_plain = self.state_items()
        missing = (set(own_fields) | set(own_arrays)) - set(fields)
        if missing:
            raise ValueError(f"checkpoint lacks {sorted(missing)[:3]}: written by another solver or version")
        for key, f in own_fields.items():
            f.from_numpy(fields[key])
        for key, a in own_arrays.items():
            a[...] = fields[key]
        owners = {"solver": self}
        for prefix in sorted(own_plain, key=len):
            if prefix != "solver":
                parent, name = prefix.rsplit(".", 1)
                owners[prefix] = getattr(owners[parent], name)
            for name, value in plain.get(prefix, {}).items():
                setattr(owners[prefix], name, value)
