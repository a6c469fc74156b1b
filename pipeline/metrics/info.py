"""The benchmark's metrics as data (PROTOCOL.md 4): name, table label, better direction, whether the
paper reports it, table decimals, the definition written into every run record and the range its values
lie in (records are checked against it when read). No heavy imports, so table generation stays cheap."""

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType


@dataclass(frozen=True)
class MetricInfo:
    """How a metric is shown in tables: ``label``, whether higher values are better, whether it is one
    of the paper's eight columns, the decimals of a table cell; ``definition`` for run records; ``bounds``,
    the closed range every value lies in (``pipeline.records.verify`` refuses a record with one outside)."""

    name: str
    label: str
    higher_is_better: bool
    paper: bool
    decimals: int
    definition: str
    bounds: tuple[float, float]

    @property
    def arrow(self) -> str:
        return "↑" if self.higher_is_better else "↓"


MAX_DISTANCE = 1000.0  # scene units: every scene spans less than 20 (PROTOCOL 2)
UNIT = (0.0, 1.0)
CORRELATION = (-1.0, 1.0)

_ALL = (
    # name, label, higher is better, in the paper's tables, decimals, definition, bounds
    MetricInfo(
        "psnr",
        "PSNR",
        True,
        True,
        2,
        "10 log10(1 / RGB), RGB the MSE pooled over the 20 evaluation views (PROTOCOL 4.1)",
        (0.0, 100.0),  # dB: the MSE of images in [0, 1] is at most 1; 100 dB is an MSE of 1e-10
    ),
    MetricInfo(
        "ssim",
        "SSIM",
        True,
        True,
        3,
        "Gaussian 11x11 window, sigma 1.5, 5-pixel border dropped, mean over views (PROTOCOL 4.1)",
        CORRELATION,
    ),
    MetricInfo(
        "lpips",
        "LPIPS",
        False,
        True,
        3,
        "AlexNet v0.1 linear heads, inputs in [-1, 1], mean over views; null without weights (PROTOCOL 4.1)",
        (0.0, 2.0),  # unrelated images are about 1 apart
    ),
    MetricInfo(
        "rgb",
        "RGB",
        False,
        True,
        4,
        "MSE pooled over all evaluation pixels and channels, black background (PROTOCOL 4.1)",
        UNIT,
    ),
    MetricInfo(
        "acc",
        "Acc.",
        False,
        True,
        4,
        "mean distance reconstructed -> nearest GT point; null if nothing is reconstructed (PROTOCOL 4.2)",
        (0.0, MAX_DISTANCE),
    ),
    MetricInfo(
        "comp",
        "Comp.",
        False,
        True,
        4,
        "mean distance GT point -> nearest reconstructed point; null for an empty reconstruction",
        (0.0, MAX_DISTANCE),
    ),
    MetricInfo(
        "cr",
        "C.R.",
        True,
        True,
        3,
        "fraction of GT points within the scene's C.R. threshold of a reconstructed point (PROTOCOL 4.2)",
        UNIT,
    ),
    MetricInfo(
        "vis",
        "Vis.",
        True,
        True,
        3,
        "seen GT faces / all GT faces over the observed poses, a face count (PROTOCOL 4.3)",
        UNIT,
    ),
    MetricInfo(
        "vis_area",
        "Vis. (area)",
        True,
        False,
        3,
        "area-weighted fraction of seen GT faces (logged, not reported)",
        UNIT,
    ),
    MetricInfo(
        "patch_pearson",
        "Patch r",
        True,
        False,
        3,
        "Pearson r of 32x32-patch means of error and uncertainty (PROTOCOL 4.4)",
        CORRELATION,
    ),
    MetricInfo(
        "view_pearson",
        "View r",
        True,
        False,
        3,
        "Pearson r of per-view sums of error and uncertainty (PROTOCOL 4.4)",
        CORRELATION,
    ),
    MetricInfo(
        "ause",
        "AUSE (addition)",
        False,
        False,
        4,
        "area under the sparsification error curve minus the oracle's; 0 is a perfect ranking (an addition)",
        (0.0, 3.0),  # a mean of per-pixel errors, each a sum over 3 channels in [0, 1]
    ),
)
METRICS: Mapping[str, MetricInfo] = MappingProxyType({m.name: m for m in _ALL})
PAPER_METRICS: tuple[MetricInfo, ...] = tuple(m for m in METRICS.values() if m.paper)  # the paper's column order
