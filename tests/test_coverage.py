"""nvf/coverage.py: farthest view sampling's view distance (M33) and its pick."""

import math

import torch

from nvf.cameras import Intrinsics, look_at, matrix_to_pose, pixel_rays
from nvf.config import FieldConfig, SamplerConfig
from nvf.coverage import BEHIND, FarthestViewScorer, faces, view_distance
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.planning import argmax_first, score_poses

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
INTR = Intrinsics.from_fov(8, 8)


def view(position, target=(0.0, 0.0, 0.0)) -> torch.Tensor:
    return look_at(torch.tensor(position), torch.tensor(target))


def test_view_distance_adds_the_centres_angle_about_the_object_and_the_directions_angle():
    """(M33) Zero for the same view; pi for the centre on the opposite side looking at the object (both terms
    pi/2 at a right angle); pi for the same centre looking the other way."""
    o = torch.zeros(3, dtype=torch.float64)
    c, f = torch.tensor([0.0, -3.0, 0.0], dtype=torch.float64), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    others = torch.tensor([[0.0, -3.0, 0.0], [3.0, 0.0, 0.0], [0.0, -3.0, 0.0]], dtype=torch.float64)
    forwards = torch.tensor([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], dtype=torch.float64)
    d = view_distance(c, f, others, forwards, o)
    assert torch.allclose(d, torch.tensor([0.0, math.pi, math.pi], dtype=torch.float64), atol=1e-12)


def test_fvs_picks_the_candidate_farthest_from_every_observed_view():
    """(M33) Observed views on one side of the object: of candidates beside them, at a right angle and opposite,
    the opposite one scores highest; the score is the distance to the nearest observed view, read off the
    candidate's rays (its centre and optical axis)."""
    model = SceneModel(
        AABB, FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32), SamplerConfig(grid_resolution=16)
    )
    observed = torch.stack([view([0.0, -3.0, 0.5]), view([0.5, -3.0, 0.0])])
    obs = Observations(torch.zeros(2, 8, 8, 4), observed, INTR)
    scorer = FarthestViewScorer().prepare(model, obs, lambda purpose: torch.Generator(), 64)
    candidates = torch.stack([matrix_to_pose(view(p)) for p in ([0.2, -3.0, 0.3], [3.0, 0.0, 0.0], [0.0, 3.0, 0.0])])
    scores = score_poses(model, scorer, candidates, INTR, 64)
    assert argmax_first(scores) == 2 and scores[0] < scores[1] < scores[2]
    origins, dirs = pixel_rays(view([3.0, 0.0, 0.0]), INTR)
    expected = view_distance(
        torch.tensor([3.0, 0.0, 0.0], dtype=torch.float64),
        torch.tensor([-1.0, 0.0, 0.0], dtype=torch.float64),
        scorer.centres,
        scorer.forwards,
        scorer.pivot,
    ).min()
    assert math.isclose(float(scorer.view_score(model, origins, dirs, 64)), float(expected), abs_tol=1e-6)


def test_facing_fvs_ranks_the_views_that_look_at_the_object_first():
    """(M33, facing variant) A candidate far from the observed views but looking away from the object ranks below
    a nearer one that looks at it; without ``facing`` the far one wins. Among views that all miss the object the
    farthest still ranks first (each loses the same ``BEHIND``)."""
    model = SceneModel(
        AABB, FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32), SamplerConfig(grid_resolution=16)
    )
    observed = torch.stack([view([0.0, -3.0, 0.5])])
    obs = Observations(torch.zeros(1, 8, 8, 4), observed, INTR)
    candidates = torch.stack(
        [
            matrix_to_pose(view([3.0, 0.0, 0.0])),  # a right angle round, looking at the object
            matrix_to_pose(view([0.0, 3.0, 0.0], target=(3.0, 3.0, 0.0))),  # opposite, looking sideways
            matrix_to_pose(view([0.0, -3.0, 0.0], target=(3.0, -3.0, 0.0))),  # beside the observed, sideways
        ]
    )
    generators = lambda purpose: torch.Generator()  # noqa: E731
    plain = score_poses(model, FarthestViewScorer().prepare(model, obs, generators, 64), candidates, INTR, 64)
    facing = score_poses(model, FarthestViewScorer(True).prepare(model, obs, generators, 64), candidates, INTR, 64)
    assert argmax_first(plain) == 1 and argmax_first(facing) == 0
    assert torch.allclose(facing, plain - torch.tensor([0.0, BEHIND, BEHIND], dtype=plain.dtype), atol=1e-5)
    assert facing[1] > facing[2]


def test_faces_is_the_optical_axis_meeting_the_box():
    """A camera outside the box faces it when its axis points into the box, not when it points away or past it;
    inside the box every direction meets it."""
    box = AABB.to(torch.float64)
    outside = torch.tensor([0.0, -3.0, 0.0], dtype=torch.float64)
    assert faces(outside, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), box)
    assert not faces(outside, torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64), box)
    assert not faces(outside, torch.tensor([1.0, 0.2, 0.0], dtype=torch.float64), box)
    assert faces(torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64), box)
