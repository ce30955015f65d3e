"""Whether a solver's step loops run on one thread (CPU): decided by timing steps."""

import numpy as np
import taichi as ti


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
