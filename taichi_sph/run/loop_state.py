"""The time loop's bookkeeping (`LoopState`: next output times, step times, running maxima), saved in every
checkpoint beside the solver state, and what a run hands back (`RunResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class LoopState:
    """The run loop's bookkeeping, saved in every checkpoint beside the solver state."""

    next_out: float = 0.0
    next_frame: float = 0.0
    next_snap: float | None = None
    next_checkpoint: float | None = None
    dt: float = 0.0                       # the last step's dt (the timeseries' `dt` column)
    dts: list = field(default_factory=list)
    step_times: list = field(default_factory=list)
    max_rho_err: float = 0.0
    peak_speed: float = 0.0               # the fluid's largest speed at the guard checks (guards.sound_speed_note)
    max_wall_crossings: int = 0           # fluid particles outside their wall box, most at one output time
    max_outside: int = 0                  # fluid particles outside the domain, most at one guard check
    outside_note: str = ""                # where the first one left (guards.left_domain_detail)
    frames: int = 0                       # frames written
    render_s: float = 0.0
    wall_s: float = 0.0                   # stepping wall time of the segments before a resume
    compile_s: float = 0.0
    snapshot_steps: list = field(default_factory=list)   # steps of the periodic snapshots written
    timeseries_bytes: int = 0             # timeseries.csv size at the checkpoint
    last_checkpoint_t: float | None = None
    resumed_at: list = field(default_factory=list)
    observed_step: int = -1               # the step whose outputs were written last
    energy_start: float | None = None     # energy above the rest state at the first output row (energy_watch.py)
    energy_peak: float | None = None
    energy_last: float | None = None
    wall_work_peak: float = 0.0           # the largest |W| of oscillating walls at an output row (energy_watch.py)


@dataclass
class RunResult:
    summary: dict
    exit_code: int
    out_dir: Path | None
    final_state: dict = field(default_factory=dict)
