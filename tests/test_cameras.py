"""nvf/cameras.py: look-at, pixel-centre rays, quaternion round trips, SE(3) updates (PROTOCOL.md 1)."""

import math

import pytest
import torch

from nvf.cameras import (
    Intrinsics,
    look_at,
    matrix_to_pose,
    matrix_to_quat,
    pixel_rays,
    pose_to_matrix,
    project,
    quat_to_matrix,
    se3_exp,
    se3_update,
)


def test_fov90_focal_is_half_width():
    assert Intrinsics.from_fov(512, 512).focal == pytest.approx(256.0)
    assert Intrinsics.from_fov(300, 300).focal == pytest.approx(150.0)


def test_look_at_points_minus_z_at_target():
    pos, target = torch.tensor([1.0, -2.0, 0.5]), torch.tensor([0.2, 0.3, 0.1])
    c2w = look_at(pos, target)
    forward = -c2w[:3, 2]
    expected = (target - pos) / torch.linalg.norm(target - pos)
    assert torch.allclose(forward, expected, atol=1e-6)
    assert torch.allclose(c2w[:3, :3] @ c2w[:3, :3].T, torch.eye(3), atol=1e-6)
    assert torch.det(c2w[:3, :3]) == pytest.approx(1.0, abs=1e-6)
    assert c2w[2, 1] > 0  # camera y has a positive world-z component (up = +z)


def test_look_at_straight_down_uses_shifted_up():
    c2w = look_at(torch.tensor([0.0, 0.0, 1.2]), torch.zeros(3))
    assert torch.isfinite(c2w).all()
    assert torch.allclose(-c2w[:3, 2], torch.tensor([0.0, 0.0, -1.0]), atol=1e-6)


def test_pixel_rays_go_through_pixel_centres():
    intr = Intrinsics.from_fov(4, 2)
    c2w = look_at(torch.tensor([0.0, -3.0, 0.0]), torch.zeros(3))
    origins, dirs = pixel_rays(c2w, intr)
    assert origins.shape == (8, 3) and dirs.shape == (8, 3)
    assert torch.allclose(torch.linalg.norm(dirs, dim=-1), torch.ones(8), atol=1e-6)
    uv, depth = project(origins + 2.0 * dirs, c2w, intr)
    expected_u = torch.tensor([0.5, 1.5, 2.5, 3.5] * 2)
    expected_v = torch.tensor([0.5] * 4 + [1.5] * 4)
    assert torch.allclose(uv[:, 0], expected_u, atol=1e-4)
    assert torch.allclose(uv[:, 1], expected_v, atol=1e-4)
    assert (depth > 0).all()
    # row 0 is the top of the image: its rays point up (+z world here)
    assert (dirs[:4, 2] > 0).all() and (dirs[4:, 2] < 0).all()


def test_quaternion_round_trip():
    q = torch.randn(500, 4, dtype=torch.float64)
    q = q / torch.linalg.norm(q, dim=-1, keepdim=True)
    rot = quat_to_matrix(q)
    assert torch.allclose(rot @ rot.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(500, 3, 3), atol=1e-9)
    q2 = matrix_to_quat(rot)
    assert torch.allclose(q2, torch.where(q[:, 3:] < 0, -q, q), atol=1e-9)


def test_pose_vector_round_trip():
    c2w = look_at(torch.tensor([0.7, 2.0, 2.35]), torch.tensor([-2.0, 2.0, 0.35]))
    assert torch.allclose(pose_to_matrix(matrix_to_pose(c2w)), c2w, atol=1e-5)


def test_se3_exp_matches_rotation_and_identity():
    assert torch.allclose(se3_exp(torch.zeros(6)), torch.eye(4))
    angle = 0.3
    xi = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, angle])
    rot = se3_exp(xi)[:3, :3]
    expected = torch.tensor(
        [[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0], [0.0, 0.0, 1.0]]
    )
    assert torch.allclose(rot, expected, atol=1e-6)
    # a pure translation twist moves the camera centre by rho
    c2w = look_at(torch.tensor([1.0, 1.0, 1.0]), torch.zeros(3))
    moved = se3_update(c2w, torch.tensor([0.1, -0.2, 0.3, 0.0, 0.0, 0.0]))
    assert torch.allclose(moved[:3, 3], c2w[:3, 3] + torch.tensor([0.1, -0.2, 0.3]), atol=1e-6)


def test_rays_are_differentiable_wrt_pose():
    pose = matrix_to_pose(look_at(torch.tensor([1.0, 1.0, 1.0]), torch.zeros(3))).requires_grad_(True)
    origins, dirs = pixel_rays(pose_to_matrix(pose), Intrinsics.from_fov(3, 3))
    (origins + dirs).sum().backward()
    assert pose.grad is not None and torch.isfinite(pose.grad).all() and pose.grad.abs().sum() > 0
    xi = torch.zeros(6, requires_grad=True)
    _, d2 = pixel_rays(se3_update(pose_to_matrix(pose.detach()), xi), Intrinsics.from_fov(3, 3))
    d2[:, 0].sum().backward()
    assert torch.isfinite(xi.grad).all() and xi.grad.abs().sum() > 0
