"""Does uncertainty beat coverage in the committed cpu episodes? Final PSNR of every uncertainty method minus that of
FVS (METHOD 18) and of FVS among the candidates that look at the object (``fvs_facing``), paired by seed (the 95%
Student-t interval of ``pipeline.tables.stats.paired``), per scene and over the three scenes' nine seeds. Run from
the repository root:
``python scripts/pilots/uncertainty_vs_coverage.py > results/pilots/uncertainty_vs_coverage/episodes.txt``."""

import json
from pathlib import Path

import pandas as pd

from pipeline.tables.stats import paired

SCENES = ("default", "hotdog", "hubble")
METHODS = ("nvf", "fisherrf", "bayesrays", "activenerf", "neurar", "wd", "activermap", "air", "random")
COVERAGE = ("fvs", "fvs_facing")


def final_psnr(scene: str, method: str) -> pd.Series:
    """Final PSNR (dB) per seed of the cpu argmax records of ``method`` on ``scene``."""
    out = {}
    for seed in (100, 101, 102):
        steps = Path("results/runs") / scene / f"{method}-argmax-none" / "cpu" / f"seed_{seed}" / "steps.jsonl"
        out[(scene, seed)] = json.loads(steps.read_text().splitlines()[-1])["metrics"]["psnr"]
    return pd.Series(out)


for baseline in COVERAGE:
    print(f"method minus {baseline}, final PSNR (dB), paired by seed: mean [95% interval]")
    for method in (*METHODS, *(other for other in COVERAGE if other != baseline)):
        cells = []
        for scenes in [(s,) for s in SCENES] + [SCENES]:
            a = pd.concat([final_psnr(s, method) for s in scenes])
            b = pd.concat([final_psnr(s, baseline) for s in scenes])
            cells.append(paired(a, b).text())
        print(
            f"{method:11s} " + "  ".join(f"{name}: {cell}" for name, cell in zip([*SCENES, "all"], cells, strict=True))
        )
    print()
