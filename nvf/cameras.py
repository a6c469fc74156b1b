"""Pinhole cameras, camera-to-world poses and pixel rays (PROTOCOL.md section 1).

Conventions: world frame Z-up; OpenGL camera axes (x right, y up, z backward, the camera looks
along -z); a pose vector is ``[qx, qy, qz, qw, x, y, z]`` (unit quaternion, scalar last).
Rays go through pixel centres. Everything is differentiable with respect to the pose.
"""

import math
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor


@dataclass(frozen=True)
class Intrinsics:
    """Square-pixel pinhole camera; ``focal`` in pixels, principal point at the image centre."""

    width: int
    height: int
    focal: float

    @staticmethod
    def from_fov(width: int, height: int, fov_deg: float = 90.0) -> "Intrinsics":
        """Horizontal field of view ``fov_deg``; 90 degrees gives ``f = W / 2`` (PROTOCOL.md)."""
        return Intrinsics(width, height, width / (2.0 * math.tan(math.radians(fov_deg) / 2.0)))

    @property
    def num_pixels(self) -> int:
        return self.width * self.height

    def matrix(self) -> Float[Tensor, "3 3"]:
        return torch.tensor(
            [[self.focal, 0.0, self.width / 2.0], [0.0, self.focal, self.height / 2.0], [0.0, 0.0, 1.0]]
        )


def look_at(
    position: Float[Tensor, "3"], target: Float[Tensor, "3"], up: tuple[float, float, float] = (0.0, 0.0, 1.0)
) -> Float[Tensor, "4 4"]:
    """Camera-to-world matrix of a camera at ``position`` looking at ``target`` (PROTOCOL.md 1).

    If ``up`` is parallel to the viewing axis it is first replaced by ``normalise(up + (0.1,0,0))``.
    """
    position = position.to(torch.float64)
    z = position - target.to(torch.float64)
    z = z / torch.linalg.norm(z)
    up_t = torch.tensor(up, dtype=torch.float64)
    x = torch.linalg.cross(up_t, z)
    if torch.linalg.norm(x) < 1e-7:
        up_t = up_t + torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64)
        up_t = up_t / torch.linalg.norm(up_t)
        x = torch.linalg.cross(up_t, z)
    x = x / torch.linalg.norm(x)
    y = torch.linalg.cross(z, x)
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, position
    return c2w.to(torch.float32)


def camera_directions(intrinsics: Intrinsics, device: torch.device | str = "cpu") -> Float[Tensor, "P 3"]:
    """Un-normalised camera-frame directions of every pixel centre, row-major (row v, column u)."""
    v, u = torch.meshgrid(
        torch.arange(intrinsics.height, dtype=torch.float32, device=device),
        torch.arange(intrinsics.width, dtype=torch.float32, device=device),
        indexing="ij",
    )
    f = intrinsics.focal
    dirs = torch.stack(
        [(u + 0.5 - intrinsics.width / 2.0) / f, -(v + 0.5 - intrinsics.height / 2.0) / f, -torch.ones_like(u)],
        dim=-1,
    )
    return dirs.reshape(-1, 3)


def rays_from_camera_dirs(
    c2w: Float[Tensor, "*B 4 4"], cam_dirs: Float[Tensor, "P 3"]
) -> tuple[Float[Tensor, "*B P 3"], Float[Tensor, "*B P 3"]]:
    """World-frame ray origins and unit directions for camera-frame directions ``cam_dirs``."""
    rot = c2w[..., :3, :3]
    dirs = torch.einsum("...ij,pj->...pi", rot, cam_dirs)
    dirs = dirs / torch.linalg.norm(dirs, dim=-1, keepdim=True)
    origins = c2w[..., None, :3, 3].expand_as(dirs)
    return origins, dirs


def pixel_rays(
    c2w: Float[Tensor, "*B 4 4"], intrinsics: Intrinsics
) -> tuple[Float[Tensor, "*B P 3"], Float[Tensor, "*B P 3"]]:
    """Rays through every pixel centre of a ``H x W`` image, row-major (``P = H * W``)."""
    return rays_from_camera_dirs(c2w, camera_directions(intrinsics, c2w.device))


def project(
    points: Float[Tensor, "N 3"], c2w: Float[Tensor, "4 4"], intrinsics: Intrinsics
) -> tuple[Float[Tensor, "N 2"], Float[Tensor, " N"]]:
    """Pixel coordinates ``(u, v)`` (continuous, top-left origin) and camera depth (> 0 in front)."""
    rot, pos = c2w[:3, :3], c2w[:3, 3]
    cam = (points - pos) @ rot  # world -> camera: R^T (x - p)
    depth = -cam[:, 2]
    safe = torch.where(depth.abs() > 1e-12, depth, torch.full_like(depth, 1e-12))
    u = intrinsics.focal * cam[:, 0] / safe + intrinsics.width / 2.0
    v = -intrinsics.focal * cam[:, 1] / safe + intrinsics.height / 2.0
    return torch.stack([u, v], dim=-1), depth


def quat_to_matrix(quat: Float[Tensor, "*B 4"]) -> Float[Tensor, "*B 3 3"]:
    """Rotation matrix of a scalar-last quaternion ``[qx, qy, qz, qw]``.

    The quaternion is used as given (not re-normalised), as the -OPT raw parameterisation expects
    (METHOD.md section 14); for a unit quaternion this is the usual rotation.
    """
    x, y, z, w = quat.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - z * w),
        2 * (x * z + y * w),
        2 * (x * y + z * w),
        1 - 2 * (x * x + z * z),
        2 * (y * z - x * w),
        2 * (x * z - y * w),
        2 * (y * z + x * w),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(*quat.shape[:-1], 3, 3)


def matrix_to_quat(rot: Float[Tensor, "*B 3 3"]) -> Float[Tensor, "*B 4"]:
    """Scalar-last unit quaternion (with ``qw >= 0``) of a rotation matrix (Shepperd's method)."""
    m = rot
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    candidates = torch.stack(
        [
            torch.stack(
                [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1], 1 + trace], -1
            ),
            torch.stack(
                [
                    1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 2, 1] - m[..., 1, 2],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                    m[..., 1, 2] + m[..., 2, 1],
                    m[..., 0, 2] - m[..., 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
        ],
        dim=-2,
    )  # [*B, 4, 4]: each row is 4*q*q_k for the k-th largest pivot
    pivots = torch.stack([trace, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = pivots.argmax(-1)
    q = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = q / torch.linalg.norm(q, dim=-1, keepdim=True)
    return torch.where(q[..., 3:4] < 0, -q, q)


def pose_to_matrix(pose: Float[Tensor, "*B 7"]) -> Float[Tensor, "*B 4 4"]:
    """Camera-to-world matrix of a pose vector ``[qx, qy, qz, qw, x, y, z]``."""
    c2w = torch.zeros(*pose.shape[:-1], 4, 4, dtype=pose.dtype, device=pose.device)
    c2w[..., :3, :3] = quat_to_matrix(pose[..., :4])
    c2w[..., :3, 3] = pose[..., 4:]
    c2w[..., 3, 3] = 1.0
    return c2w


def matrix_to_pose(c2w: Float[Tensor, "*B 4 4"]) -> Float[Tensor, "*B 7"]:
    """Pose vector ``[qx, qy, qz, qw, x, y, z]`` of a camera-to-world matrix."""
    return torch.cat([matrix_to_quat(c2w[..., :3, :3]), c2w[..., :3, 3]], dim=-1)


def skew(v: Float[Tensor, "*B 3"]) -> Float[Tensor, "*B 3 3"]:
    """Cross-product matrix ``[v]_x``."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v.unbind(-1)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*v.shape[:-1], 3, 3)


def se3_exp(xi: Float[Tensor, "*B 6"]) -> Float[Tensor, "*B 4 4"]:
    """Exponential map of a twist ``xi = [rho (translation), phi (rotation)]`` to an SE(3) matrix.

    Closed-form Rodrigues formulas with a Taylor fallback near ``phi = 0`` so gradients stay finite.
    """
    rho, phi = xi[..., :3], xi[..., 3:]
    theta2 = (phi * phi).sum(-1, keepdim=True)[..., None]  # [*B,1,1]
    small = theta2 < 1e-8
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(theta2_safe)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2_safe)
    c = torch.where(small, 1.0 / 6 - theta2 / 120, (theta - torch.sin(theta)) / (theta2_safe * theta))
    k = skew(phi)
    k2 = k @ k
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device).expand_as(k)
    rot = eye + a * k + b * k2
    v = eye + b * k + c * k2
    out = torch.zeros(*xi.shape[:-1], 4, 4, dtype=xi.dtype, device=xi.device)
    out[..., :3, :3] = rot
    out[..., :3, 3] = (v @ rho[..., None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def se3_update(c2w: Float[Tensor, "*B 4 4"], xi: Float[Tensor, "*B 6"]) -> Float[Tensor, "*B 4 4"]:
    """Left-multiplicative tangent update ``exp(xi) @ c2w`` (the -OPT ``se3`` parameterisation)."""
    return se3_exp(xi) @ c2w
