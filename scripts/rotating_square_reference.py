"""Build taichi_sph/data/reference/rotating_square_converged.csv from fine runs of configs/rotating_square_2d.yaml.

    python scripts/rotating_square_reference.py RUN_DIR [RUN_DIR ...] > taichi_sph/data/reference/rotating_square_converged.csv

Each RUN_DIR is a finished run of the scene (its timeseries.csv has the rotating_square metric's columns); the
table is their mean, interpolated onto omega t = 0, 0.02, ..., the shortest run's end. The header lines
(source, runs, spread between the runs) are written from the runs themselves; the bundled table's lines on
convergence and on the early-time curvature were added by hand. Bundled: the scene's settings at dx = 0.005 (WCSPH,
time.cfl=0.25, alpha 0.02, A = 4) and dx = 0.01 (ISPH, shifting A = 4, blend 0.3: the settings before the scene's
ISPH got A = 8 / blend 0.1, which goes unstable at dx 0.01).
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import yaml

COLUMNS = {"I_ratio": "square_I_ratio", "Q_ratio": "square_Q_ratio", "angle_lag_rad": "square_angle_lag_rad",
           "p_centre_star": "square_p_centre_star"}


def load(run: Path) -> tuple[dict, dict[str, np.ndarray]]:
    summary = json.loads((run / "summary.json").read_text())
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    summary["config_dx"] = cfg["particles"]["dx"]
    summary["config_cfl"] = cfg["time"]["cfl"]
    with open(run / "timeseries.csv") as fh:
        rows = list(csv.DictReader(fh))
    cols = {k: np.array([float(r[k]) for r in rows]) for k in ["t", *COLUMNS.values()]}
    return summary, cols


def main(argv: list[str]) -> None:
    runs = [load(Path(a)) for a in argv]
    omega = 1.0  # the scene's angular_velocity
    wt_end = min(c["t"][-1] for _, c in runs) * omega
    wt = np.round(np.arange(0.0, wt_end + 1e-9, 0.02), 10)
    table = {name: np.array([np.interp(wt, c["t"] * omega, c[col]) for _, c in runs]) for name, col in COLUMNS.items()}
    print("# Rotating square patch (Colagrossi 2005, 'A meshless Lagrangian method for free-surface and interface flows with")
    print("# fragmentation', PhD thesis, Univ. Rome La Sapienza; Le Touze, Colagrossi, Colicchio & Greco 2013, Int. J. Numer.")
    print("# Meth. Fluids 73, 660-691): square side L, u = omega (y, -x), p(t=0) Colagrossi's series, free surface, no gravity.")
    print("# NOT a published table: a converged run of ours (taichi-sph), the mean of the runs below, interpolated linearly")
    print("# onto omega t. Columns: I_ratio = <r^2>/<r^2>_0, Q_ratio = <r^4>/<r^4>_0 about the centroid, angle_lag_rad =")
    print("# orientation of the 4-fold moment <(x+iy)^4> behind the rigid rotation, p_centre_star = mean p within 0.05 L of")
    print("# the centroid / (rho0 omega^2 L^2) (series at t = 0: -0.14734). Runs (scripts/rotating_square_reference.py):")
    for s, _ in runs:
        print(f"#   {s['solver']} dx = {s['config_dx']} m (cfl {s['config_cfl']}): n_fluid {s['n_fluid']}, steps {s['steps']}, "
              f"min pair {s['particle_order']['min_pair_distance_dx']:.2f} dx, voids {s['particle_order']['max_void_particles']}")
    for name, values in table.items():
        spread = np.abs(values.max(axis=0) - values.min(axis=0))
        scale = np.abs(values.mean(axis=0))
        if name in ("I_ratio", "Q_ratio"):
            print(f"#   spread between the runs of {name}: max {np.max(spread / scale):.4f} relative")
    print("omega_t," + ",".join(COLUMNS))
    for i, w in enumerate(wt):
        print(f"{w:g}," + ",".join(f"{table[name][:, i].mean():.6f}" for name in COLUMNS))


if __name__ == "__main__":
    main(sys.argv[1:])
