"""stability.md: the battery's table of verdicts (with the evidence of refused cases run anyway), the case
notes, and the stability map's table."""

from __future__ import annotations

from taichi_sph.config.docs import table_cell
from taichi_sph.studies.stability_verdicts import ENERGY_GROWTH_LIMIT
from taichi_sph.studies.table import format_value

COLUMNS = (("case", "case"), ("solver", "solver"), ("verdict", "verdict"), ("criterion / reason", None),
           ("max density error", "max_density_error"), ("energy drift", "energy_drift"),
           ("energy growth", "energy_growth"), ("min spacing / dx", "min_spacing_dx"), ("steps", "steps"),
           ("wall time [s]", "wall_time_s"), ("as expected", "as_expected"))


def _why(row: dict) -> str:
    parts = []
    if row.get("criterion"):
        parts.append(str(row["criterion"]))
    if row.get("reason"):
        parts.append(str(row["reason"]))
    text = ": ".join(parts)
    anyway = row.get("if_run_anyway")
    if anyway:
        text += f" [run anyway: {anyway['verdict']}" + (f", {anyway['criterion']}" if anyway.get("criterion") else "") + \
                (f", max density error {format_value(anyway.get('max_density_error'))}" if anyway.get("max_density_error") is not None else "") + "]"
    return table_cell(text)


def stability_markdown(result: dict) -> str:
    lines = ["# Stability battery", "",
             f"Runtime {result['runtime_s']:.0f} s. Verdicts: stable / unstable (guard or garbage criterion) / "
             "refused (severe a-priori check; the case is still run once, unchecked, to show why).", ""]
    lines += ["| " + " | ".join(c[0] for c in COLUMNS) + " |", "|---" * len(COLUMNS) + "|"]
    for row in result["cases"]:
        cells = []
        for _, key in COLUMNS:
            if key is None:
                cells.append(_why(row))
            elif key == "as_expected":
                v = row.get(key)
                cells.append("-" if v is None else ("yes" if v else f"**no** (expected {row['expected']})"))
            else:
                cells.append(format_value(row.get(key)))
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Cases:", ""]
    seen = set()
    for row in result["cases"]:
        if row["case"] not in seen:
            seen.add(row["case"])
            lines.append(f"- `{row['case']}`: {row.get('note', '')}")
    lines += ["", "Energy drift: (E_end - E_0) / E_0 of kinetic + potential energy over the snapshots (impacts and "
              "viscosity dissipate, so negative drift is physical); growth above "
              f"{ENERGY_GROWTH_LIMIT:.0%} marks a run unstable. Min spacing / dx: the closest pair of fluid particles "
              "at the end (pairing / clumping shows as values well below 1)."]
    m = result.get("map")
    if m:
        lines += ["", f"## Stability map ({m['scene']}, WCSPH)", "", f"![stability map]({m['plot']})", ""]
        lines += ["| c0 / U \\ CFL | " + " | ".join(f"{c:g}" for c in m["cfl"]) + " |", "|---" * (len(m["cfl"]) + 1) + "|"]
        for ratio in m["c0_ratio"]:
            cells = []
            for cfl in m["cfl"]:
                cell = next((c for c in m["cells"] if c["cfl"] == cfl and c["c0_ratio"] == ratio), None)
                if cell is None:
                    cells.append("-")
                    continue
                if cell["verdict"] == "stable":
                    text = f"stable ({format_value(cell.get('max_density_error'))})"
                else:
                    text = f"**{cell['criterion'] or cell['verdict']}** at t = {format_value(cell.get('t_reached'))} s"
                cells.append(text + (" [refused]" if cell["flagged"] else ""))
            lines.append(f"| {ratio:g} | " + " | ".join(cells) + " |")
        lines += ["", "Cells: stable (max density error), or the criterion that fired and when; [refused]: a severe "
                  "a-priori check would refuse this configuration in the battery (the map runs it anyway)."]
    return "\n".join(lines) + "\n"
