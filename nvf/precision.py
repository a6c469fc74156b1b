"""Numeric precision of the field's MLPs (``train.precision``): the names, their dtypes, and which of
them a device runs natively.

``fp32`` is plain float32. ``bf16`` and ``fp16`` run the MLPs' layers in bfloat16 / float16
(``RadianceField.mlp_precision``); the hash table, the volume-rendering sums, the entropy maths and
the losses stay float32. On the CPU a low precision pays only with native instructions (oneDNN):
bfloat16 dot products (AVX512_BF16 or AMX on x86, the BF16 extension on Arm) and float16 arithmetic
(AVX512_FP16 or AMX-FP16); without them oneDNN emulates the type, slower than float32.
"""

import platform

import torch

from nvf.config import Precision

DTYPES: dict[str, torch.dtype] = {
    Precision.fp32: torch.float32,
    Precision.bf16: torch.bfloat16,
    Precision.fp16: torch.float16,
}
PRECISIONS = tuple(Precision)
# What a device needs to run a low precision natively, for error messages.
REQUIREMENTS = {
    ("cpu", "bf16"): "bfloat16 dot products (AVX512_BF16 or AMX on x86, BF16 on Arm)",
    ("cpu", "fp16"): "float16 arithmetic (AVX512_FP16 or AMX-FP16)",
    ("cuda", "bf16"): "compute capability 8.0 or later",
}


def precision_dtype(precision: str) -> torch.dtype:
    """The dtype of a precision name (fp32 | bf16 | fp16)."""
    if precision not in DTYPES:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return DTYPES[precision]


def _cpu_bf16() -> bool:
    if platform.machine().lower() in ("x86_64", "amd64"):
        return torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()
    return torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported()


def _cpu_fp16() -> bool:
    return torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_fp16_supported()


def supported_precisions(device: torch.device) -> tuple[str, ...]:
    """The precisions ``device`` runs natively: always fp32; on CUDA fp16, and bf16 where the GPU has
    it (compute capability 8.0 and later); on the CPU bf16 and fp16 where its instructions do."""
    if device.type == "cuda":
        bf16 = torch.cuda.is_bf16_supported(including_emulation=False)
        return ("fp32", "bf16", "fp16") if bf16 else ("fp32", "fp16")
    if device.type == "cpu":
        return tuple(p for p, native in (("fp32", True), ("bf16", _cpu_bf16()), ("fp16", _cpu_fp16())) if native)
    return ("fp32",)


def unsupported_reason(precision: str, device: torch.device) -> str | None:
    """``None`` if ``device`` runs ``precision`` natively, else one line saying what it lacks and what
    it supports."""
    if precision == "fp32":
        return None
    available = supported_precisions(device)
    if precision in available:
        return None
    need = REQUIREMENTS.get((device.type, precision), f"a {device.type} device with {precision} support")
    return f"{precision} needs {need}, which this {device.type} lacks; available here: {', '.join(available)}"
