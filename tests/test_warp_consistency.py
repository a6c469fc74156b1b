"""nvf/warp_consistency.py: WarpRF's backward warp (M40), per-pixel disagreement (M41) and view score (M42);
``method=warprf`` at the smoke budget."""

import torch

from nvf.cameras import Intrinsics, look_at, pixel_rays
from nvf.config import FieldConfig, SamplerConfig
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.seeding import generator_factory
from nvf.warp_consistency import WarpScorer, warped
from pipeline.config.validation import compose_run
from pipeline.episode.runner import run_episode

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
INTR = Intrinsics.from_fov(8, 8)
NARROW = Intrinsics.from_fov(8, 8, 30.0)


def test_a_point_reads_the_training_image_where_it_projects():
    """(M40) A point on the optical axis of a camera reads its image's centre (bilinear between the four centre
    pixels); one projecting outside reads the border."""
    camera = look_at(torch.tensor([3.0, 0.0, 0.0]), torch.zeros(3))
    image = torch.zeros(8, 8, 3)
    image[3:5, 3:5] = torch.tensor([0.2, 0.4, 0.6])
    image[:, 7] = torch.tensor([1.0, 0.0, 0.0])
    got = warped(torch.tensor([[0.0, 0.0, 0.0], [0.0, 30.0, 0.0]]), image, camera, INTR)  # +y: the camera's right
    torch.testing.assert_close(got[0], torch.tensor([0.2, 0.4, 0.6]))
    torch.testing.assert_close(got[1], torch.tensor([1.0, 0.0, 0.0]))


def test_a_candidate_the_warped_views_agree_with_scores_below_one_they_disagree_with():
    """(M41, M42) At a training view's own pose every pixel's point warps back onto its own pixel, so the warped
    rendering agrees with the candidate's (score ~0); from another side the renderings disagree (score > 0). A
    narrow view whose every ray meets the occupied box: a ray meeting nothing has depth 0, its point the camera's
    centre (as the reference's zero depth), which reads no pixel of its own view."""
    torch.manual_seed(0)
    model = SceneModel(
        AABB, FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32), SamplerConfig(grid_resolution=8)
    )
    model.grid.occupied[:] = True
    with torch.no_grad():
        model.field.encoding.table.normal_(0.0, 1.0)  # a textured field: colours vary across the view
    train = torch.stack([look_at(torch.tensor([2.6, 0.0, 0.3]), torch.zeros(3))])
    views = WarpScorer().prepare(
        model, Observations(torch.zeros(1, 8, 8, 4), train, NARROW), generator_factory(0, 0, "cpu"), 4096
    )

    def score(c2w: torch.Tensor) -> float:
        return float(views.view_score(model, *pixel_rays(c2w, NARROW), 16))

    agree, disagree = score(train[0]), score(look_at(torch.tensor([-2.0, 1.5, -0.5]), torch.zeros(3)))
    assert agree < 1e-4 < 0.01 < disagree


def test_warprf_runs_an_episode_at_the_smoke_budget(tmp_path):
    run = compose_run(
        ["budget=smoke", "scene=default", "method=warprf", "budget.horizon=2", f"paths.outputs={tmp_path}"]
    )
    assert run_episode(run).status == "done"
