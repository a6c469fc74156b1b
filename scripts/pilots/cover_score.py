"""COVER's own view score against the port's (docs/METHOD.md M39) on the planner's candidates: default seed 100's
first step (its three initial views, trained as the cpu episode trains them), every candidate scored both ways,
then the picks of two whole episodes, one per score. Run from the repository root with one torch thread:
``OMP_NUM_THREADS=1 python scripts/pilots/cover_score.py > results/pilots/cover_score/output.txt``.

COVER's score ``S`` is the mean of ``M(p)`` over the pixels with ``A(p) > 0`` (the lowest taken: here its
complement ``1 - S``, the highest); the port's ``U`` is the mean of ``A(p) - M(p)`` over every pixel. The episode
of ``S`` is ``results/pilots/cover_score/episode_seen_mean`` (made before the port scored ``U``); the episode of
``U`` is the committed record ``results/runs/default/cover-argmax-none/cpu/seed_100``."""

import json
from pathlib import Path

import numpy as np
import torch
from scipy import stats

from nvf.cameras import pixel_rays, pose_to_matrix
from nvf.cover import CoveredViews
from nvf.planning import prepare_scorer
from pipeline.config.validation import compose_run
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import LpipsMetric
from pipeline.scenes.blender import blender_python
from pipeline.scenes.loading import load_scene

PILOT = Path("results/pilots/cover_score")
EPISODES = {
    "S (COVER's)": PILOT / "episode_seen_mean",
    "U (the port's)": Path("results/runs/default/cover-argmax-none/cpu/seed_100"),
}


def off_axis(c2w: np.ndarray, centre: np.ndarray) -> float:
    """Degrees between a camera's axis (its -z) and the direction from its centre to ``centre``."""
    axis, towards = -c2w[:3, 2], centre - c2w[:3, 3]
    return float(np.degrees(np.arccos(np.clip(axis @ towards / np.linalg.norm(towards), -1.0, 1.0))))


def main() -> None:
    run = compose_run(["scene=default", "method=cover", "seed=100", "budget=cpu"])
    scene = load_scene(run.scene, Path(run.paths.assets), blender_python(run.paths.blender_python))
    centre = scene.object_aabb.mean(dim=0).numpy()
    episode = Episode(EpisodeSettings.of(run, scene), scene, torch.device("cpu"), LpipsMetric())
    try:
        obs = episode.observations()
        model, _ = episode.train(obs, 0)
        selection, generators = episode.plan(model, obs, 0)
        chunk = episode.settings.planner.score_chunk_rays
        views = prepare_scorer(episode.scorer, model, obs, generators, chunk)
    finally:
        episode.close()
    assert isinstance(views, CoveredViews) and selection.candidates is not None and selection.scores is not None
    rows = []
    for pose in selection.candidates:
        c2w = pose_to_matrix(pose)
        opacity, coverage = views.opacity_and_coverage(model, *pixel_rays(c2w, episode.plan_intrinsics), chunk)
        seen = opacity > 0
        s = 1.0 - float(coverage[seen].mean()) if bool(seen.any()) else 0.0
        u = float((opacity - coverage).mean())
        mean_opacity = float(opacity[seen].mean()) if bool(seen.any()) else 0.0
        rows.append((s, u, int(seen.sum()), mean_opacity, off_axis(c2w.numpy(), centre)))
    table = np.array(rows)
    assert np.allclose(table[:, 1], selection.scores.double().numpy()), "U is the score the episode planned with"
    pixels = episode.plan_intrinsics.num_pixels
    print(f"default seed 100, step 0: {len(table)} candidates of {pixels} planning pixels each")
    print(
        f"  seeing any geometry: {int((table[:, 2] > 0).sum())}; axis within 30 deg of the object's centre: "
        f"{int((table[:, 4] < 30).sum())}"
    )
    for k, name in ((0, "1 - S (COVER's)"), (1, "U (the port's)")):
        i = int(np.argmax(table[:, k]))
        print(
            f"  argmax of {name}: candidate {i}, score {table[i, k]:.3f}, pixels seeing geometry {int(table[i, 2])}, "
            f"their mean opacity {table[i, 3]:.4f}, {table[i, 4]:.0f} deg off the object"
        )
    seeing = table[:, 2] > 0
    rho = stats.spearmanr(table[seeing, 0], table[seeing, 1]).statistic
    print(f"  Spearman of 1 - S and U over the candidates seeing geometry: {rho:.2f}")
    for name, folder in EPISODES.items():
        steps = [json.loads(line) for line in (folder / "steps.jsonl").read_text().splitlines()]
        angles = [off_axis(pose_to_matrix(torch.tensor(r["selected_pose"])).numpy(), centre) for r in steps]
        psnr = [r["metrics"]["psnr"] for r in steps]
        print(
            f"episode of {name}: picks {np.median(angles):.0f} deg off the object (median), "
            f"{np.mean(np.array(angles) > 30):.2f} over 30 deg; PSNR step 0 {psnr[0]:.2f}, "
            f"max {max(psnr):.2f}, last {psnr[-1]:.2f} dB"
        )


if __name__ == "__main__":
    main()
