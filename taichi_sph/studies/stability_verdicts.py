"""The verdict of one stability run, from its summary and energy measurements:

- `refused`  an a-priori check is severe (checks.py): the run is pointless; the reason is the check's message.
             The battery still runs it once, unchecked, and reports what happened (`if run anyway`),
             so every refusal is backed by evidence.
- `unstable` a guard fired during the run (non-finite state, particles leaving the domain, neighbour
             overflow, density error beyond the guard), or the run "finished" with garbage: density
             error beyond the guard at an output time, energy above rest grown by more than
             ENERGY_GROWTH_LIMIT, fluid through the walls, or fluid particles collapsed onto each
             other (closer than CLUMPING_LIMIT x dx: the tensile instability's pairs).
- `stable`   none of that.
- `failed`   the solver raised (a bug; traceback in the run folder's error.txt).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from taichi_sph.studies.table import is_number

ENERGY_GROWTH_LIMIT = 0.5      # E_max > 1.5 E_0 without an energy source: garbage
WALL_PENETRATION_LIMIT = 0.01  # fraction of fluid particles found outside their wall box
CLUMPING_LIMIT = 0.05          # two fluid particles closer than 5% of dx: collapsed (tensile instability, pairing)


@dataclass
class Verdict:
    verdict: str                 # stable | unstable | refused | failed | interrupted
    criterion: str | None = None
    reason: str = ""


def classify(summary: dict | None, *, severe: list | tuple = (), guard: float = 0.2,
             measurements: dict | None = None) -> Verdict:
    """Turn a run's summary (and its energy measurements) into a verdict; `severe` holds the severe
    a-priori checks (CheckResult or str), which refuse the case before anything ran."""
    if severe:
        codes = ",".join(getattr(c, "code", "check") for c in severe)
        return Verdict("refused", codes, "; ".join(getattr(c, "message", str(c)) for c in severe))
    if summary is None:
        return Verdict("failed", None, "no summary")
    status = summary.get("status")
    if status == "failed":
        return Verdict("failed", None, summary.get("error", ""))
    if status == "interrupted":
        return Verdict("interrupted", None, "interrupted by the user")
    if status == "unstable":
        inst = summary.get("instability", {})
        t = inst.get("t")
        return Verdict("unstable", inst.get("criterion"),
                       f"{inst.get('detail', '')}" + (f" at t = {t:.4g} s" if is_number(t) else ""))
    m = measurements or {}
    rho_err = summary.get("max_density_error")
    ke = summary.get("conservation", {}).get("kinetic_energy", 0.0)
    if not is_number(rho_err) or (ke is not None and not is_number(ke)):
        return Verdict("unstable", "non_finite", "the run finished with non-finite density or energy")
    if rho_err > guard:
        return Verdict("unstable", "density_error", f"finished, but max |rho - rho0|/rho0 = {rho_err:.3g} > guard {guard:g}")
    growth = m.get("energy_growth")
    if growth == math.inf:
        return Verdict("unstable", "non_finite", "non-finite energy in a snapshot")
    if is_number(growth) and growth > ENERGY_GROWTH_LIMIT:
        return Verdict("unstable", "energy_growth",
                       f"finished, but its energy above rest grew by {growth:.0%} (> {ENERGY_GROWTH_LIMIT:.0%})")
    crossings = summary.get("conservation", {}).get("wall_crossings") or 0
    n_fluid = summary.get("n_fluid") or 0
    if n_fluid and crossings > max(1, WALL_PENETRATION_LIMIT * n_fluid):
        return Verdict("unstable", "wall_penetration", f"finished, but {crossings} of {n_fluid} fluid particles crossed a wall")
    spacing = m.get("min_spacing_dx")
    if is_number(spacing) and spacing < CLUMPING_LIMIT:
        return Verdict("unstable", "particle_clumping",
                       f"finished, but two fluid particles are {spacing:.2g} dx apart (< {CLUMPING_LIMIT:g} dx): collapsed pairs")
    return Verdict("stable", None, "")


def as_expected(verdict: str, expected: str) -> bool | None:
    """Did the case come out as a sound solver should? None when there is no expectation."""
    if verdict == "failed":
        return False
    if verdict == "interrupted" or expected == "either":
        return None
    if expected == "unstable":
        return verdict in ("unstable", "refused")
    return verdict == expected
