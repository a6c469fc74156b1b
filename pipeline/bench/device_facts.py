"""``python -m pipeline.bench device [--out PATH] [overrides]``: the facts of the machine a run would use:
the device ``device=auto`` picks, torch and CUDA versions, each CUDA device's name, compute capability and
memory, the precisions it trains natively, ``nvidia-smi``'s view of the GPUs (where it is installed), the
CPU's cores and memory. Writes ``${paths.results}/bench/device.json`` (or ``--out``).
"""

import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import torch

from nvf.device import resolve_device
from nvf.precision import supported_precisions
from pipeline.bench._report import report_path, write_report
from pipeline.cli import ArgumentParser, description, fail
from pipeline.config.memory import GIB, host_memory
from pipeline.config.paths import paths_from_args

NVIDIA_SMI_QUERY = "name,memory.total,driver_version,compute_cap,utilization.gpu,memory.used"


def nvidia_smi() -> list[dict[str, str]] | str:
    """One row per GPU from ``nvidia-smi --query-gpu``, or why there is none."""
    if shutil.which("nvidia-smi") is None:
        return "nvidia-smi is not on PATH"
    command = ["nvidia-smi", f"--query-gpu={NVIDIA_SMI_QUERY}", "--format=csv,noheader"]
    try:
        lines = subprocess.run(command, capture_output=True, text=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError) as err:
        return f"nvidia-smi failed: {' '.join(str(err).split())}"
    keys = NVIDIA_SMI_QUERY.split(",")
    return [dict(zip(keys, (v.strip() for v in line.split(",")), strict=False)) for line in lines.splitlines() if line]


def cuda_devices() -> list[dict[str, object]]:
    """Each CUDA device torch sees: name, compute capability, memory and native training precisions."""
    found = []
    for index in range(torch.cuda.device_count()):
        props = torch.cuda.get_device_properties(index)
        found.append(
            {
                "index": index,
                "name": props.name,
                "compute_capability": f"{props.major}.{props.minor}",
                "memory_gib": props.total_memory / GIB,
                "multiprocessors": props.multi_processor_count,
                "precisions": list(supported_precisions(torch.device("cuda", index))),
            }
        )
    return found


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench device", description=description(__doc__))
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON path (default: ${paths.results}/bench/device.json)"
    )
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="paths overrides, e.g. paths.results=DIR")
    args = parser.parse_intermixed_args(argv)
    try:
        out = report_path(args.out, paths_from_args(args.overrides, ("paths.results",))["results"], "device")
    except ValueError as err:
        fail(str(err))
    report = {
        "benchmark": "device",
        "device_auto": str(resolve_device("auto")),
        "torch": torch.__version__,
        "torch_cuda": torch.version.cuda,
        "cuda_available": torch.cuda.is_available(),
        "cuda_devices": cuda_devices(),
        "nvidia_smi": nvidia_smi(),
        "cpu_precisions": list(supported_precisions(torch.device("cpu"))),
        "python": sys.version.split()[0],
        "machine": platform.platform(),
        "cores": os.cpu_count(),
        "memory_gib": host_memory() / GIB,
    }
    write_report(report, out)
    print(f"device=auto is {report['device_auto']}; torch {report['torch']} (CUDA {report['torch_cuda']}); wrote {out}")
