"""Figures from run records: metric-vs-step curves per scene and budget, and a run's image grid (steps x
GT | prediction | score map | depth)."""

import hashlib
import math
import re
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from PIL import Image

from pipeline.metrics.info import PAPER_METRICS
from pipeline.records.files import is_plain_file
from pipeline.records.images import MAP_COLORMAPS, map_range, save_figure
from pipeline.tables.escape import plot_text
from pipeline.tables.load import Runs

IMAGE_NAME = re.compile(r"step_(\d+)_(.+)\.png")
UNSAFE = re.compile(r"[^A-Za-z0-9_.=+-]")
MAX_NAME_PART = 80
MAX_KINDS = 8  # columns of a run's image grid
MAX_IMAGE_PIXELS = 4096 * 4096  # a run's images are at most budget.image_size squared (512 px in the paper budget)
MAX_FILE_NAME = 200  # characters of a whole file name: its atomic write's temp name adds 22, within NAME_MAX (255)
IMAGE_KINDS = (("gt", "GT"), ("pred", "prediction"), ("score", "score map"), ("entropy", "entropy"), ("depth", "depth"))
KIND_ORDER = {kind: i for i, (kind, _) in enumerate(IMAGE_KINDS)}


def safe_name(text: object) -> str:
    """``text`` (a string from a run record: untrusted) as a piece of a file name that stays in its
    directory: characters other than letters, digits and ``_.=+-`` become ``_``, a leading ``.`` too;
    a changed or over-long text is cut and gets ``-`` and 8 hex digits of its SHA-1, so different
    texts keep different names."""
    text = str(text)
    name = UNSAFE.sub("_", text)
    name = "_" + name[1:] if name.startswith(".") else name
    if name == text and len(name) <= MAX_NAME_PART:
        return name
    return f"{name[:MAX_NAME_PART]}-{hashlib.sha1(text.encode('utf-8')).hexdigest()[:8]}"


def file_name(parts: list[object], separator: str, suffix: str) -> str:
    """A file name from record texts: each part ``safe_name``, joined with ``separator``; a name longer than
    ``MAX_FILE_NAME`` is cut and gets 8 hex digits of its SHA-1, so it can always be written."""
    stem = separator.join(safe_name(part) for part in parts)
    if len(stem) + len(suffix) <= MAX_FILE_NAME:
        return stem + suffix
    digest = hashlib.sha1(stem.encode("utf-8")).hexdigest()[:8]
    return f"{stem[: MAX_FILE_NAME - len(suffix) - 9]}-{digest}{suffix}"


def integer_steps(ax) -> None:
    """Step axes tick whole steps only."""
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def curves(runs: Runs, figures: Path) -> list[Path]:
    """Metric-vs-step curves per (scene, budget) of the finished runs: mean ± population-std band over seeds,
    one line per method in the paper's row order (colour by position, dashed for ablations), the legend in a
    row under the panels."""
    written = []
    for (scene, budget), frame in runs.long.groupby(["scene", "budget"]):
        fig = Figure(figsize=(16, 8), dpi=80)
        groups = sorted(frame.groupby(["method", "planner", "ablation"]), key=lambda kv: runs.row(*kv[0]).order)
        legend_rows = math.ceil(len(groups) / 7)
        fig.subplots_adjust(left=0.04, right=0.99, bottom=0.1 + 0.035 * legend_rows, top=0.9, wspace=0.25, hspace=0.35)
        axes = fig.subplots(2, 4).ravel()
        for ax, m in zip(axes, PAPER_METRICS, strict=True):
            for i, ((method, planner, ablation), group) in enumerate(groups):
                series = group[group["metric"] == m.name].groupby("step")["value"]
                mean, std = series.mean(), series.std(ddof=0).fillna(0.0)
                if mean.notna().any():
                    color = f"C{i % 10}"  # the 10-colour cycle; ablations dashed, so no two lines look alike
                    style = "-" if ablation == "none" else "--"
                    label = plot_text(runs.row(method, planner, ablation).label)
                    ax.plot(mean.index, mean.to_numpy(), color=color, linestyle=style, label=label)
                    low, high = (mean - std).to_numpy(), (mean + std).to_numpy()
                    ax.fill_between(mean.index, low, high, alpha=0.2, color=color)
            ax.set_title(f"{m.label} {m.arrow}")
            ax.set_xlabel("step")
            integer_steps(ax)
        handles, labels = axes[0].get_legend_handles_labels()
        if handles:
            fig.legend(handles, labels, loc="lower center", ncol=min(7, len(handles)), frameon=False)
        seeds = frame.groupby(["method", "planner", "ablation"])["seed"].nunique()
        seed_text = f"{seeds.min()}" if seeds.min() == seeds.max() else f"{seeds.min()}-{seeds.max()}"
        plural = "s" if seeds.max() > 1 else ""
        title = f"{scene}, {budget} budget: mean ± population std over {seed_text} seed{plural} per method"
        fig.suptitle(plot_text(title))
        path = figures / file_name(["curves", scene, budget], "_", ".png")
        save_figure(fig, path)
        written.append(path)
    return written


def step_images(run_dir: Path) -> dict[int, dict[str, Path]]:
    """``images/step_XX_<kind>.png`` of a run: step -> kind -> path."""
    found: dict[int, dict[str, Path]] = {}
    folder = Path(run_dir) / "images"
    for path in sorted(folder.glob("step_*.png")) if folder.is_dir() and not folder.is_symlink() else ():
        match = IMAGE_NAME.fullmatch(path.name)
        if match and is_plain_file(path):
            found.setdefault(int(match.group(1)), {})[match.group(2)] = path
    return found


def image_grid(run_dir: Path, out_path: Path, title: str = "", max_rows: int = 5) -> Path | None:
    """Assemble ``images/step_XX_<kind>.png`` of a run into one grid under ``title``: rows = up to ``max_rows``
    evenly spaced steps (first and last included), columns = GT, prediction, score/entropy map, depth, others,
    each enlarged without smoothing; a map with a recorded range gets a colour bar in its unit, a score map
    without a finite value says that the method scores no views. None when the run saved no images."""
    found = step_images(run_dir)
    if not found:
        return None
    kinds = sorted(
        {kind for images in found.values() for kind in images},
        key=lambda kind: (KIND_ORDER.get(kind, len(KIND_ORDER)), kind),
    )[:MAX_KINDS]
    steps = sorted(found)
    steps = [steps[round(i)] for i in np.linspace(0, len(steps) - 1, min(max_rows, len(steps)))]
    fig = Figure(figsize=(3.0 * len(kinds), 2.6 * len(steps) + 0.6), dpi=90, layout="constrained")
    axes = np.asarray(fig.subplots(len(steps), len(kinds), squeeze=False))
    for i, step in enumerate(steps):
        for j, kind in enumerate(kinds):
            ax = axes[i, j]
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(plot_text(dict(IMAGE_KINDS).get(kind, kind)))
            if j == 0:
                ax.set_ylabel(f"step {step}")
            if kind in found[step]:
                _image_panel(fig, ax, kind, found[step][kind])
            else:
                ax.set_axis_off()
    fig.suptitle(f"{plot_text(title)}\nevaluation view 0; each map coloured in its own range" if title else "")
    save_figure(fig, Path(out_path))
    return Path(out_path)


def _read_image(path: Path) -> np.ndarray | None:
    """A run's PNG as an array (``[H, W]``, or ``[H, W, 3 | 4]``), or None when it is not a readable image of
    that shape and at most ``MAX_IMAGE_PIXELS`` pixels."""
    try:
        with Image.open(path) as image:
            if image.width * image.height > MAX_IMAGE_PIXELS:
                return None
        array = iio.imread(path)
    except (OSError, ValueError, Image.DecompressionBombError):
        return None
    return array if array.ndim == 2 or (array.ndim == 3 and array.shape[-1] in (3, 4)) else None


def _image_panel(fig: Figure, ax, kind: str, path: Path) -> None:
    """One grid cell: the image enlarged (nearest neighbour) and, for a map, its colour bar or why it is empty.
    The images are record files too (untrusted): one that does not decode (``_read_image``) leaves the cell
    empty, and a map whose recorded range does not parse gets no colour bar."""
    image = _read_image(path)
    if image is None:
        ax.set_axis_off()
        return
    ax.imshow(
        image[..., :3] if image.ndim == 3 else image,
        cmap=None if image.ndim == 3 else "viridis",
        interpolation="nearest",
    )
    try:
        recorded = map_range(path) if kind not in ("gt", "pred") else None
    except (OSError, ValueError):
        recorded = None
    if recorded is None:
        return
    low, high, unit = recorded
    if math.isnan(low) and math.isnan(high):
        ax.images[0].set_alpha(0.15)
        ax.text(
            0.5,
            0.5,
            "no score map:\nthis method\nscores no views" if kind == "score" else "no finite value",
            transform=ax.transAxes,
            ha="center",
            va="center",
            fontsize=9,
        )
        return
    if not (math.isfinite(low) and math.isfinite(high)):
        return  # a range no map of ours records
    norm = Normalize(low, high if high > low else low + 1e-12)
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=MAP_COLORMAPS.get(kind, "viridis")), ax=ax, shrink=0.9)
    bar.set_label(plot_text(unit), fontsize=8)
    bar.ax.tick_params(labelsize=7)


def step_curve(rows: list[dict], title: str, out_path: Path) -> Path:
    """PSNR per step of one run's rows (``steps.jsonl``), as a PNG at ``out_path``."""
    steps = [row["step"] for row in rows]
    psnr = [row["metrics"].get("psnr") for row in rows]
    fig = Figure(figsize=(5, 3.2), dpi=100, layout="constrained")
    ax = fig.subplots()
    ax.plot(steps, [math.nan if v is None else v for v in psnr], marker="o", markersize=3)
    ax.set_xlabel("step")
    ax.set_ylabel("PSNR (dB)")
    integer_steps(ax)
    ax.set_title(plot_text(title), fontsize=9)
    ax.grid(alpha=0.3)
    save_figure(fig, Path(out_path))
    return Path(out_path)
