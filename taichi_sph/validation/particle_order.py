"""Particle-order diagnostics at output times: clumping, voids, the free-surface fraction.

Every run (both solvers, 1D/2D/3D) writes, per output row of timeseries.csv:

- `min_pair_distance_dx`: min |x_a - x_b| / dx over fluid-fluid pairs (a Taichi min-reduction over the
  neighbour lists; a lattice gives 1);
- `min_wall_distance_dx`: the same over fluid-wall pairs (empty without walls; the fluid starts dx/2
  from a wall face and 1 dx from the nearest wall particle). Not part of the clumping test;
- `free_surface_fraction`: the fraction of fluid particles the free-surface indicator flags, ISPH's
  test (physics/free_surface.py) for either solver: kernel sum c_a < `isph.free_surface_threshold`, or
  c_a < 0.97 with no fluid neighbour in the 45-degree cone around the outward normal;
- `void_particles`: interior fluid particles whose kernel sum is below the threshold, at a hole in the
  fluid (`void_particles` below says exactly which): the particles the indicator misjudges as free
  surface although no outside air reaches them;
- `interior_density_error`: max |rho_a - rho0| / rho0 of the solver's own density field over the
  full-support particles: fluid particles with no free-surface particle (themselves included) within
  the kernel support, so that no part of their support lies in the air. `max_density_error` counts every
  fluid particle: with a summation density (ISPH; WCSPH `density: summation`) a particle whose support
  the free surface cuts has a kernel-sum deficit that is not expansion (ISPH floors it at rho0 only
  below c_a = 0.97, so the band 0.97-1 shows as up to 3%). This one is compression or expansion of fluid
  whose neighbourhood is complete, for either solver;
- `interior_density_drift`: the signed mean of rho_a / rho0 - 1 over the same particles: a uniform drift of the
  whole fluid's density, which the max above does not tell from local compression (WCSPH's continuity density
  does not see a particle shift's volume change: in the lid-driven cavity at Re 1000 with shifting A = 20 the
  whole fluid drifted +6.5% in 6.5 s before the density guard stopped the run; a fluid at rest under gravity
  sits at g H / (2 c0^2), 0.1-0.2% in the bundled tanks). summary.json warns past `DENSITY_DRIFT_WARN`;
- `interior_kernel_sum_error`: max |c_a - 1| over the same particles: the summation density the current
  arrangement implies (ISPH's density at the next step), the same definition for both solvers, so it
  measures the disorder of the arrangement, whatever density the solver integrates (WCSPH's continuity
  density does not see it).

summary.json `particle_order` holds the extremes over the run (`ParticleOrderLog.summary`), and a
warning is added when a void (>= 1 void particle at some output) or clumping (a fluid pair closer than
`CLUMPING_DX` dx) appears.

They use the neighbour lists of the last build: they hold every pair within the support as long as the
Verlet skin allows (WCSPH); ISPH rebuilds them each step before moving, so a pair that came within
reach during the last step is missing from the kernel sums (its weight is near zero at the support's
edge; a pair closer than dx/2 now was in the list). Cost: one pass like a density summation, and a
grid of dx over the fluid's bounding box (numpy), at output times only.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_sph.config.schema import Config
from taichi_sph.physics.free_surface import SURFACE_CANDIDATE, in_surface_cone, kernel_sum_ratio
from taichi_sph.scene.bodies import FLUID
from taichi_sph.scene.lattice import lattice_kernel_sum
from taichi_sph.sph.particles import np_float

# a fluid pair closer than this (in dx) is clumping. On the initial lattice the nearest pair is 1 dx;
# compression at the density bounds the scenes meet (3%) shortens it by 1% (2D), and cavity_2d (ISPH,
# shifting on) stays at 0.56-0.65 dx over 10 s; pairing pulls pairs well inside dx/2, where the kernels'
# repulsion fades (the cubic spline's |grad W| peaks at 2h/3 and vanishes at r = 0): the default dam
# break reaches 0.003 dx (WCSPH) and 0.001 dx (ISPH). 0.5 dx is also issue 15's acceptance bound.
CLUMPING_DX = 0.5
# |interior_density_drift| past this is warned of: a weakly compressible fluid's mean density departs from rho0 by
# about Ma^2 / 2 (0.5% at c0 = 10 U) and by g H / (2 c0^2) under gravity (0.1-0.2% in the bundled tanks)
DENSITY_DRIFT_WARN = 0.02
ORDER_COLUMNS = ["min_pair_distance_dx", "min_wall_distance_dx", "void_particles", "free_surface_fraction",
                 "interior_density_error", "interior_density_drift", "interior_kernel_sum_error"]
_FAR = 1e30


# ----------------------------------------------------------------------------- voids on a grid
def _components(empty: np.ndarray, periodic: tuple[bool, ...]) -> np.ndarray:
    """Connected components of the True nodes of a boolean grid (face neighbours, wrapped on periodic
    axes): an int array of the grid's shape, each empty node its component's smallest flat index, -1
    elsewhere. Vectorised union-find (hook roots to the smaller root, then pointer jumping)."""
    flat = empty.ravel()
    ids = np.flatnonzero(flat)
    index = np.full(flat.size, -1, dtype=np.int32)  # int32: a grid of 2^31 nodes would not fit anyway
    index[ids] = np.arange(len(ids), dtype=np.int32)
    index = index.reshape(empty.shape)
    us, vs = [], []
    for axis in range(empty.ndim):
        nxt = np.roll(index, -1, axis=axis)
        pair = (index >= 0) & (nxt >= 0)
        if not periodic[axis]:
            edge = [slice(None)] * empty.ndim
            edge[axis] = -1
            pair[tuple(edge)] = False
        us.append(index[pair])
        vs.append(nxt[pair])
    u, v = np.concatenate(us), np.concatenate(vs)
    parent = np.arange(len(ids), dtype=np.int32)
    while True:
        ru, rv = parent[u], parent[v]
        differ = ru != rv
        if not differ.any():
            break
        np.minimum.at(parent, np.maximum(ru, rv)[differ], np.minimum(ru, rv)[differ])
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    labels = np.full(flat.size, -1, dtype=np.int64)
    labels[ids] = ids[parent]  # the root's flat index
    return labels.reshape(empty.shape)


def void_particles(x: np.ndarray, kernel_sum: np.ndarray, threshold: float, dx: float, lo, hi,
                   periodic: tuple[bool, ...]) -> np.ndarray:
    """Which fluid particles border a void: kernel sum c_a < threshold, a hole next to them that no
    outside air reaches, and no outside air next to them.

    Holes: a grid of spacing dx over the fluid's bounding box within the domain (and 3.5 spacings beyond
    it on non-periodic axes; the whole period on periodic ones; particles outside it mark nothing). A node is empty when no fluid particle lies within one
    spacing of it along every axis (|x_d - y_d| < dx for all d: a lattice leaves no node empty, a missing
    disc of radius 2 dx does). Empty nodes connected (face neighbours, wrapped on periodic axes) to the
    grid's border are outside air; the others are enclosed holes. Walls are not in the grid: a gap
    between fluid and a wall reaches the border around the fluid, so it is never a void (the fluid-wall
    distance is reported apart). "Next to": within 2 spacings along every axis (a free-surface particle
    has an outside node within 2 dx).

    x: (N, dim) fluid positions, kernel_sum: (N,) c_a. Returns a boolean mask over the N particles."""
    n, dim = x.shape
    out = np.zeros(n, dtype=bool)
    candidates = kernel_sum < threshold
    if not candidates.any():
        return out
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    origin, spacing, shape = np.empty(dim), np.empty(dim), np.empty(dim, dtype=np.int64)
    for d in range(dim):
        if periodic[d]:
            shape[d] = max(int(round((hi[d] - lo[d]) / dx)), 1)
            origin[d], spacing[d] = lo[d], (hi[d] - lo[d]) / shape[d]
        else:  # the fluid's extent, within the domain (an unstable run's state may hold inf or NaN)
            coord = x[np.isfinite(x[:, d]), d]
            first = max(coord.min(), lo[d]) if len(coord) else lo[d]
            last = max(min(coord.max(), hi[d]), first) if len(coord) else hi[d]
            origin[d], spacing[d] = first - 3.5 * dx, dx  # nodes between the lattice sites
            shape[d] = int(math.ceil((last - origin[d]) / dx + 3.5)) + 1
    # node i sits at origin + i spacing; a particle marks the nodes within one spacing along every axis
    u = (x - origin) / spacing
    u = np.clip(np.nan_to_num(u, nan=-10.0), -10.0, shape + 10.0)  # off the grid: marks nothing
    base = np.floor(u).astype(np.int64)
    occupied = np.zeros(tuple(shape), dtype=bool)
    for offset in np.ndindex(*(3,) * dim):
        node = base + (np.asarray(offset) - 1)
        near = np.all(np.abs(node - u) < 1.0, axis=1)
        node = _wrap(node, shape, periodic)
        ok = near & np.all((node >= 0) & (node < shape), axis=1)
        occupied[tuple(node[ok].T)] = True
    labels = _components(~occupied, periodic)
    outside_roots = set()
    for d in range(dim):
        if not periodic[d]:
            for face in (0, -1):
                edge = [slice(None)] * dim
                edge[d] = face
                roots = labels[tuple(edge)]
                outside_roots.update(np.unique(roots[roots >= 0]).tolist())
    outside = np.isin(labels, np.fromiter(outside_roots, dtype=np.int64, count=len(outside_roots)))
    enclosed = (labels >= 0) & ~outside
    if not enclosed.any():
        return out
    idx = np.flatnonzero(candidates)
    near_hole = np.zeros(len(idx), dtype=bool)
    near_air = np.zeros(len(idx), dtype=bool)
    for offset in np.ndindex(*(4,) * dim):
        node = base[idx] + (np.asarray(offset) - 1)
        near = np.all(np.abs(node - u[idx]) <= 2.0, axis=1)
        node = _wrap(node, shape, periodic)
        ok = near & np.all((node >= 0) & (node < shape), axis=1)
        at = tuple(node[ok].T)
        near_hole[ok] |= enclosed[at]
        near_air[ok] |= outside[at]
    out[idx] = near_hole & ~near_air
    return out


def _wrap(node: np.ndarray, shape: np.ndarray, periodic: tuple[bool, ...]) -> np.ndarray:
    node = node.copy()
    for d, per in enumerate(periodic):
        if per:
            node[:, d] %= shape[d]
    return node


# ----------------------------------------------------------------------------- the Taichi pass
@ti.data_oriented
class OrderProbe:
    """Kernel sums, free-surface flags and closest pairs of a solver's particles, from its neighbour lists.

    `OrderProbe(solver).particles()` gives the per-particle arrays, `.measure()` the timeseries row."""

    def __init__(self, solver) -> None:
        cfg = solver.cfg
        self.solver = solver
        self.dx = cfg.particles.dx
        self.volume = self.dx ** cfg.dim
        self.lattice_sum = lattice_kernel_sum(cfg, solver.kernel.w_np)
        self.threshold = cfg.isph.free_surface_threshold
        self.rho0 = cfg.fluid.rho0
        self.lo, self.hi, self.periodic = tuple(cfg.domain.lo), tuple(cfg.domain.hi), tuple(cfg.periodic)
        self.closest = ti.field(float, shape=2)  # min pair distance: [fluid-fluid, fluid-wall]
        self.surface = ti.field(ti.i32, shape=solver.n)  # the flags of `surface`, for the pair term

    @ti.kernel
    def _measure(self, kernel_sum: ti.types.ndarray(), surface: ti.types.ndarray(), pos: ti.types.ndarray(),
                 rho: ti.types.ndarray(), full: ti.types.ndarray()):
        """kernel_sum[a] = c_a, surface[a] = the ISPH free-surface flag (-1: not fluid), pos[a] = x_a,
        rho[a] = the solver's density, full[a] = 1 when no free-surface particle (a included) lies within
        a's support; closest = the smallest fluid-fluid and fluid-wall pair distances."""
        S = self.solver
        P = S.particles
        NS = S.nsearch
        for i in range(2):
            self.closest[i] = _FAR
        for a in range(S.n):
            for d in ti.static(range(S.dim)):
                pos[a, d] = P.x[a][d]
            kernel_sum[a] = 0.0
            surface[a] = -1
            self.surface[a] = -1
            rho[a] = P.rho[a]
            if P.kind[a] == FLUID:
                sums = ti.Struct(w=S.kernel.w0, grad_c=ti.Vector.zero(float, S.dim))
                NS.for_each_neighbor(a, P.x, self.kernel_sum_pair, sums)
                c = kernel_sum_ratio(sums.w, self.volume, self.lattice_sum)
                flag = c < self.threshold
                if not flag and c < SURFACE_CANDIDATE:
                    cone = ti.Struct(outward=-sums.grad_c.normalized(1e-12), flag=True)
                    NS.for_each_neighbor(a, P.x, self.surface_cone_pair, cone)
                    flag = cone.flag
                kernel_sum[a] = c
                surface[a] = ti.select(flag, 1, 0)
                self.surface[a] = surface[a]
        for a in range(S.n):  # after the loop above: every flag is set
            full[a] = 0
            if surface[a] == 0:
                support = ti.Struct(full=1)
                NS.for_each_neighbor(a, P.x, self.full_support_pair, support)
                full[a] = support.full

    @ti.func
    def kernel_sum_pair(self, a, b, r_ab, sums: ti.template()):
        """sum_b W_ab and grad c (unscaled) of pair (a, b); the closest fluid-fluid and fluid-wall pairs."""
        S = self.solver
        r = r_ab.norm()
        sums.w += S.kernel.w(r)
        sums.grad_c += S.kernel.grad_w(r_ab, r)
        if S.particles.kind[b] == FLUID:
            ti.atomic_min(self.closest[0], r)
        else:
            ti.atomic_min(self.closest[1], r)

    @ti.func
    def surface_cone_pair(self, a, b, r_ab, cone: ti.template()):
        """A fluid neighbour in the scan cone around a's outward normal: a is not at the free surface."""
        r_ba = -r_ab
        if self.solver.particles.kind[b] == FLUID and in_surface_cone(r_ba, r_ba.norm(), cone.outward,
                                                                      self.solver.support):
            cone.flag = False

    @ti.func
    def full_support_pair(self, a, b, r_ab, support: ti.template()):
        """A free-surface particle within a's support: a's support is not full."""
        if self.surface[b] == 1:
            support.full = 0

    def particles(self) -> dict:
        """Per fluid particle (in the solver's current order): x, kernel_sum c_a, free_surface (the
        indicator's flag), void (void_particles), rho (the solver's density), full_support (no
        free-surface particle within the support); and the closest fluid-fluid / fluid-wall distances
        in dx (None where there is no such pair)."""
        S = self.solver
        c = np.zeros(S.n, dtype=np_float())
        surface = np.zeros(S.n, dtype=np.int32)
        pos = np.zeros((S.n, S.dim), dtype=np_float())
        rho = np.zeros(S.n, dtype=np_float())
        full = np.zeros(S.n, dtype=np.int32)
        self._measure(c, surface, pos, rho, full)
        fluid = surface >= 0
        x = pos[fluid].astype(np.float64)
        kernel_sum = c[fluid].astype(np.float64)
        closest = [float(v) / self.dx if v < 0.5 * _FAR else None for v in self.closest.to_numpy()]
        void = (void_particles(x, kernel_sum, self.threshold, self.dx, self.lo, self.hi, self.periodic)
                if len(x) else np.zeros(0, dtype=bool))
        return {"x": x, "kernel_sum": kernel_sum, "free_surface": surface[fluid] == 1, "void": void,
                "rho": rho[fluid].astype(np.float64), "full_support": full[fluid] == 1,
                "min_pair_distance_dx": closest[0], "min_wall_distance_dx": closest[1]}

    def measure(self) -> dict:
        """The timeseries columns ORDER_COLUMNS at the current state."""
        p = self.particles()
        n = len(p["x"])
        full = p["full_support"]
        strain = p["rho"][full] / self.rho0 - 1.0  # the full-support particles' rho / rho0 - 1
        return {"min_pair_distance_dx": p["min_pair_distance_dx"], "min_wall_distance_dx": p["min_wall_distance_dx"],
                "void_particles": int(p["void"].sum()),
                "free_surface_fraction": float(p["free_surface"].sum()) / n if n else 0.0,
                "interior_density_error": float(np.abs(strain).max()) if full.any() else None,
                "interior_density_drift": float(np.mean(strain)) if full.any() else None,
                "interior_kernel_sum_error": float(np.abs(p["kernel_sum"][full] - 1.0).max()) if full.any() else None}


# ----------------------------------------------------------------------------- over the run
def density_drift_cause(cfg: Config) -> str:
    """What makes a run's mean interior density drift from its particles' volumes, as a hint: WCSPH's continuity
    density (with the shift, which it does not see; without it, the integrated div v). '' for a density that is
    a kernel sum (WCSPH's summation, ISPH's)."""
    if cfg.solver != "wcsph" or cfg.wcsph.density != "continuity":
        return ""
    if cfg.shifting_enabled and cfg.shifting.density != "continuity":  # 'continuity': the density follows the shift
        return ("WCSPH's continuity density with particle shifting does not see the shift's volume change; try "
                "`wcsph.density: summation`, `shifting.density: continuity` or shifting off")
    return ("WCSPH's continuity density integrates div v, not the particles' volumes; `wcsph.density: summation` "
            "follows the volumes, and a stiffer fluid (a larger fluid.reference_speed or fluid.c0) compresses, and "
            "drifts, less")


@dataclass
class ParticleOrderLog:
    """Extremes of the order columns over the output times (plain values: saved in checkpoints)."""

    clumping_dx: float = CLUMPING_DX
    min_pair: float | None = None
    min_pair_t: float | None = None
    min_wall: float | None = None
    max_void: int = 0
    max_void_t: float | None = None
    first_void_t: float | None = None
    void_outputs: int = 0
    first_clump_t: float | None = None
    surface_fraction_max: float = 0.0
    surface_fraction_final: float | None = None
    outputs: int = 0
    interior_density_error: float | None = None
    interior_kernel_sum_error: float | None = None
    density_drift: float | None = None  # the signed interior_density_drift of largest magnitude
    density_drift_t: float | None = None

    def record(self, t: float, row: dict) -> None:
        """Fold one output row (OrderProbe.measure) into the extremes."""
        self.outputs += 1
        pair = row["min_pair_distance_dx"]
        if pair is not None and (self.min_pair is None or pair < self.min_pair):
            self.min_pair, self.min_pair_t = pair, t
        if pair is not None and pair < self.clumping_dx and self.first_clump_t is None:
            self.first_clump_t = t
        wall = row["min_wall_distance_dx"]
        if wall is not None and (self.min_wall is None or wall < self.min_wall):
            self.min_wall = wall
        voids = row["void_particles"]
        if voids > 0:
            self.void_outputs += 1
            if self.first_void_t is None:
                self.first_void_t = t
        if voids > self.max_void:
            self.max_void, self.max_void_t = voids, t
        self.surface_fraction_max = max(self.surface_fraction_max, row["free_surface_fraction"])
        self.surface_fraction_final = row["free_surface_fraction"]
        for key in ("interior_density_error", "interior_kernel_sum_error"):
            value, worst = row.get(key), getattr(self, key)
            if value is not None and (worst is None or value > worst):
                setattr(self, key, value)
        drift = row.get("interior_density_drift")
        if drift is not None and (self.density_drift is None or abs(drift) > abs(self.density_drift)):
            self.density_drift, self.density_drift_t = drift, t

    def summary(self) -> dict:
        """summary.json `particle_order`."""
        return {"min_pair_distance_dx": self.min_pair, "min_pair_distance_t": self.min_pair_t,
                "min_wall_distance_dx": self.min_wall, "clumping_below_dx": self.clumping_dx,
                "max_void_particles": self.max_void, "max_void_t": self.max_void_t,
                "void_outputs": self.void_outputs, "outputs": self.outputs,
                "free_surface_fraction_max": self.surface_fraction_max,
                "free_surface_fraction_final": self.surface_fraction_final,
                "interior_kernel_sum_error_max": self.interior_kernel_sum_error,
                "interior_density_drift_extreme": self.density_drift, "interior_density_drift_t": self.density_drift_t}

    def warnings(self, drift_cause: str = "") -> list[str]:
        """One line each for a void, for clumping and for a drift of the mean density (with `drift_cause`:
        density_drift_cause), if they appeared."""
        out = []
        if self.first_void_t is not None:
            out.append(f"particle order: void at t = {self.first_void_t:.4g} s (interior particles with a kernel sum "
                       f"below the free-surface threshold around a hole; up to {self.max_void} at t = "
                       f"{self.max_void_t:.4g} s, in {self.void_outputs} of {self.outputs} outputs)")
        if self.first_clump_t is not None:
            out.append(f"particle order: clumping at t = {self.first_clump_t:.4g} s (fluid particles closer than "
                       f"{self.clumping_dx:g} dx; closest {self.min_pair:.3g} dx at t = {self.min_pair_t:.4g} s)")
        if self.density_drift is not None and abs(self.density_drift) > DENSITY_DRIFT_WARN:
            out.append(f"particle order: the interior fluid's mean density drifted {100 * self.density_drift:+.2g}% "
                       f"(at t = {self.density_drift_t:.4g} s; more than {100 * DENSITY_DRIFT_WARN:g}%): the density "
                       f"no longer follows the particles' volumes" + (f" ({drift_cause})" if drift_cause else ""))
        return out
