"""View rigs (PROTOCOL.md 2.3-2.5): a scene's initial and evaluation cameras, built from the rig its yaml
declares (``conf/scene/<name>.yaml``, ``init_views`` and ``eval_views``). All cameras are c2w matrices with
OpenGL axes, looking at their target with up +z unless the rig says otherwise.

Rigs (the keys each takes):

- ``ring``: ``centre`` P0, ``centre_target`` (where P0 looks), ``radius`` r, ``angles`` theta_i (degrees),
  ``targets`` (one per angle); view i sits at ``P0 (r cos theta_i, r sin theta_i, 0, 1)^T`` and looks at
  ``targets[i]``; ``centre_is_view: true`` puts P0 itself first (Room).
- ``orbit``: ``centre`` c, ``semi_axes`` a, ``target``, ``angles`` as ``[theta, phi]`` pairs (degrees, phi
  from +z): views at ``c + a * dir(theta, phi)`` looking at ``target``, then ``extra`` ``[position, target]`` pairs.
- ``straight_down``: ``circles`` of ``{centre: [x, y], radius, count, z}``: ``count`` cameras at angles
  ``360 i / count`` on each circle, each the translation times ``R_z(theta)`` (looking straight down).
- ``rule``: PROTOCOL 2.5's Lego analogy from the scene's tight box (3 initial views, 20 evaluation views).
"""

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import look_at

Vec = Sequence[float | int] | np.ndarray  # a point or vector; beartype rejects ints as floats
RIGS = ("ring", "orbit", "straight_down", "rule")


def _look(position: Vec, target: Vec) -> Float[Tensor, "4 4"]:
    return look_at(torch.tensor(position, dtype=torch.float64), torch.tensor(target, dtype=torch.float64))


def direction(theta_deg: float | int, phi_deg: float | int) -> np.ndarray:
    """``dir(theta, phi) = (sin phi cos theta, sin phi sin theta, cos phi)``, phi from +z (PROTOCOL 2.4)."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(p) * math.cos(t), math.sin(p) * math.sin(t), math.cos(p)])


def ring_views(
    centre: Vec,
    centre_target: Vec,
    radius: float,
    thetas_deg: Vec,
    targets: Sequence[Vec],
) -> Float[Tensor, "n 4 4"]:
    """Views at ``P0 (r cos theta_i, r sin theta_i, 0, 1)^T`` looking at ``targets[i]`` (PROTOCOL 2.3)."""
    p0 = _look(centre, centre_target).to(torch.float64)
    poses = []
    for theta, target in zip(thetas_deg, targets, strict=True):
        t = math.radians(theta)
        offset = torch.tensor([radius * math.cos(t), radius * math.sin(t), 0.0, 1.0], dtype=torch.float64)
        poses.append(_look((p0 @ offset)[:3].tolist(), target))
    return torch.stack(poses)


def orbit_views(
    centre: Vec, semi_axes: Vec, target: Vec, angles: Sequence[Vec], extra: Sequence[Sequence[Vec]] = ()
) -> Float[Tensor, "n 4 4"]:
    """Views at ``centre + semi_axes * dir(theta, phi)`` looking at ``target``, then the ``extra``
    ``(position, target)`` views (PROTOCOL 2.4)."""
    c, a = np.asarray(centre, float), np.asarray(semi_axes, float)
    poses = [_look(c + a * direction(theta, phi), target) for theta, phi in angles]
    return torch.stack([*poses, *(_look(position, look) for position, look in extra)])


def straight_down(x: float, y: float, z: float, theta_deg: float) -> Float[Tensor, "4 4"]:
    """Translation times ``R_z(theta)``: camera x axis (cos, sin, 0), camera z axis +z (PROTOCOL 2.4 Room)."""
    t = math.radians(theta_deg)
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:2, :2] = torch.tensor([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]], dtype=torch.float64)
    c2w[:3, 3] = torch.tensor([x, y, z], dtype=torch.float64)
    return c2w.to(torch.float32)


def straight_down_views(circles: Sequence[Mapping[str, Any]]) -> Float[Tensor, "n 4 4"]:
    """``count`` cameras looking straight down on each circle, at angles ``360 i / count``."""
    poses = []
    for circle in circles:
        (cx, cy), r, z = circle["centre"], float(circle["radius"]), float(circle["z"])
        for t in (math.radians(360.0 / circle["count"] * i) for i in range(circle["count"])):
            poses.append(straight_down(r * math.cos(t) + cx, r * math.sin(t) + cy, z, math.degrees(t)))
    return torch.stack(poses)


def lego_layout(centre: Vec, semi_axes: Vec, target: Vec, top: Vec, top_target: Vec) -> Float[Tensor, "20 4 4"]:
    """Lego's 20 evaluation views: phi = 30 (4), 60 (6), 90 (9) deg rings at ``centre + a * dir``, then a top view."""
    angles = [(90.0 * j, 30.0) for j in range(4)] + [(60.0 * j, 60.0) for j in range(6)]
    angles += [(40.0 * j, 90.0) for j in range(9)]
    return orbit_views(centre, semi_axes, target, angles, [(top, top_target)])


def _r05(x: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(x) / 0.05) * 0.05


def _ceil05(x: np.ndarray) -> np.ndarray:
    return np.ceil(np.asarray(x) / 0.05 - 1e-6) * 0.05


def rule_parameters(tight_box: Float[np.ndarray, "2 3"]) -> dict[str, np.ndarray]:
    """PROTOCOL 2.5 rule: target ``t``, semi-axes ``a``, ``top`` view, centre ``P0`` and ring targets ``z``."""
    lo, hi = tight_box
    c, h = (lo + hi) / 2.0, (hi - lo) / 2.0
    return {
        "t": _r05(c),
        "a": _ceil05(h + np.array([0.85, 0.85, 1.0])),
        "top": _r05(np.array([c[0], c[1], hi[2] + 0.7])),
        "P0": _r05(np.array([c[0], c[1] + h[1] + 1.05, c[2]])),
        "z": _r05(lo[2] + np.array([0.04, 0.375, 0.71]) * 2.0 * h[2]),
    }


def rule_views(tight_box: Float[np.ndarray, "2 3"]) -> tuple[Float[Tensor, "3 4 4"], Float[Tensor, "20 4 4"]]:
    """Initial and evaluation views by analogy with Lego from a tight box (PROTOCOL 2.5)."""
    p = rule_parameters(tight_box)
    t = p["t"]
    init = ring_views(p["P0"], t, 0.3, (0, 120, 240), [(t[0], t[1], z) for z in p["z"]])
    return init, lego_layout(t, p["a"], t, p["top"], t)


def rig_views(rig: Mapping[str, Any], tight_box: Float[np.ndarray, "2 3"], initial: bool) -> Float[Tensor, "n 4 4"]:
    """The cameras of one declared rig (module docstring); ``initial`` picks the rule's initial or
    evaluation set. Raises KeyError / ValueError for a rig that lacks a key or names no known rig."""
    kind = rig.get("rig")
    if kind == "rule":
        return rule_views(tight_box)[0 if initial else 1]
    if kind == "ring":
        views = ring_views(rig["centre"], rig["centre_target"], float(rig["radius"]), rig["angles"], rig["targets"])
        if rig.get("centre_is_view", False):
            views = torch.cat([_look(rig["centre"], rig["centre_target"])[None], views])
        return views
    if kind == "orbit":
        return orbit_views(rig["centre"], rig["semi_axes"], rig["target"], rig["angles"], rig.get("extra", ()))
    if kind == "straight_down":
        return straight_down_views(rig["circles"])
    raise ValueError(f"rig {kind!r} is not one of {', '.join(RIGS)}")
