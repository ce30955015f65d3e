"""Pre-flight memory estimate: particle count and bytes a run will need, from the config alone.

Nothing here allocates particles: fluid blocks and wall boxes are tensor-product lattices, so their counts are
products of 1D axis counts (`scene.lattice.axis_points`, the same arithmetic the builder uses), and a sphere is
counted row by row. The bytes follow what the solvers allocate: per particle (Taichi fields, neighbour lists, PPE
arrays), per cell (and the multigrid's cell levels), the host's numpy arrays, lattice temporaries and output copies,
and a fixed baseline. `HOST_FACTOR` and `BASELINE_BYTES` are calibrated against the peak RSS of dam_break_2d and
dam_break_3d runs (scripts/measure_memory.py). What is counted, item by item: docs/notes/memory.md.
"""

from __future__ import annotations

import math
import subprocess
from dataclasses import dataclass, replace

import numpy as np

from taichi_sph.config.schema import AUTO, Body, Config
from taichi_sph.scene.bodies import fluid_body_points
from taichi_sph.scene.confinement import wcsph_shift_by_confinement
from taichi_sph.scene.lattice import auto_neighbour_capacity, axis_points
from taichi_sph.sph.kernels import support_factor

GIB = float(1 << 30)
# Python + numpy + Taichi runtime + LLVM compiling the step kernels: the measured peak RSS of dam-break
# runs extrapolated to no particle (3D compiles larger kernels); the same with a cold kernel cache
BASELINE_BYTES = {1: 160e6, 2: 170e6, 3: 235e6}
# the renderer (Vulkan context, frame buffers) when frames are written (measured: +92 MB, 960 x 540)
RENDER_BYTES = 95e6
# host copies per particle taken at output times (state dict, argsort, snapshot encoding), measured
HOST_OUTPUT_BYTES_PER_PARTICLE = {1: 150.0, 2: 200.0, 3: 260.0}
# the particle-order void grid per node (bool and int32 arrays, union-find edges; counted, not measured)
ORDER_GRID_BYTES_PER_NODE = 24.0
# scale of the counted host + device bytes, fitted to the measured peaks
HOST_FACTOR = 1.0


@dataclass(frozen=True)
class MemoryEstimate:
    n_fluid: int
    n_wall: int
    max_neighbors: int
    device_bytes: float     # Taichi fields (host RAM on the CPU backend)
    host_bytes: float       # numpy arrays, build temporaries, output copies, baseline
    on_device: bool         # whether the fields live in GPU memory (cuda/vulkan/gpu)

    @property
    def n(self) -> int:
        return self.n_fluid + self.n_wall

    @property
    def host_total(self) -> float:
        """Bytes of host RAM: everything on the CPU backend, numpy and baseline on a GPU."""
        return self.host_bytes + (0.0 if self.on_device else self.device_bytes)

    def describe(self) -> str:
        line = (f"{self.n} particles ({self.n_fluid} fluid + {self.n_wall} wall), {self.max_neighbors} neighbour "
                f"slots each: ~{self.host_total / GIB:.2f} GiB host memory")
        if self.on_device:
            line += f", ~{self.device_bytes / GIB:.2f} GiB device memory"
        return line


# ----------------------------------------------------------------------------- counting
def _inside(axis: np.ndarray, lo: float, hi: float) -> int:
    return int(np.count_nonzero((axis > lo) & (axis < hi)))


def _sphere_count(dim: int, radius: float, dx: float) -> int:
    """Cell-centred lattice points (geometry.lattice_sphere) within radius - dx/2 of the centre,
    counted along rows of the last axis."""
    n = int(math.ceil(radius / dx))
    if (2 * n) ** (dim - 1) > 4_000_000:
        unit = {1: 2.0, 2: math.pi, 3: 4.0 / 3.0 * math.pi}[dim]
        return int(unit * (radius - 0.5 * dx) ** dim / dx ** dim)
    r_keep = radius - 0.5 * dx + 1e-12
    offs = (np.arange(-n, n) + 0.5) * dx
    if dim == 1:
        return int(np.count_nonzero(np.abs(offs) <= r_keep))
    grids = np.meshgrid(*([offs] * (dim - 1)), indexing="ij")
    rest = r_keep * r_keep - sum(g.ravel() ** 2 for g in grids)
    # points (j + 1/2) dx with j >= 0 up to sqrt(rest): floor(sqrt(rest) / dx + 1/2) on each side
    half = np.floor(np.sqrt(np.maximum(rest, 0.0)) / dx + 0.5 + 1e-9)
    return int(np.sum(np.where(rest >= 0.0, 2 * np.minimum(half, n), 0)))


def body_points(body: Body, dx: float, layers: int) -> tuple[int, int]:
    """(points the body contributes, points of the largest lattice built for it); `layers`: a wall_box's
    particle layers (Config.wall_layers)."""
    if body.type == "fluid_sphere":
        count = _sphere_count(len(body.center), body.radius, dx)
        return count, (2 * int(math.ceil(body.radius / dx)) + 1) ** len(body.center)
    if body.type == "wall_box":
        thick = layers * dx
        lo_ext = [body.lo[a] - thick for a in range(len(body.lo))]
        hi_ext = [body.hi[a] + thick for a in range(len(body.lo))]
        if body.open_top:
            hi_ext[-1] = body.hi[-1]
        axes = [axis_points(lo_ext[a], hi_ext[a], dx) for a in range(len(body.lo))]
        full = math.prod(len(ax) for ax in axes)
        inner = math.prod(_inside(axes[a], body.lo[a], body.hi[a]) for a in range(len(body.lo)))
        return full - inner, full
    count = math.prod(len(axis_points(body.lo[a], body.hi[a], dx)) for a in range(len(body.lo)))
    return count, count


def particle_counts(cfg: Config) -> tuple[int, int, int]:
    """(fluid, wall, largest lattice temporary) for the config, without building a particle.
    Fluid particles on wall sites (removed by the builder) are still counted: an upper bound. Walls at their own
    spacing (dx / walls.refinement); a hexagonal packing's fluid (2D only) counted by building its points."""
    dx = cfg.particles.dx
    fluid = wall = largest = 0
    for body in cfg.bodies:
        if body.type.startswith("fluid") and cfg.particles.packing == "hexagonal":
            count = lattice = len(fluid_body_points(body, dx, "hexagonal")[0])
        elif body.type.startswith("fluid"):
            count, lattice = body_points(body, dx, cfg.wall_layers(body))
        else:
            count, lattice = body_points(body, cfg.wall_dx, cfg.wall_layers(body) * cfg.wall_refinement)
        largest = max(largest, lattice)
        if body.type.startswith("fluid"):
            fluid += count
        else:
            wall += count
    return fluid, wall, largest


# ----------------------------------------------------------------------------- bytes
def neighbour_capacity(cfg: Config) -> int:
    """Neighbour-list slots per particle, as SolverBase sizes them (support x (1 + skin)); 0 with access 'cells'."""
    if cfg.particles.neighbor_access != "lists":
        return 0
    if cfg.particles.max_neighbors != AUTO:
        return int(cfg.particles.max_neighbors)
    radius = support_factor(cfg.particles.kernel) * cfg.h * (1.0 + cfg.skin_fraction)
    return auto_neighbour_capacity(cfg, radius)


def device_bytes_per_particle(cfg: Config, n_fluid: int, n_wall: int, render: bool) -> float:
    """Bytes of Taichi fields per particle (see the module doc for the list)."""
    from taichi_sph.sph.features import Features
    f = Features.from_config(cfg, n_wall)
    fp = 8 if cfg.precision == "f64" else 4
    d = cfg.dim
    nb = neighbour_capacity(cfg)
    floats = 3 * d + 3                      # x, v, acc, rho, p, mass
    ints = 2                                # kind, id
    floats += 2 * d + 3                     # permutation scratch of x, v, rho, p, mass
    ints += 2 + 5 + nb                      # scratch of kind, id; cell sort; neighbour list
    if cfg.skin_fraction > 0.0:
        floats += d
    if f.ghost_velocity:
        floats += d
    # WCSPH's shift left unset is on where the fluid fills its container (scene/confinement.py), which only the built
    # particles tell: counted as on, an upper bound of d floats and an int a particle
    if f.shifting or wcsph_shift_by_confinement(cfg):
        floats += d + d * f.shifting_correction          # the shift (+ the Taylor correction's dv)
        floats += f.shifting_density in ("taylor", "continuity")  # the density's correction
        ints += 1                                         # this step's surface flags
        ints += f.tensile_instability_control             # the free-surface region kept for it
    if cfg.solver == "wcsph":
        floats += (f.density == "continuity") + (f.density_diffusion != "none") + f.dim * (f.density_diffusion == "antuono")
        if f.walls and cfg.wall_clearance is not None:
            floats += 2 * (d + 1)                           # wall planes (+ scratch)
            ints += 1                                       # near-wall flag
    else:
        kinematic = f.walls and cfg.wall_clearance is not None
        floats += 2 * ((d + 1) if kinematic else 0) + d     # wall planes (+ scratch), acc scratch
        ints += 2 * (kinematic and cfg.shifting_walls == "mirror")  # container-face flag (+ scratch)
        floats += 1 + d                                     # rho_summation, grad_p_estimate
        floats += 4 + nb + {"cg": 3, "mgcg": 4 + 3 ** d - 1}.get(cfg.isph.ppe.solver_for(n_fluid), 0)
        ints += 2 + nb                                      # role, row start, a column index per pair
    if f.free_slip_normal_viscosity and cfg.wall_clearance is None:
        floats += 2 * d                                     # wall face normals (+ scratch)
    extra = 24.0 if render else 0.0
    return floats * fp + ints * 4 + extra


def cell_count(cfg: Config) -> int:
    """Cells of the neighbour grid (support-sized, one layer of margin on non-periodic axes)."""
    radius = support_factor(cfg.particles.kernel) * cfg.h * (1.0 + cfg.skin_fraction)
    total = 1
    for a in range(cfg.dim):
        length = cfg.domain.hi[a] - cfg.domain.lo[a]
        total *= max(int(length // radius), 3) if cfg.periodic[a] else int(math.ceil(length / radius)) + 2
    return total


def order_grid_nodes(cfg: Config) -> int:
    """Nodes of the particle-order void grid at its largest: spacing dx over the whole domain (it covers
    the fluid's bounding box and 3.5 dx beyond it)."""
    total = 1
    for a in range(cfg.dim):
        total *= int(math.ceil((cfg.domain.hi[a] - cfg.domain.lo[a]) / cfg.particles.dx)) + 8
    return total


def multigrid_bytes(cfg: Config, n_fluid: int) -> float:
    """mgcg's cell levels: a 3^dim stencil and five vectors per cell of the neighbour grid, and the coarser
    levels (each 2^dim times smaller)."""
    if cfg.solver != "isph" or cfg.isph.ppe.solver_for(n_fluid) != "mgcg":
        return 0.0
    fp = 8 if cfg.precision == "f64" else 4
    return (3 ** cfg.dim + 5) * fp * cell_count(cfg) * 2 ** cfg.dim / (2 ** cfg.dim - 1)


def on_device(arch: str) -> bool:
    return arch in ("cuda", "vulkan", "gpu", "auto") and gpu_memory_available() is not None


def estimate(cfg: Config, *, render: bool = False, device: bool | None = None) -> MemoryEstimate:
    """Bytes the run will need on the host and (on a GPU backend) on the device."""
    fluid, wall, largest = particle_counts(cfg)
    n = fluid + wall
    dev = device_bytes_per_particle(cfg, fluid, wall, render) * n + 8.0 * cell_count(cfg) + multigrid_bytes(cfg, fluid)
    kept = (2 * cfg.dim + 3) * 8 + 4                  # ParticleArrays (float64) kept by the run
    build = largest * (2 * cfg.dim * 8 + 1)           # meshgrid + stacked points of the largest body
    # output copies, and a checkpoint's largest single field copy (the neighbour list) beside them
    outputs = HOST_OUTPUT_BYTES_PER_PARTICLE[cfg.dim] * n + max(4 * neighbour_capacity(cfg) * n,
                                                                ORDER_GRID_BYTES_PER_NODE * order_grid_nodes(cfg))
    host = BASELINE_BYTES[cfg.dim] + (RENDER_BYTES if render else 0.0) + kept * n + max(build, outputs)
    gpu = on_device(cfg.arch) if device is None else device
    return MemoryEstimate(fluid, wall, neighbour_capacity(cfg), HOST_FACTOR * dev, HOST_FACTOR * host, gpu)


# ----------------------------------------------------------------------------- what is there
def _cgroup_limit() -> float | None:
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = open(path).read().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 1 << 60:
            return float(text)
    return None


def host_memory_available() -> float:
    """MemAvailable of /proc/meminfo (bytes), capped by a cgroup memory limit; inf if unknown."""
    avail = math.inf
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = float(line.split()[1]) * 1024.0
                    break
    except OSError:
        pass
    limit = _cgroup_limit()
    return min(avail, limit) if limit is not None else avail


_GPU_FREE: list[float | None] = []


def gpu_memory_available() -> float | None:
    """Free memory of the first NVIDIA GPU (bytes) from nvidia-smi, None when there is none."""
    if _GPU_FREE:
        return _GPU_FREE[0]
    free = None
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=memory.free", "--format=csv,noheader,nounits"],
                             capture_output=True, text=True, timeout=5)
        if out.returncode == 0 and out.stdout.strip():
            free = float(out.stdout.split()[0]) * 1024.0 * 1024.0
    except (OSError, subprocess.SubprocessError, ValueError):
        free = None
    _GPU_FREE.append(free)
    return free


def with_dx(cfg: Config, dx: float) -> Config:
    return replace(cfg, particles=replace(cfg.particles, dx=dx))


def finest_dx_that_fits(cfg: Config, fits) -> float | None:
    """The smallest particles.dx (3 significant digits, rounded up) whose estimate `fits`, at most 1000x
    the configured one; None if even that does not fit."""
    lo, hi = cfg.particles.dx, cfg.particles.dx * 1000.0
    if not fits(with_dx(cfg, hi)):
        return None
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        if fits(with_dx(cfg, mid)):
            hi = mid
        else:
            lo = mid
        if hi / lo < 1.001:
            break
    digits = 2 - int(math.floor(math.log10(hi)))
    rounded = math.ceil(hi * 10 ** digits) / 10 ** digits
    return rounded


def preflight(cfg: Config, *, render: bool = False) -> tuple[MemoryEstimate, str | None]:
    """The estimate, and the refusal line when it exceeds the host's (or the GPU's) available memory."""
    est = estimate(cfg, render=render)
    host_avail = host_memory_available()
    gpu_avail = gpu_memory_available() if est.on_device else None

    def fits(c: Config) -> bool:
        e = estimate(c, render=render, device=est.on_device)
        ok = e.host_total <= host_avail
        return ok and (gpu_avail is None or e.device_bytes <= gpu_avail)

    if fits(cfg):
        return est, None
    if est.host_total > host_avail:
        need = f"~{est.host_total / GIB:.1f} GiB of host memory, {host_avail / GIB:.1f} GiB available"
    else:
        need = f"~{est.device_bytes / GIB:.1f} GiB of GPU memory, {gpu_avail / GIB:.1f} GiB available"
    dx = finest_dx_that_fits(cfg, fits)
    hint = (f"particles.dx >= {dx:g} fits ({sum(particle_counts(with_dx(cfg, dx))[:2])} particles)"
            if dx is not None else "no resolution fits")
    line = (f"{est.n} particles ({est.n_fluid} fluid + {est.n_wall} wall at dx = {cfg.particles.dx:g}) need {need}: "
            f"{hint}")
    return est, line
