"""The repository's own directories, in one place and free of heavy imports (``pipeline.tables`` uses them
without torch): ``REPO`` the checkout, ``CONF`` its Hydra configs, ``RESULTS`` its committed results, ``RUNS`` its
committed run records (the experiments' default ``--records``, the same wherever a command runs from)."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CONF = REPO / "conf"
RESULTS = REPO / "results"
RUNS = RESULTS / "runs"
