"""Peak RSS of short runs against the pre-flight estimate (taichi_sph/memory.py).

    .venv/bin/python scripts/measure_memory.py [CONFIG:DX ...]

Each case runs `taichi-sph run CONFIG --set particles.dx=DX --t-end T --no-render --quiet --force` in a
child process (a few steps, one output row, the final snapshot) and reads its peak resident set size
from wait4(); prints a Markdown table: particles, estimate, measured, estimate / measured.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

from taichi_sph.config.loader import load_config
from taichi_sph.run.memory import GIB, estimate

CASES = ["configs/dam_break_2d.yaml:0.025", "configs/dam_break_2d.yaml:0.0125", "configs/dam_break_2d.yaml:0.005",
         "configs/dam_break_3d.yaml:0.04", "configs/dam_break_3d.yaml:0.02", "configs/dam_break_3d.yaml:0.0125"]


def peak_rss(argv: list[str], cache: str) -> float:
    """Peak RSS of a child process [bytes], compiling its kernels into an empty cache (a first run)."""
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache)
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {proc.stderr.read().decode()[-500:]}")
    return usage.ru_maxrss * 1024.0


def main(cases: list[str]) -> None:
    print("| config | dx | particles | estimate GiB | measured peak GiB | estimate / measured |")
    print("|---|---|---|---|---|---|")
    for case in cases:
        path, dx = case.rsplit(":", 1)
        cfg = load_config(path, [f"particles.dx={dx}"])
        est = estimate(cfg, render=False, device=False)
        with tempfile.TemporaryDirectory() as out:
            argv = [sys.executable, "-m", "taichi_sph", "run", path, "--set", f"particles.dx={dx}",
                    "--t-end", "0.0004", "--no-render", "--quiet", "--force", "--out", out]
            measured = peak_rss(argv, os.path.join(out, "ticache"))
        print(f"| {cfg.name} | {dx} | {est.n} | {est.host_total / GIB:.3f} | {measured / GIB:.3f} | "
              f"{est.host_total / measured:.2f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or CASES)
