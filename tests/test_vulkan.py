"""The device set: every code path that differs by arch, run on a GPU backend, against the CPU.

`TAICHI_SPH_TEST_ARCH=vulkan pytest -q -m vulkan` runs it on Taichi's Vulkan backend, in CI on Mesa's software
Vulkan (lavapipe, on the CPU: .ci/run); `TAICHI_SPH_TEST_ARCH=cuda` on an NVIDIA GPU (scripts/gpu_report.sh).
Without that variable every test here is skipped, and `pytest -q` deselects the set (marker `vulkan`). The
arch branches and the test that covers each: docs/gpu.md.

Each test builds its solvers in a fresh runtime, the device's or the CPU's (a solver built first after an init
is served from Taichi's offline cache on the next run). Tolerances against the CPU: f32 rounding drift, measured
on lavapipe (docs/gpu.md); the device's reductions add with atomics in thread order, the CPU's in a fixed order.
"""

import math
import os
import signal

import numpy as np
import pytest

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.linalg.ppe_slots import DONE, ITERATIONS
from taichi_sph.run.runtime import current_arch_name, init_taichi, reset
from taichi_sph.scene.bodies import build_particles
from taichi_sph.solvers.registry import make_solver
from taichi_sph.sph.precision import device_has_float64

ENV = "TAICHI_SPH_TEST_ARCH"
DEVICE = os.environ.get(ENV, "").strip()
DEVICES = ("vulkan", "cuda")

pytestmark = [
    pytest.mark.vulkan,
    pytest.mark.skipif(DEVICE not in DEVICES, reason=f"the device set runs with {ENV}=vulkan (software Vulkan "
                                                     f"will do) or {ENV}=cuda; {ENV} is {DEVICE or 'unset'}"),
]

# tiny scenes: the bundled dam breaks, coarse (2D: 800 fluid + 1.2k wall particles; 3D: 330 + 2.4k)
SCENES = {
    2: ("dam_break_2d.yaml", ["particles.dx=0.05"]),
    3: ("dam_break_3d.yaml", ["particles.dx=0.06"]),
}
# ISPH's free-surface particles get p = rho0 |g - a| dx/2 where grad C . grad p > 0 (physics/ppe_terms.py,
# free_surface_pressure), else 0. On the column's vertical face at rest grad C is horizontal and grad p vertical:
# the sign is that of grad C's vertical component, f32 noise, and the CPU and the device round it apart (a
# particle at mid-height got 0 Pa on the CPU and 245 Pa on lavapipe: 0.16 dx apart after 10 steps). Gravity
# leaning 0.6 degrees towards +x makes the sign definite on that face; with it the two agree to 1e-5 dx.
TILT = {2: "gravity=[0.1,-9.81]", 3: "gravity=[0.1,0.0,-9.81]"}
# simulated time of each comparison: ~50 WCSPH steps, 6-10 ISPH steps
T_END = {("wcsph", 2): 0.02, ("wcsph", 3): 0.04, ("isph", 2): 0.15, ("isph", 3): 0.12}

# Largest device-CPU difference allowed after those steps, by field: x in dx, v in the CPU run's max |v|, p in its
# max |p|, rho in rho0. Measured on lavapipe (docs/gpu.md), the largest of each solver's cases: WCSPH x 4.8e-6 dx,
# v 1.6e-5, p 1.0e-4, rho 2.4e-7; ISPH x 7.2e-6 dx, v 1.1e-6, p 1.3e-5, rho 7.3e-7. WCSPH's bounds are ~20x
# those. ISPH's allow for what lavapipe did not show but a GPU's many threads may: a CG that stops one
# iteration apart (the residual's atomic sums differ in the last bits), which moves p by up to the solve
# tolerance (1e-4). Both stay far below a real error: the one wrong Dirichlet value of the vertical face (TILT)
# moved x by 0.16 dx and v by 1.2e-2.
TOLERANCE = {"wcsph": {"x": 1e-4, "v": 3e-4, "p": 2e-3, "rho": 5e-6},
             "isph": {"x": 1e-3, "v": 1e-3, "p": 1e-3, "rho": 2e-5}}


def runtime(arch: str) -> None:
    """A fresh runtime: the device's, or the CPU's (TAICHI_SPH_TEST_ARCH would turn a request for the CPU
    into one for the device: it is lifted while the CPU starts)."""
    reset()
    if arch == "cpu":
        saved = os.environ.pop(ENV, None)
        try:
            init_taichi("cpu", "f32")
        finally:
            if saved is not None:
                os.environ[ENV] = saved
        assert current_arch_name() in ("x64", "arm64")
    else:
        init_taichi(arch, "f32")
        assert current_arch_name() == arch


def scene(dim: int, solver: str, access: str, *extra: str):
    name, sets = SCENES[dim]
    tilt = [TILT[dim]] if solver == "isph" else []
    return load_config(bundled_configs_dir() / name, sets + tilt + [f"solver={solver}",
                                                                   f"particles.neighbor_access={access}", *extra])


def by_id(st: dict) -> dict[str, np.ndarray]:
    """x, v, rho, p of a host state in particle-id order (the cell sort permutes the particles)."""
    order = np.argsort(st["id"])
    return {k: st[k][order] for k in ("x", "v", "rho", "p")}


def run_on(arch: str, cfg, t_end: float) -> dict:
    """Steps to t_end on `arch`: the state by particle id, the step count, t, the PPE iterations (ISPH)."""
    runtime(arch)
    solver = make_solver(cfg, build_particles(cfg))
    if cfg.solver == "wcsph":
        solver.schedule.serial = False  # no timing probe (the device is parallel anyway)
    else:
        solver.ppe.serial = False
    solver.prepare()
    solver.advance(10_000, math.inf, t_end)
    return {"state": by_id(solver.host_state()), "steps": solver.step_count, "t": solver.t,
            "iterations": list(getattr(solver, "iterations", [])), "dx": cfg.particles.dx, "rho0": cfg.fluid.rho0,
            "step_loop": getattr(solver, "step_loop", "device")}


def drift(cpu: dict, dev: dict) -> dict[str, float]:
    """max |device - CPU| per field, in the units of TOLERANCE."""
    a, b = cpu["state"], dev["state"]
    scale = {"x": cpu["dx"], "v": np.abs(a["v"]).max(), "p": np.abs(a["p"]).max(), "rho": cpu["rho0"]}
    return {k: float(np.abs(b[k] - a[k]).max() / scale[k]) for k in scale}


# ----------------------------------------------------------------------------- the device itself
def test_the_set_runs_on_the_device_and_gpu_picks_a_gpu_backend():
    """The fixture's runtime is the device's (the CPU request overridden); `gpu`/`auto` start a GPU backend
    (or Taichi's CPU fallback) without refusing it."""
    assert current_arch_name() == DEVICE
    reset()
    init_taichi("gpu", "f32")
    assert current_arch_name() in ("cuda", "vulkan", "metal", "opengl", "x64", "arm64")


# ----------------------------------------------------------------------------- device against CPU
# ISPH takes 'lists' only (it assembles its pressure equation from the stored lists). mgcg in 2D only: its GPU
# branches (the one-kernel iteration, the one-thread level threshold) are the same code in 3D, whose 27-slot
# stencil took 10 of the set's 13 minutes to compile cold (CPU and lavapipe; 3D mgcg runs in the CPU's slow set)
CASES = [("wcsph", 2, "lists", ()), ("wcsph", 2, "cells", ()), ("wcsph", 3, "lists", ()),
         ("isph", 2, "lists", ("isph.ppe.solver=mgcg",)), ("isph", 2, "lists", ("isph.ppe.solver=cg",)),
         ("isph", 3, "lists", ("isph.ppe.solver=cg",))]


@pytest.mark.parametrize("solver, dim, access, extra", CASES,
                         ids=[f"{s}-{d}d-{a}" + "".join("-" + e.split("=")[1] for e in x) for s, d, a, x in CASES])
def test_a_short_run_matches_the_cpu(solver, dim, access, extra):
    """The same scene to the same t on the CPU and on the device: the same number of steps, the same t, the same
    PPE iterations within one, and every field within f32 drift. WCSPH covers the device-resident step loop
    (one launch per step, the neighbour build gated inside it, parallel schedule), ISPH the parallel PPE loops,
    the atomic reductions, the device-side stopping test, mgcg's one-kernel iteration with the GPU's
    one-thread level threshold, and its dt and t on the device (solvers/isph_loop.py)."""
    cfg = scene(dim, solver, access, *extra)
    t_end = T_END[(solver, dim)]
    cpu = run_on("cpu", cfg, t_end)
    dev = run_on(DEVICE, cfg, t_end)
    assert dev["steps"] == cpu["steps"] >= 6
    assert dev["t"] == pytest.approx(t_end, abs=1e-9) and cpu["t"] == pytest.approx(t_end, abs=1e-9)
    if solver == "isph":
        assert dev["step_loop"] == cpu["step_loop"] == "device"  # ISPH's dt and t on the device (isph_loop.py)
        assert len(dev["iterations"]) == len(cpu["iterations"])
        assert all(abs(a - b) <= 1 for a, b in zip(cpu["iterations"], dev["iterations"])), (cpu["iterations"],
                                                                                             dev["iterations"])
    d = drift(cpu, dev)
    print(f"{solver} {dim}D {access}: {cpu['steps']} steps, device - CPU: " +
          ", ".join(f"{k} {v:.2g}" for k, v in d.items()))
    for k, v in d.items():
        assert np.isfinite(v) and v <= TOLERANCE[solver][k], (k, d)


# ----------------------------------------------------------------------------- without 64-bit floats
@pytest.mark.parametrize("solver", ["wcsph", "isph"])
def test_the_f32_only_path_on_the_device_matches_the_cpu(solver):
    """`float64: false` on the device (what an Apple GPU through MoltenVK gets: the rebased f32 clock, the f32
    stopping test) against the CPU's f64 clock and stopping test: the same steps, t, iterations within one, fields
    within the same f32 drift bounds."""
    extra = ("isph.ppe.solver=cg",) if solver == "isph" else ()
    t_end = T_END[(solver, 2)]
    cpu = run_on("cpu", scene(2, solver, "lists", *extra), t_end)
    dev = run_on(DEVICE, scene(2, solver, "lists", *extra, "float64=false"), t_end)
    assert dev["steps"] == cpu["steps"] >= 6 and dev["t"] == pytest.approx(t_end, abs=1e-9)
    assert all(abs(a - b) <= 1 for a, b in zip(cpu["iterations"], dev["iterations"]))
    d = drift(cpu, dev)
    print(f"{solver} 2D float64 false: {cpu['steps']} steps, device - CPU: " + ", ".join(f"{k} {v:.2g}" for k, v in d.items()))
    for k, v in d.items():
        assert np.isfinite(v) and v <= TOLERANCE[solver][k], (k, d)


def test_the_float64_probe_runs_on_the_device():
    """The capability probe compiles and runs its one-value f64 kernel (lavapipe and NVIDIA GPUs have 64-bit
    floats; a MoltenVK device would answer False and `float64: auto` would take the f32 path)."""
    runtime(DEVICE)
    assert device_has_float64()


def test_wide_fields_keep_their_own_slots_on_the_device():
    """taichi-dev/taichi#8803: in one SNode tree, an f64 field placed after a 4-byte field of odd length is
    addressed one slot low on the SPIR-V backends. `wide_fields` gives the 64-bit fields a tree of their own: each
    value written comes back, the i32 neighbour's included (on Taichi 1.7.4 + lavapipe the same layout in one
    tree reads the i32's last element back as the f64's low word)."""
    import taichi as ti

    from taichi_sph.sph.precision import wide_fields

    runtime(DEVICE)
    flags = ti.field(ti.i32, 3)  # 12 bytes: the next field of the same tree would sit at 4 mod 8
    scalar, array = wide_fields(ti.f64, (), 3)
    after = ti.field(ti.i32, ())

    @ti.kernel
    def write():
        for k in range(3):
            flags[k] = 7 + k
            array[k] = ti.cast(1.0, ti.f64) + ti.cast(k, ti.f64) * ti.cast(1e-12, ti.f64)
        scalar[None] = ti.cast(2.0, ti.f64) + ti.cast(1e-12, ti.f64)
        after[None] = 5

    write()
    assert flags.to_numpy().tolist() == [7, 8, 9] and after[None] == 5
    assert scalar[None] == 2.0 + 1e-12
    assert array.to_numpy().tolist() == [1.0 + k * 1e-12 for k in range(3)]


def test_f64_particle_fields_are_refused_on_the_device():
    """`precision: f64` on a SPIR-V device would place f64 particle fields next to i32 ones of odd length in one
    tree (taichi-dev/taichi#8803): refused with its cause and the fix, before a step runs."""
    from taichi_sph.errors import SPHError

    reset()
    init_taichi(DEVICE, "f64")
    cfg = scene(2, "wcsph", "lists", "precision=f64")
    with pytest.raises(SPHError, match="precision: f64 on .*8803.*precision: f32"):
        make_solver(cfg, build_particles(cfg))


# ----------------------------------------------------------------------------- the PPE's stopping flag
def test_ppe_stopping_flag_on_the_device():
    """On the system of a real step, for each PPE solver from p = 0: the device-side test stops the solve below
    the tolerance (jacobi: or at max_iterations); iterations launched after it said done change nothing (p bit
    for bit, the count); and check_every, how many launches go between two read-backs, does not matter."""
    runtime(DEVICE)
    cfg = scene(2, "isph", "lists", "isph.ppe.solver=mgcg")
    solver = make_solver(cfg, build_particles(cfg))
    solver.prepare()
    solver.step()
    ppe = solver.ppe
    iterate = {"mgcg": ppe.mgcg_iteration, "cg": ppe.cg_iteration, "jacobi": ppe.jacobi_iteration}
    for name in ("mgcg", "cg", "jacobi"):
        ppe.solver = name
        ppe.max_iterations = 400 if name == "jacobi" else cfg.isph.ppe.max_iterations
        results = {}
        for check_every in (1, 5):
            ppe.check_every = check_every
            ppe.p.fill(0.0)
            iterations, residual, _ = ppe.solve(solver.p_background)
            progress = ppe.progress.to_numpy()
            assert progress[DONE] == 1.0 and int(progress[ITERATIONS]) == iterations > 0
            assert residual <= ppe.tolerance or iterations == ppe.max_iterations, (name, residual, iterations)
            p = ppe.p.to_numpy()
            for _ in range(3):  # launched after done: empty
                iterate[name](False)
            assert ppe.progress.to_numpy()[ITERATIONS] == iterations
            np.testing.assert_array_equal(ppe.p.to_numpy(), p, err_msg=name)
            results[check_every] = (iterations, p)
        (i1, p1), (i5, p5) = results[1], results[5]
        assert abs(i1 - i5) <= 1, (name, i1, i5)
        assert np.abs(p5 - p1).max() <= 10 * ppe.tolerance * np.abs(p1).max(), name


# ----------------------------------------------------------------------------- checkpoint and resume
@pytest.mark.parametrize("solver", ["wcsph", "isph"])
def test_interrupted_run_resumes_from_its_checkpoint_on_the_device(solver, tmp_path, monkeypatch):
    """A run interrupted (SIGINT) after its checkpoint resumes from it, on the device, to the state of an
    uninterrupted run: WCSPH within f32 drift, ISPH within its device-CPU bound (its atomic sums move where CG
    stops), each output time written once."""
    import taichi_sph.run.simulation as simulation
    from taichi_sph.run.checkpoint import load_resume
    from taichi_sph.run.output import read_timeseries

    t_end = {"wcsph": 0.03, "isph": 0.2}[solver]
    cfg = scene(2, solver, "lists", f"time.t_end={t_end}", f"output.checkpoint_every={t_end / 3}",
                f"output.every={t_end / 6}")
    runtime(DEVICE)  # each run starts in a fresh runtime (Simulation keeps it: same arch and precision)
    ref = simulation.Simulation(cfg, tmp_path / "ref", render=False, quiet=True).run()
    assert ref.exit_code == 0
    progress = simulation.Progress

    class InterruptAt(progress):
        sent = False

        def update(self, t, steps):
            if t >= 0.5 * t_end and not InterruptAt.sent:
                InterruptAt.sent = True
                os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(simulation, "Progress", InterruptAt)
    out = tmp_path / "run"
    runtime(DEVICE)
    first = simulation.Simulation(cfg, out, render=False, quiet=True).run()
    assert first.exit_code == 130 and 0.5 * t_end <= first.summary["t_end"] < t_end
    monkeypatch.setattr(simulation, "Progress", progress)
    runtime(DEVICE)
    resumed = simulation.Simulation(cfg, out, render=False, quiet=True).run(resume=load_resume(out))
    assert resumed.exit_code == 0 and resumed.summary["resumed_at"] and resumed.summary["arch"] == DEVICE
    assert abs(resumed.summary["steps"] - ref.summary["steps"]) <= (0 if solver == "wcsph" else 1)
    t = read_timeseries(out / "timeseries.csv")["t"]
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(t_end)
    a, b = by_id(ref.final_state), by_id(resumed.final_state)
    scale = {"x": cfg.particles.dx, "v": np.abs(a["v"]).max(), "p": np.abs(a["p"]).max()}
    d = {key: float(np.abs(b[key] - a[key]).max() / s) for key, s in scale.items()}
    print(f"{solver} resumed - uninterrupted: " + ", ".join(f"{k} {v:.2g}" for k, v in d.items()))
    for key, v in d.items():
        assert v <= TOLERANCE[solver][key], (key, d)
