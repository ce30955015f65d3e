#!/usr/bin/env bash
# One-time set-up on a fresh Debian/Ubuntu machine (idempotent; safe to re-run):
#  - system packages when missing: software Vulkan (mesa-vulkan-drivers) for the offscreen renderer,
#    a virtual X server (xvfb, xauth) for the live window's tests (`taichi-sph view` under Xvfb),
#    python3-venv for the virtual environment
#  - a virtual environment in .venv with taichi-sph and its dependencies installed (editable), with the
#    dev extra (ruff, the linter CI runs)
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
# (either folder may hold the driver files: `ls a/*.json b/*.json` fails when one of them is empty)
if ! compgen -G "/usr/share/vulkan/icd.d/*.json" >/dev/null && ! compgen -G "/etc/vulkan/icd.d/*.json" >/dev/null; then
  need+=(mesa-vulkan-drivers libvulkan1)
fi
if ! ldconfig -p 2>/dev/null | grep -q "libX11.so.6"; then need+=(libx11-6); fi
# the live window (GLFW inside Taichi) loads these X libraries at run time
for lib in libXrandr.so.2:libxrandr2 libXinerama.so.1:libxinerama1 libXcursor.so.1:libxcursor1 libXi.so.6:libxi6 \
           libXxf86vm.so.1:libxxf86vm1 libX11-xcb.so.1:libx11-xcb1; do
  if ! ldconfig -p 2>/dev/null | grep -q "${lib%%:*}"; then need+=("${lib##*:}"); fi
done
if ! command -v Xvfb >/dev/null 2>&1; then need+=(xvfb); fi
if ! command -v xauth >/dev/null 2>&1; then need+=(xauth); fi
if ! python3 -c "import ensurepip, venv" >/dev/null 2>&1; then need+=(python3-venv); fi
if [ ${#need[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    echo "setup: installing ${need[*]}" >&2
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  else
    echo "setup: missing ${need[*]}; install them with: sudo apt-get install -y ${need[*]}" >&2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
.venv/bin/python -m pip install -q -e ".[dev,cluster]"  # cluster: Ray, so that tests/test_executor.py runs the --cluster path
echo "setup: ready (.venv/bin/taichi-sph)" >&2
