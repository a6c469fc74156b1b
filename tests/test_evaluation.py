"""pipeline/episode/evaluation.py: the step's reconstruction (PROTOCOL 4.2) equals the straightforward one."""

import math

import numpy as np
import pytest
import torch

from nvf.cameras import Intrinsics, look_at
from nvf.config import FieldConfig, SamplerConfig
from nvf.model import SceneModel
from nvf.observations import Observations
from pipeline.episode.evaluation import reconstruct_points
from pipeline.metrics.geometry import points_from_rays

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _setup() -> tuple[SceneModel, Observations]:
    """An untrained hash-grid model (a few per cent of its rays reach A > 0.5) and three 16 x 16
    training views around it."""
    torch.manual_seed(0)
    cfg = FieldConfig(num_levels=4, log2_hashmap_size=12, max_resolution=64, hidden_dim=16)
    model = SceneModel(AABB, cfg, SamplerConfig(grid_resolution=16))
    model.update_grid(0, torch.Generator().manual_seed(0))
    eyes = torch.tensor([[3.0, 0.5, 0.5], [0.3, -3.0, 1.0], [-2.0, 2.0, -1.5]])
    c2w = torch.stack([look_at(eye, torch.zeros(3)) for eye in eyes])
    return model, Observations(torch.rand(3, 16, 16, 4), c2w, Intrinsics.from_fov(16, 16))


@torch.no_grad()
def _straightforward(model, obs, num_points, batch, generator) -> np.ndarray:
    """PROTOCOL 4.2 as written: render every drawn batch with the default (rgb) head, keep A > 0.5."""
    points = []
    for _ in range(4 * math.ceil(num_points / batch)):
        origins, dirs, _, _ = obs.sample_rays(batch, generator)
        result = model.render(origins, dirs)
        points.append(points_from_rays(origins, dirs, result.depth, result.acc).numpy())
        if sum(map(len, points)) >= num_points:
            break
    return np.concatenate(points)[:num_points]


@pytest.mark.parametrize("num_points", [10, 1000])  # stops mid-batch; stops at the 4x batch cap
def test_reconstruct_points_equals_the_straightforward_render(num_points):
    model, obs = _setup()
    expected = _straightforward(model, obs, num_points, 64, torch.Generator().manual_seed(3))
    points = reconstruct_points(model, obs, num_points, 64, torch.Generator().manual_seed(3))
    assert 0 < len(expected) <= num_points and (len(expected) == num_points) == (num_points == 10)
    assert np.array_equal(points, expected)
