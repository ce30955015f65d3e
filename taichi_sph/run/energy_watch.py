"""The energy guard: the fluid's mechanical energy above its rest state (validation/energy.py) at every output
row, its start, peak and last value kept in the loop state, and the growth that ends a run with no energy input
"unstable" (`guards.energy_growth`):
    E(t) - E_rest > (1 + growth) (E(0) - E_rest) + floor,
floor = energy_floor (the body forces' work over 3e-3 dx for WCSPH, or over (dx / H)^2 dx if larger, H the settled
depth; over 1e-3 dx for ISPH; and a millionth of the kinetic energy at the scene's speed). A closed flow only loses
energy to viscosity, diffusion and impacts; a gain is the scheme's. Where walls oscillate as prescribed and the
solver measures their work W (WCSPH: solvers/wall_motion.py), the energy judged is E - E_rest - W.

E - E_rest is taken no smaller than the kinetic energy E_k: the true rest state is the minimum of E_p + E_e, so
E_k <= E - E_rest always. The estimated rest state can sit above that minimum (WCSPH's compressed column sits
lower than the lattice heights it is estimated on): a WCSPH wave with no diffusion turned 30 J of potential
energy into particle noise, E_k grew from 2 to 10 J while E - E_rest_estimate fell to -12 J."""

from __future__ import annotations

import numpy as np

from taichi_sph.config.schema import Config
from taichi_sph.run.loop_state import LoopState
from taichi_sph.scene.bodies import FLUID
from taichi_sph.validation.energy import elastic_energy, energy_floor, energy_input, potential_energy, rest_state

# a start at rest that ends within this many floors of it may be its settling's swing, not a growth: the guard says so
SETTLING_HINT = 3.0
# a gain past this fraction of guards.energy_growth (and the floor) that stays under the guard's bound is warned about:
# a WCSPH dam break onto a wet bed gained 8% and ended "ok" with no word of it (docs/notes/user_scenes.md)
GAIN_WARN = 0.5
# the balance E - E_rest - W of oscillating walls is allowed this fraction of the largest |W| so far on top of the
# floor: the pair sums miss the share of the wall's pressure force the fluid takes from the static wall particles
# under a moving body's edge (a piston's corner with the floor), an O(dx) part of W. A 2 m flume at 10 particles over
# the depth: E - E_rest - W swings +-1.8 J with the piston, 6-10% of |W| (both solvers); WCSPH at 20 (the 6 m flume): 3.6%
WALL_WORK_TOLERANCE = 0.25

ENERGY_COLUMNS = ["potential_energy", "elastic_energy", "energy_above_rest"]


class EnergyWatch:
    """Measures E - E_rest on host states and judges its growth (module docstring)."""

    def __init__(self, cfg: Config, fluid_mass: np.ndarray, released: float = 0.0,
                 wall_work_measured: bool = False) -> None:
        self.cfg = cfg
        self.rest = rest_state(cfg, fluid_mass, released)
        self.floor = energy_floor(cfg, float(np.sum(fluid_mass, dtype=np.float64)), self.rest.depth)
        # oscillating walls whose work W the solver measures (WCSPH's pair forces): the energy judged is E - E_rest - W
        self.wall_work_measured = wall_work_measured and bool(cfg.wall_motions)
        self.input = energy_input(cfg, self.wall_work_measured)

    @property
    def guarded(self) -> bool:
        return self.cfg.guards.energy_growth is not None and self.input is None

    def measure(self, state: dict, loop: LoopState, kinetic: float, wall_work: float | None = None) -> dict:
        """The timeseries columns of this state (`kinetic`: its fluid's E_k); the loop's start/peak/last energies
        updated: E - E_rest, less the moving walls' work W since t = 0 where it is measured (`wall_work`)."""
        f = state["kind"] == FLUID
        m = state["mass"][f]
        potential = potential_energy(self.cfg, state["x"][f], m)
        elastic = elastic_energy(self.cfg, state["rho"][f], m)
        raw = kinetic + potential + elastic - self.rest.potential - self.rest.elastic
        above = max(raw, kinetic)
        judged = above
        if self.wall_work_measured and wall_work is not None:
            # a piston drawn back lets the fluid below the rest state of the container at rest: E - E_rest < E_k is
            # then real, and W holds its counterpart, so the balance takes E - E_rest as it is
            judged = raw - wall_work
            loop.wall_work_peak = max(loop.wall_work_peak, abs(wall_work))
        if loop.energy_start is None:
            loop.energy_start = loop.energy_peak = judged
        if not np.isfinite(judged):
            loop.energy_peak = float("inf")
        else:
            loop.energy_peak = max(loop.energy_peak, judged)
        loop.energy_last = judged
        return {"potential_energy": potential, "elastic_energy": elastic, "energy_above_rest": above}

    def violation(self, loop: LoopState) -> dict | None:
        """{criterion, detail} when the last measured energy grew past the bound; None otherwise or unguarded."""
        if not self.guarded or loop.energy_start is None or loop.energy_last is None:
            return None
        growth = self.cfg.guards.energy_growth
        bound = (1.0 + growth) * max(loop.energy_start, 0.0) + self.floor + self.wall_work_allowance(loop)
        if np.isfinite(loop.energy_last) and loop.energy_last <= bound:
            return None
        what = "energy above rest less the moving walls' work" if self.wall_work_measured else "energy above rest"
        allowance = (f" + {WALL_WORK_TOLERANCE:g} x the walls' largest |work| {loop.wall_work_peak:.4g} J"
                     if self.wall_work_measured else "")
        detail = (f"{what} {loop.energy_last:.4g} J > {bound:.4g} J = (1 + guards.energy_growth "
                  f"{growth:g}) x its start {loop.energy_start:.4g} J + floor {self.floor:.3g} J{allowance}, with no "
                  f"other energy input")
        if loop.energy_start < self.floor and loop.energy_last < SETTLING_HINT * self.floor:
            # a start at rest whose settling swings past the floor (a coarse tank: docs/notes/user_scenes.md)
            detail += (". A fluid that starts at rest swings as its start settles, more at a coarse resolution: if "
                       "this one only swings, refine particles.dx, settle the start (particles.settle, WCSPH) or "
                       "switch the guard off (guards.energy_growth: null)")
        return {"criterion": "energy_growth", "detail": detail}

    def wall_work_allowance(self, loop: LoopState) -> float:
        """WALL_WORK_TOLERANCE x the largest |W| so far where the walls' work is measured (0 otherwise): the
        balance's discretisation error grows with the work done."""
        return WALL_WORK_TOLERANCE * loop.wall_work_peak if self.wall_work_measured else 0.0

    def _growth_start_peak(self, loop: LoopState) -> tuple[float, float, float] | None:
        """(guards.energy_growth, start, peak) of a guarded run with a positive start and a finite peak, for the
        warnings below; None otherwise."""
        start, peak = loop.energy_start, loop.energy_peak
        if not self.guarded or start is None or peak is None or start <= 0.0 or not np.isfinite(peak):
            return None
        return self.cfg.guards.energy_growth, start, peak

    def growth_inside_floor(self, loop: LoopState) -> str | None:
        """A warning when the energy above rest peaked past (1 + guards.energy_growth) x its start but inside the
        floor, so the guard did not end the run: where the scene's own energy is comparable to the floor (a small
        wave: its 2 J against 0.5 J) a gain of tens of percent passes as settling. None otherwise or unguarded."""
        watched = self._growth_start_peak(loop)
        if watched is None:
            return None
        growth, start, peak = watched
        if peak <= (1.0 + growth) * start + self.wall_work_allowance(loop):
            return None
        return (f"energy above rest peaked {peak / start - 1.0:.0%} above its start ({start:.4g} -> {peak:.4g} J), past "
                f"guards.energy_growth {growth:g} but within the floor {self.floor:.3g} J the guard allows for the "
                f"fluid settling, so not called unstable: at this scene's energy the guard cannot tell a gain from a "
                f"change of the fluid's level; see kinetic_energy in timeseries.csv")

    def gain_below_bound(self, loop: LoopState) -> str | None:
        """A warning when the energy above rest peaked past (1 + GAIN_WARN x guards.energy_growth) x its start + the
        floor but stayed under the guard's bound: a closed flow only loses energy, so a gain of that size is the
        scheme's, and the run's "ok" should not pass it in silence. None otherwise, unguarded, or where
        growth_inside_floor speaks."""
        watched = self._growth_start_peak(loop)
        if watched is None:
            return None
        growth, start, peak = watched
        if peak <= (1.0 + GAIN_WARN * growth) * start + self.floor + self.wall_work_allowance(loop):
            return None
        return (f"energy above rest peaked {peak / start - 1.0:.0%} above its start ({start:.4g} -> {peak:.4g} J) with "
                f"no energy input, under the guard's bound (guards.energy_growth {growth:g} and the floor "
                f"{self.floor:.3g} J): a closed flow only loses energy, so this gain is the scheme's; see "
                f"energy_above_rest in timeseries.csv (a finer dx, or for WCSPH a density diffusion, e.g. "
                f"wcsph.density_diffusion.model: fourtakas, may remove it)")

    def summary(self, loop: LoopState) -> dict:
        """summary.json's `energy` block: above rest at the start, the peak and the end, the drift relative to the
        start, and whether the guard watched this run (and why not)."""
        start, peak, last = loop.energy_start, loop.energy_peak, loop.energy_last
        scale = max(abs(start), self.floor) if start is not None else None
        return {
            "above_rest_start": start, "above_rest_peak": peak, "above_rest_end": last,
            "drift": (last - start) / scale if scale else None,
            "growth": (peak - start) / scale if scale else None,
            "rest_potential": self.rest.potential, "rest_elastic": self.rest.elastic, "floor": self.floor,
            **({"less_wall_work": True} if self.wall_work_measured else {}),
            "guard": "on" if self.guarded else
                     f"off: {self.input}" if self.input else "off: guards.energy_growth is null",
        }
