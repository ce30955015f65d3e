"""Pieces of a run's summary.json computed from the loop's record: the step timing (compile time, stepping
time, steps), the dt range, and the conservation block of the final state."""

from __future__ import annotations

import numpy as np

from taichi_sph.run.loop_state import LoopState
from taichi_sph.scene.bodies import FLUID
from taichi_sph.validation import diagnostics as diag


def step_timing(loop: LoopState, segment_step_times: list[float]) -> tuple[float, float, int]:
    """(compile_s, stepping_s, nsteps): set-up plus the first step beyond a typical one (this segment's
    median) is compile time; the stepping time and step count leave every segment's first step out
    (`loop.step_times` already holds this segment's)."""
    step_times = segment_step_times
    typical = float(np.median(step_times[1:])) if len(step_times) > 2 else 0.0
    compile_s = loop.compile_s + (step_times[0] - typical if step_times else 0.0)
    stepping_s = max(sum(loop.step_times[1:]) if len(loop.step_times) > 1 else sum(loop.step_times), 1e-12)
    nsteps = max(len(loop.step_times) - 1, 1)
    return compile_s, stepping_s, nsteps


def dt_range(dts: list) -> dict:
    return {"dt_min": float(min(dts)) if dts else None, "dt_mean": float(np.mean(dts)) if dts else None,
            "dt_max": float(max(dts)) if dts else None}


def conservation(final: dict, crossings: int, crossings_max: int) -> dict:
    """Fluid mass, momentum and kinetic energy at the end; fluid particles outside their wall box."""
    f = final["kind"] == FLUID
    return {
        "fluid_mass": float(final["mass"][f].sum()),
        "momentum": diag.total_momentum(final["v"][f], final["mass"][f]).tolist(),
        "kinetic_energy": diag.kinetic_energy(final["v"][f], final["mass"][f]),
        "wall_crossings": crossings,
        "wall_crossings_max": crossings_max,  # at any output time
    }
