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
# Parts (each with its own time limit, so a slow part cannot eat the others' time; LIMIT_<part>=seconds changes it):
#   0. view --realtime --offscreen on CUDA              (issue 25: the spacing chosen for this machine, the RTF and
#                                                       frames per wall second reached; dam_break_2d WCSPH and ISPH,
#                                                       dam_break_3d; GGUI through the GPU's Vulkan driver, no display)
#   1. taichi-sph bench --report --arch "$arch"          (< 8 min: throughput 2D/3D x WCSPH/ISPH x 100k/1M/4M,
#                                                       real-time factor of every bundled scene)
#   2. dam_break_2d and dam_break_3d, WCSPH on CUDA    (wall crossings in summary.json: want 0)
#   3. TAICHI_SPH_TEST_ARCH=cuda pytest                (the suite with every CPU request served by CUDA)
#   4. TAICHI_SPH_TEST_ARCH=cuda pytest -m vulkan      (the device set, tests/test_vulkan.py: every arch branch,
#                                                       both solvers, 2D/3D, against the CPU; < 10 min)
#   5. TAICHI_SPH_TEST_ARCH=vulkan pytest -m vulkan    (the same on the GPU's own Vulkan driver: the backend
#                                                       AMD, Intel and Apple GPUs get; docs/gpu.md)
# PARTS=1,2 (say) runs a subset; REPORT_ARGS adds bench options (e.g. "--particles 100000,1000000", or
# "--parts scenes" for the bundled scenes' real-time factors alone: ISPH's cases compile ~1 min each on CUDA, so
# the whole report does not fit a 15-minute device lease; the JSON keeps every case finished before a limit).
# Every part's output goes to OUT_DIR (default gpu-report/); send that folder back.
set -uo pipefail
cd "$(dirname "$0")/.."
out=${1:-${OUT:-gpu-report}}
mkdir -p "$out"
py=${PYTHON:-python3}
parts=${PARTS:-0,1,2,3,4,5}
arch=${ARCH:-cuda}  # ARCH=cpu tries the script on a machine without a GPU
{
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null || echo "nvidia-smi: not found"
  nvidia-smi 2>/dev/null
  $py -c "import taichi, sys; print('taichi', '.'.join(map(str, taichi.__version__)), 'python', sys.version.split()[0])" 2>&1 | grep -v '^\[Taichi\]'
  $py -c "import taichi as ti; ti.init(arch=ti.cuda, log_level=ti.ERROR); print('taichi arch:', ti.lang.impl.current_cfg().arch.name)" 2>&1 | tail -1
  $py -c "import taichi as ti; ti.init(arch=ti.vulkan, log_level=ti.ERROR); print('taichi arch:', ti.lang.impl.current_cfg().arch.name)" 2>&1 | tail -1
  nproc; free -g | head -2
} | tee "$out/gpu.txt"

if [[ ",$parts," == *",0,"* ]]; then
  echo "== 0. view --realtime --offscreen (cuda): dam_break_2d WCSPH, ISPH; dam_break_3d" | tee "$out/realtime.txt"
  export TAICHI_SPH_CACHE=${TAICHI_SPH_CACHE:-/tmp/taichi_sph_cache}
  for case in "dam_break_2d wcsph" "dam_break_2d isph" "dam_break_3d"; do
    set -- $case
    echo "-- $case" | tee -a "$out/realtime.txt"
    frames=$(( ${REALTIME_T:-2} * 30 + 8 ))
    timeout "${LIMIT_0:-120}" $py -m taichi_sph view "configs/$1.yaml" ${2:+--solver $2} --realtime --offscreen \
      --arch "$arch" --frames "$frames" --set "time.t_end=${REALTIME_T:-2}" 2>&1 | grep -v '^\[Taichi\]' \
      | tee -a "$out/realtime.txt"
    echo "exit ${PIPESTATUS[0]}" | tee -a "$out/realtime.txt"
  done
fi

if [[ ",$parts," == *",1,"* ]]; then
  echo "== 1. bench --report (cuda)"
  timeout "${LIMIT_1:-540}" $py -m taichi_sph bench --report --arch "$arch" ${REPORT_ARGS:-} --json "$out/report.json" 2>&1 | tee "$out/report.txt"
fi

if [[ ",$parts," == *",2,"* ]]; then
  echo "== 2. dam breaks on CUDA: wall crossings"
  for scene in dam_break_2d dam_break_3d; do
    timeout "${LIMIT_2:-300}" $py -m taichi_sph run "configs/$scene.yaml" --arch "$arch" --no-render --quiet --overwrite \
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
  TAICHI_SPH_TEST_ARCH=cuda timeout "${LIMIT_3:-600}" $py -m pytest -q -x -p no:cacheprovider 2>&1 | tail -25 | tee "$out/pytest.txt"
fi

if [[ ",$parts," == *",4,"* ]]; then
  echo "== 4. the device set on CUDA"
  TAICHI_SPH_TEST_ARCH=cuda timeout "${LIMIT_4:-600}" $py -m pytest -q -m vulkan -s -p no:cacheprovider 2>&1 | tail -40 | tee "$out/device-set-cuda.txt"
fi

if [[ ",$parts," == *",5,"* ]]; then
  echo "== 5. the device set on the GPU's Vulkan driver"
  TAICHI_SPH_TEST_ARCH=vulkan timeout "${LIMIT_5:-600}" $py -m pytest -q -m vulkan -s -p no:cacheprovider 2>&1 | tail -40 | tee "$out/device-set-vulkan.txt"
fi
