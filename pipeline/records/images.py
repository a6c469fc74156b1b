"""Images written by the pipeline: per-step PNGs of a run (GT | prediction | score map | depth of
evaluation view 0; a map's value range and unit in its PNG text, for colour bars), colourised maps, and
matplotlib figures saved atomically."""

import io
import math
from pathlib import Path

import matplotlib
import numpy as np
from jaxtyping import Float
from matplotlib.figure import Figure
from PIL import Image, PngImagePlugin

from pipeline.atomic_write import atomic_write_bytes


def to_uint8(image: Float[np.ndarray, "H W 3"]) -> np.ndarray:
    return (np.nan_to_num(image).clip(0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def colorize(values: Float[np.ndarray, "H W"], cmap: str) -> np.ndarray:
    """A scalar map in a matplotlib colour map, scaled to its own finite range (NaN: black)."""
    finite = np.isfinite(values)
    out = np.zeros((*values.shape, 3))
    if finite.any():
        lo, hi = values[finite].min(), values[finite].max()
        scaled = (values - lo) / (hi - lo) if hi > lo else np.zeros_like(values)
        out = matplotlib.colormaps[cmap](np.where(finite, scaled, 0.0))[..., :3]
        out[~finite] = 0.0
    return out


MAP_COLORMAPS = {"score": "magma"}  # any other scalar map: viridis
DEPTH_UNIT = "scene units"
RANGE_KEY, UNIT_KEY = "nvf:range", "nvf:unit"  # PNG text of a colourised map: "low high" (or "none"), its unit


def save_step_images(directory: Path, step: int, images: dict[str, np.ndarray], score_unit: str = "") -> None:
    """Write ``step_XX_{gt,pred,score,depth}.png`` under ``directory``; a scalar map is colourised in its own
    finite range, which its PNG text records with its unit (``score_unit`` for the score map, scene units
    for depth; range ``none`` for a map without a finite value, e.g. the score map of a method with no scorer).
    Each is written atomically (``atomic_write_bytes``: never through a link planted at its name)."""
    for name, image in images.items():
        text = PngImagePlugin.PngInfo()
        if image.ndim == 2:
            finite = image[np.isfinite(image)]
            text.add_text(RANGE_KEY, f"{float(finite.min())!r} {float(finite.max())!r}" if finite.size else "none")
            text.add_text(UNIT_KEY, DEPTH_UNIT if name == "depth" else score_unit if name == "score" else "")
            image = colorize(image, MAP_COLORMAPS.get(name, "viridis"))
        png = io.BytesIO()
        Image.fromarray(to_uint8(image)).save(png, format="PNG", pnginfo=text)
        atomic_write_bytes(directory / f"step_{step:02d}_{name}.png", png.getvalue())


def map_range(path: Path) -> tuple[float, float, str] | None:
    """``(low, high, unit)`` a colourised map's PNG records (NaN, NaN when it had no finite value); None
    when it records none (images written before maps carried their range)."""
    with Image.open(path) as image:
        text = getattr(image, "text", {})
    if RANGE_KEY not in text:
        return None
    if text[RANGE_KEY] == "none":
        return math.nan, math.nan, text.get(UNIT_KEY, "")
    low, high = (float(v) for v in text[RANGE_KEY].split())
    return low, high, text.get(UNIT_KEY, "")


def save_figure(fig: Figure, path: Path, colors: int | None = None) -> None:
    """Save a figure as PNG atomically (``atomic_write_bytes``); with ``colors``, as a PNG with a palette of
    that many colours (smaller, for figures of few colours)."""
    png = io.BytesIO()
    fig.savefig(png, format="png")
    if colors is not None:
        with Image.open(io.BytesIO(png.getvalue())) as image:
            png = io.BytesIO()
            image.convert("RGB").quantize(colors).save(png, format="PNG", optimize=True)
    atomic_write_bytes(path, png.getvalue())
