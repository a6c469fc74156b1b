"""FisherRF's probe count against its cost (``python -m pipeline.bench plan --probes 1,2,4,8,16``, M31): per
``K`` the preparation and scoring seconds and the candidates' ranking against an independent draw of the
largest ``K``."""

import time

from jaxtyping import Float
from torch import Tensor

from nvf.cameras import Intrinsics
from nvf.planning import argmax_first, score_poses
from nvf.seeding import generator_factory
from nvf.uncertainty.fisher import FisherRFScorer
from pipeline.cli import fail
from pipeline.diagnostics.initial_view_model import InitialViewModel
from pipeline.metrics.ranking import spearman


def probes_study(
    setup: InitialViewModel,
    poses: Float[Tensor, "m 7"],
    intr: Intrinsics,
    chunk: int,
    probes: list[int],
    prior_precision: float,
) -> dict:
    """FisherRF (lambda ``prior_precision``) at each ``K`` of ``probes`` (sorted) on ``setup``'s model and
    ``poses``: seconds (prepare, score, per step) and the agreement of the candidates' scores with the largest
    ``K``'s drawn with seed + 1."""
    seed = int(setup.cfg.seed)

    def run(k: int, seed: int) -> tuple[Tensor, float, float]:
        start = time.perf_counter()
        generators = generator_factory(seed, 0, setup.model.aabb.device)
        scorer = FisherRFScorer(k, prior_precision).prepare(setup.model, setup.obs, generators, chunk)
        prepared = time.perf_counter()
        scores = score_poses(setup.model, scorer, poses, intr, chunk)
        return scores, prepared - start, time.perf_counter() - prepared

    reference, _, _ = run(max(probes), seed + 1)
    rows = []
    for k in sorted(probes):
        scores, prepare, score = run(k, seed)
        rows.append({
            "probes": k, "prepare_seconds": prepare, "prepare_seconds_per_view": prepare / setup.obs.num_images,
            "score_seconds": score, "seconds_per_step": prepare + score,
            "spearman_to_reference": spearman(scores.cpu().numpy(), reference.cpu().numpy()),
            "same_choice_as_reference": argmax_first(scores) == argmax_first(reference),
            "choice_over_best_in_reference": float(reference[argmax_first(scores)] / reference.max()),
        })  # fmt: skip
    return {"reference_probes": max(probes), "prior_precision": prior_precision, "rows": rows}


def parse_probes(value: str) -> list[int]:
    """``1,2,4`` -> distinct positive probe counts (one line and exit status 2 otherwise)."""
    try:
        counts = [int(part) for part in value.split(",") if part.strip()]
    except ValueError:
        counts = []
    if not counts or min(counts) < 1 or len(set(counts)) != len(counts):
        fail(f"--probes {value!r} must list distinct positive probe counts, e.g. 1,2,4,8,16")
    return counts
