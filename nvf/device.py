"""The one place a device is chosen: ``device=auto`` is the first CUDA device where torch sees one, else the
CPU. Everything else takes the resolved ``torch.device`` as an argument (docs/ARCHITECTURE.md, "Devices")."""

import torch


def resolve_device(name: str = "auto") -> torch.device:
    """``auto``: ``cuda`` when torch sees a CUDA device, else ``cpu``; any other name as torch reads it
    (``cpu``, ``cuda``, ``cuda:1``)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def synchronize() -> None:
    """Wait for every CUDA kernel this process queued (a no-op where it never used CUDA): CUDA runs
    asynchronously, so a timer reads its clock after this."""
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()
