"""Images written by the pipeline: per-step PNGs of a run (GT | prediction | score map | depth of
evaluation view 0), colourised maps, and matplotlib figures saved atomically."""

import io
from pathlib import Path

import imageio.v3 as iio
import matplotlib
import numpy as np
from jaxtyping import Float
from matplotlib.figure import Figure

from pipeline.records.store import atomic_write_bytes


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


def save_step_images(directory: Path, step: int, images: dict[str, np.ndarray]) -> None:
    """Write ``step_XX_{gt,pred,score,depth}.png`` (maps colourised) under ``directory``, each atomically
    (``atomic_write_bytes``: never through a link planted at its name)."""
    for name, image in images.items():
        rgb = image if image.ndim == 3 else colorize(image, "magma" if name == "score" else "viridis")
        png = iio.imwrite("<bytes>", to_uint8(rgb), extension=".png")
        atomic_write_bytes(directory / f"step_{step:02d}_{name}.png", png)


def save_figure(fig: Figure, path: Path) -> None:
    """Save a figure as PNG atomically (``atomic_write_bytes``)."""
    png = io.BytesIO()
    fig.savefig(png, format="png")
    atomic_write_bytes(path, png.getvalue())
