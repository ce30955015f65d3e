"""--realtime on this machine: measure one solver once, cache it, choose the spacing (run/realtime.py's model).

Taichi compiles every kernel again for each particle count (field shapes), 15-40 s on a 2-core CPU, so a
scene is measured at one spacing only, the coarsest allowed: a compile, the loop-schedule probes, then
about a second of timed steps (s per step, of it in the PPE, PPE iterations). The sample is cached in
~/.cache/taichi_sph/realtime.json (or $TAICHI_SPH_CACHE) under the machine (host, CPU model, cores), the arch,
the scene (its config without dx, time and outputs) and the solver; a later run reuses it without
measuring. The live window corrects it: its own steps at the chosen dx replace the sample at that particle
count, and the drawing time of its frames is kept for the next choice's stepping share. When the
measured spacing is the chosen one, the measured solver is rewound (run/rewind.py) and used: no second compile.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from taichi_sph.config.loader import to_dict
from taichi_sph.config.schema import Config
from taichi_sph.run.realtime import (
    Candidate,
    Pick,
    Sample,
    at_dx,
    candidate_spacings,
    describe,
    pick_dx,
    pick_solver,
    ppe_exponent,
    stepping_share,
    steps_per_simulated_second,
)

CACHE_ENV = "TAICHI_SPH_CACHE"
FIRST_DRAW_S = 0.015  # a frame's drawing time until the live window has measured one on this machine [s]
MAX_SAMPLES = 4
MAX_CHECKS = 2  # measurements of a pick no sample confirms, per solver and launch (each compiles its particle count)


def cache_path() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "taichi_sph") / "realtime.json"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def device_label(arch: str) -> str:
    """'cpu x2' (cores) or the arch's name."""
    return f"cpu x{os.cpu_count()}" if arch == "cpu" else arch


def cache_key(cfg: Config, solver: str) -> str:
    """Machine, arch, scene (its config without dx, time, outputs, rendering, and the domain, which `at_dx` grows
    with the walls at a coarse dx) and solver."""
    scene = to_dict(cfg)
    for k in ("name", "description", "time", "output", "render", "probes", "metrics", "realtime", "solver", "arch",
              "domain"):
        scene.pop(k, None)
    scene["particles"].pop("dx", None)
    digest = hashlib.sha1(json.dumps(scene, sort_keys=True, default=str).encode()).hexdigest()[:12]
    return "|".join((platform.node(), _cpu_model(), str(os.cpu_count()), cfg.arch, cfg.name, digest, solver))


def load_entry(cfg: Config, solver: str) -> dict:
    """{'samples': [Sample, ...], 'draw_s': float | None (at cfg's window size)} for this machine, scene, solver."""
    try:
        raw = json.loads(cache_path().read_text()).get(cache_key(cfg, solver), {})
    except (OSError, ValueError):
        raw = {}
    return {"samples": [Sample(**s) for s in raw.get("samples", [])], "draw_s": raw.get(_draw_key(cfg))}


def _draw_key(cfg: Config) -> str:
    return f"draw_s_{cfg.render.width}x{cfg.render.height}"  # a frame's drawing time depends on the window


def store(cfg: Config, solver: str, sample: Sample | None = None, draw_s: float | None = None) -> None:
    """Keep `sample` (replacing one at the same particle count) and/or a frame's drawing time."""
    path = cache_path()
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        data = {}
    key = cache_key(cfg, solver)
    entry = data.setdefault(key, {})
    if sample is not None:
        kept = [s for s in entry.get("samples", []) if s["n"] != sample.n]
        entry["samples"] = (kept + [asdict(sample)])[-MAX_SAMPLES:]
    if draw_s is not None:
        entry[_draw_key(cfg)] = draw_s
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(data, indent=1))
        tmp.replace(path)
    except OSError:
        pass  # a cache that cannot be written only costs a measurement next time


def candidates(cfg: Config, solver: str) -> list[Candidate]:
    """Every candidate spacing with its exact particle counts and a-priori steps per simulated second."""
    from taichi_sph.scene.bodies import build_particles

    out = []
    for dx in candidate_spacings(cfg):
        c = at_dx(cfg, dx, solver)
        arrays = build_particles(c)
        out.append(Candidate(dx, arrays.n_fluid, arrays.n_wall, steps_per_simulated_second(c),
                             ppe_exponent(c, arrays.n_fluid)))
    return out


def measure(cfg: Config, min_wall_s: float = 1.0, max_steps: int = 400):
    """Compile, decide the loop schedule, then time steps for about `min_wall_s`: (Sample, solver, memento),
    the solver rewound to its prepared initial state."""
    from taichi_sph.run.rewind import SolverMemento
    from taichi_sph.run.runtime import init_taichi
    from taichi_sph.scene.bodies import build_particles
    from taichi_sph.solvers.registry import make_solver

    init_taichi(cfg.arch, cfg.precision)
    solver = make_solver(cfg, build_particles(cfg))
    solver.prepare()
    memento = SolverMemento(solver)
    t_end = cfg.time.t_end
    schedule = getattr(solver, "schedule", None)
    for _ in range(40):  # compile, then the CPU loop-schedule probes
        solver.advance(1, math.inf, t_end)
        if solver.step_count >= 2 and not (schedule is not None and schedule.deciding):
            break
    ppe0, it0, steps0 = getattr(solver, "ppe_seconds", 0.0), len(getattr(solver, "iterations", [])), solver.step_count
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < min_wall_s and solver.step_count - steps0 < max_steps and solver.t < t_end:
        solver.advance(16, math.inf, t_end)  # batches as the live window and `run` launch them
    wall, steps = time.perf_counter() - t0, max(solver.step_count - steps0, 1)
    its = getattr(solver, "iterations", [])[it0:]
    sample = Sample(solver.n, cfg.particles.dx, wall / steps, (getattr(solver, "ppe_seconds", 0.0) - ppe0) / steps,
                    float(sum(its)) / len(its) if its else 0.0)
    memento.restore()
    return sample, solver, memento


@dataclass
class Choice:
    """What --realtime chose: the pick, the config at its dx and solver, the line to print, the measured
    solver when it is the chosen one (solver, memento), and the sample the prediction rests on."""

    pick: Pick
    cfg: Config
    line: str
    share: float
    prepared: tuple | None
    measured: bool


def choose(cfg: Config, solvers: list[str], *, view: bool, log=print) -> Choice:
    """Measure (or read the cache), predict every candidate, pick dx per solver and the solver. A pick at a
    particle count no sample has is measured before it is trusted (the window compiles it anyway: the measured
    solver is the one it runs); if the prediction was wrong, the pick moves, up to MAX_CHECKS measurements, and
    a pick still unmeasured after them gives way to a measured one that reaches real time (`confirmed_pick`)."""
    picks, shares, measured = [], {}, set()
    last = None  # (solver, dx, the measured solver, its memento) of the latest measurement: each resets Taichi
    for solver in solvers:
        entry = load_entry(cfg, solver)
        cands = candidates(cfg, solver)
        samples = list(entry["samples"])
        shares[solver] = stepping_share(entry["draw_s"] or FIRST_DRAW_S) if view else 1.0
        if not samples:
            log(f"realtime: measuring {solver} at dx {cands[0].dx:g} ({cands[0].n} particles; compiling first) ...")
            samples, last = _measure_into(cfg, solver, cands[0], samples, log)
            measured.add(solver)
        pick = pick_dx(solver, samples, cands, cfg.realtime.margin, shares[solver])
        for _ in range(MAX_CHECKS):
            if any(s.n == pick.cand.n for s in samples):
                break
            log(f"realtime: checking {solver} at dx {pick.cand.dx:g} ({pick.cand.n} particles, predicted RTF "
                f"{pick.rtf:.2g}) ...")
            samples, last = _measure_into(cfg, solver, pick.cand, samples, log)
            measured.add(solver)
            pick = pick_dx(solver, samples, cands, cfg.realtime.margin, shares[solver])
        picks.append(confirmed_pick(pick, samples, cands, cfg.realtime.margin, shares[solver]))
    best = pick_solver(picks) if len(picks) > 1 else picks[0]
    prepared = None
    if last is not None and last[:2] == (best.solver, best.cand.dx):
        prepared = last[2:]
    line = describe(best, device_label(cfg.arch), shares[best.solver])
    return Choice(best, at_dx(cfg, best.cand.dx, best.solver), line, shares[best.solver], prepared,
                  best.solver in measured)


def confirmed_pick(pick: Pick, samples: list[Sample], cands: list[Candidate], margin: float, share: float) -> Pick:
    """`pick` if a sample stands at its particle count; else (the checks ran out on predictions that moved) the
    finest measured candidate that reaches `margin`, so that the run starts on a measured count, which the last
    check may have left compiled; none measured reaches it: `pick` (the model's best guess)."""
    counts = {s.n for s in samples}
    if pick.cand.n in counts:
        return pick
    measured = [c for c in cands if c.n in counts]
    fallback = pick_dx(pick.solver, samples, measured, margin, share) if measured else None
    return fallback if fallback is not None and fallback.reaches else pick


def _measure_into(cfg: Config, solver: str, cand: Candidate, samples: list[Sample], log) -> tuple[list[Sample], tuple]:
    """Measure `solver` at `cand` and cache the sample: `samples` with it (replacing one at its count), and
    (solver, dx, the measured solver, its memento)."""
    sample, obj, memento = measure(at_dx(cfg, cand.dx, solver))
    store(cfg, solver, sample)
    log(f"realtime: {solver}: {1e3 * sample.step_s:.2f} ms a step at {sample.n} particles, "
        f"{sample.particle_steps_per_s / 1e6:.3g} M particle-steps/s"
        + (f", {sample.iterations:.1f} PPE iterations a step" if sample.iterations else ""))
    return [s for s in samples if s.n != sample.n] + [sample], (solver, cand.dx, obj, memento)
