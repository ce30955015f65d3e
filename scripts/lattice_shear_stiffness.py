"""The shear stiffness of a square/cubic lattice's kernel sum against h / dx (scene/lattice.py
lattice_shear_stiffness), the table behind docs/wcsph.md "The period bias measured against the lattice's shear
stiffness". WCSPH's standing-wave period error at dx 0.025 follows about -36% x the mean of the two columns.

    .venv/bin/python scripts/lattice_shear_stiffness.py --kernel wendland_c2 --dim 2 --hdx 1.6:2.6:0.05
"""

from __future__ import annotations

import argparse

import numpy as np

from taichi_sph.scene.lattice import lattice_shear_stiffness
from taichi_sph.sph.kernels import KERNEL_NAMES, make_kernel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kernel", default="wendland_c2", choices=KERNEL_NAMES)
    parser.add_argument("--dim", type=int, default=2, choices=(2, 3))
    parser.add_argument("--hdx", default="1.6:2.6:0.05", help="start:stop:step (stop included)")
    args = parser.parse_args()
    start, stop, step = (float(v) for v in args.hdx.split(":"))
    print("| h / dx | axis | diagonal | mean |\n|---|---|---|---|")
    for hdx in np.arange(start, stop + 0.5 * step, step):
        k = make_kernel(args.kernel, args.dim, float(hdx))
        axis, diagonal = lattice_shear_stiffness(k.w_np, args.dim, 1.0, k.support_radius)
        print(f"| {hdx:.2f} | {axis:+.4f} | {diagonal:+.4f} | {(axis + diagonal) / 2:+.4f} |")


if __name__ == "__main__":
    main()
