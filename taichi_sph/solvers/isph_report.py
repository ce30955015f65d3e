"""What an ISPH run reports of its pressure solves: iterations, residuals, the settings they ran with, and a
warning for every step that stopped at `isph.ppe.max_iterations` above the tolerance."""

from __future__ import annotations

import numpy as np


def nonconverged_steps(iterations: list[int], residuals: list[float], max_iterations: int,
                       tolerance: float) -> list[int]:
    """Indices of the steps that stopped at max_iterations above the tolerance."""
    return [i for i, (n, r) in enumerate(zip(iterations, residuals)) if n >= max_iterations and r > tolerance]


def ppe_summary(solver) -> dict:
    """{"ppe": iterations, residuals and settings, "ppe_warnings": [...]} of an ISPHSolver's run so far."""
    ppe, its = solver.ppe, np.asarray(solver.iterations, dtype=float)
    residuals = solver.residuals
    bad = nonconverged_steps(solver.iterations, residuals, ppe.max_iterations, ppe.tolerance)
    summary = {"solver": ppe.solver,
               "iterations_mean": float(its.mean()) if its.size else 0.0,
               "iterations_max": int(its.max()) if its.size else 0,
               "residual_max": float(max(residuals)) if residuals else 0.0,
               "nonconverged_steps": len(bad),
               "tolerance": ppe.tolerance, "max_iterations": ppe.max_iterations,
               "source": solver.source if solver.source != "blend" else f"blend({solver.beta:g})",
               "pure_neumann_steps": solver.pure_neumann_steps,
               "free_surface": ("none: the fluid fills its container at the start (no detection)" if solver.confined
                                else "detected every step"),
               "multigrid_levels": ppe.mg.describe() if ppe.mg else None,
               "loop_schedule": {None: "undecided", True: "serial", False: "parallel"}[ppe.serial],
               "walls": ("unknowns of the PPE (hydrostatic extrapolation rows), the solved pressure >= p_b in the gradient"
                         if solver.extrapolated_walls else
                         "Neumann (pairwise hydrostatic) in the PPE, Adami pressure >= p_b in the gradient"),
               "pressure_gradient": "kernel-gradient-corrected difference form"}
    warnings = []
    if bad:
        worst = max(residuals[i] for i in bad)
        warnings.append(f"PPE ({ppe.solver}) stopped at max_iterations = {ppe.max_iterations} above the "
                        f"tolerance {ppe.tolerance:g} in {len(bad)} of {len(solver.iterations)} steps (first at "
                        f"step {bad[0] + 1}, relative residual up to {worst:.3g})")
    return {"ppe": summary, "ppe_warnings": warnings}
