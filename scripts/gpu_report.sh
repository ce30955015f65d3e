#!/usr/bin/env bash
# The GPU check in one run: speed report, CUDA wall crossings, the test suite on CUDA.
#
# Where the GPU machine has no package registry (this project's offline H200), stage taichi first,
# here, from the project root:
#     bash ../shared/gpu/stage.sh              # puts .whl/ .gl/ .devenv.sh in the checkout (git-ignored)
# then on the GPU machine, from the project root (carry .whl, .gl and .devenv.sh with the tree):
#     source .devenv.sh && bash scripts/gpu_report.sh [OUT_DIR]
# On a machine with a registry: `bash scripts/setup.sh && . .venv/bin/activate && bash scripts/gpu_report.sh`.
#
# Parts (each with its own time limit, so a slow part cannot eat the others' time):
#   1. taichi-sph bench --report --arch cuda          (< 8 min: throughput 2D/3D x WCSPH/ISPH x 100k/1M/4M,
#                                                       real-time factor of every bundled scene)
#   2. dam_break_2d and dam_break_3d, WCSPH on CUDA    (wall crossings in summary.json: want 0)
#   3. TAICHI_SPH_TEST_ARCH=cuda pytest                (the suite with every CPU request served by CUDA)
# PARTS=1,2 (say) runs a subset; REPORT_ARGS adds bench options (e.g. "--particles 100000,1000000").
set -uo pipefail
cd "$(dirname "$0")/.."
out=${1:-${OUT:-gpu-report}}
parts=${PARTS:-1,2,3}
mkdir -p "$out"
py=${PYTHON:-python3}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null | tee "$out/gpu.txt"

if [[ ",$parts," == *",1,"* ]]; then
  echo "== 1. bench --report (cuda)"
  timeout 540 $py -m taichi_sph bench --report --arch cuda ${REPORT_ARGS:-} --json "$out/report.json" 2>&1 | tee "$out/report.txt"
fi

if [[ ",$parts," == *",2,"* ]]; then
  echo "== 2. dam breaks on CUDA: wall crossings"
  for scene in dam_break_2d dam_break_3d; do
    timeout 300 $py -m taichi_sph run "configs/$scene.yaml" --arch cuda --no-render --quiet --overwrite \
      --out "$out/$scene-wcsph" > "$out/$scene.log" 2>&1
    $py - "$out/$scene-wcsph/summary.json" <<'PY'
import json, sys
try:
    s = json.load(open(sys.argv[1]))
except OSError:
    sys.exit(print(f"{sys.argv[1]}: no summary (see the .log beside it)"))
c = s["conservation"]["wall_crossings"]
print(f"{s['scene']} {s['solver']} on {s['arch']}: status {s['status']}, {s['steps']} steps, wall {s['wall_time_s']:.1f} s "
      f"(RTF {s['t_end'] / max(s['wall_time_s'], 1e-9):.3g}), wall crossings {c}, errors {s['errors']}")
PY
  done
fi

if [[ ",$parts," == *",3,"* ]]; then
  echo "== 3. the test suite on CUDA"
  TAICHI_SPH_TEST_ARCH=cuda timeout 600 $py -m pytest -q -x -p no:cacheprovider 2>&1 | tail -25 | tee "$out/pytest.txt"
fi
