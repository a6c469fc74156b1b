"""CI check: the smoke sweep's regenerated long table has the expected runs and finite numbers."""

import math
import sys
from pathlib import Path

import pandas as pd

EXPECTED_METHODS = {"random", "nvf"}
REQUIRED_METRICS = ("psnr", "ssim", "rgb", "vis")


def main(results: Path) -> None:
    runs = pd.read_csv(results / "runs.csv")
    methods = set(runs["method"])
    if methods != EXPECTED_METHODS:
        sys.exit(f"smoke table: methods {sorted(methods)} != {sorted(EXPECTED_METHODS)}")
    final = runs[runs["step"] == runs.groupby(["method"])["step"].transform("max")]
    for method in EXPECTED_METHODS:
        for metric in REQUIRED_METRICS:
            values = final[(final["method"] == method) & (final["metric"] == metric)]["value"]
            if values.empty or not all(math.isfinite(v) for v in values):
                sys.exit(f"smoke table: {method}/{metric} missing or not finite: {list(values)}")
    print(f"smoke table ok: {len(runs)} rows, methods {sorted(methods)}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
