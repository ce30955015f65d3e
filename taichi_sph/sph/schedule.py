"""Whether a solver's step loops run on one thread (CPU): decided by timing steps."""

import contextlib
import os
from collections.abc import Iterator

import numpy as np
import taichi as ti

from taichi_sph.errors import SPHError

SCHEDULE_ENV = "TAICHI_SPH_LOOP_SCHEDULE"  # serial | parallel | auto (the default): fixes the choice


def fixed_schedule() -> bool | None:
    """TAICHI_SPH_LOOP_SCHEDULE: True (serial), False (parallel) or None (auto: decided by timing)."""
    fixed = os.environ.get(SCHEDULE_ENV, "auto").strip().lower()
    if fixed not in ("auto", "serial", "parallel", ""):
        raise SPHError(f"{SCHEDULE_ENV}={fixed!r}: allowed serial, parallel, auto")
    return None if fixed in ("auto", "") else fixed == "serial"


@contextlib.contextmanager
def schedule_unless_fixed(schedule: str | None) -> Iterator[None]:
    """Runs started inside use `schedule` (serial | parallel; None: leave it to timing) unless the environment
    already fixes TAICHI_SPH_LOOP_SCHEDULE (the user's choice wins). A study whose numbers must repeat to the
    digit on a rerun (`validate`) fixes it: the timing that decides otherwise differs from run to run, and the
    two schedules may round a pair term differently (LoopSchedule)."""
    if schedule is None or os.environ.get(SCHEDULE_ENV, "").strip():
        yield
        return
    os.environ[SCHEDULE_ENV] = schedule
    try:
        fixed_schedule()  # refuse a bad value here, not in the run
        yield
    finally:
        os.environ.pop(SCHEDULE_ENV, None)


class LoopSchedule:
    """Whether a solver's step loops run on one thread: decided on the CPU by timing steps.

    Each parallel loop costs a thread-pool round (~70 us on this project's 2-core VM, a few us on an
    idle many-core CPU): on that VM a whole WCSPH step of PySPH's 3.8k-particle dam break ran ~30%
    faster on one thread, dam_break_2d's 16.5k particles at h = 2 dx ~40% slower. The first steps run
    one schedule, then the other, `warmup + probes` steps each (alternating step by step made both
    look alike: each switch costs cache and thread wake-ups), and the faster median of the last
    `probes` wins. The loops write per particle and reduce by max or integer counts, but the two
    schedules are compiled apart and fast-math may round a pair term differently (last f32 digits): a
    run that must repeat bit for bit sets TAICHI_SPH_LOOP_SCHEDULE=serial or parallel (the tests do).
    On a GPU the loops always run in parallel."""

    def __init__(self, probes: int = 6, warmup: int = 3) -> None:
        cpu = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
        self.serial: bool | None = fixed_schedule() if cpu else False
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
