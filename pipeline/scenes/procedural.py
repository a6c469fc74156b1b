"""Procedural coloured meshes: the embedded ``default`` object and the paper-scene proxies (PROTOCOL.md 2.2).

Every mesh is a deterministic (fixed-seed) union of simple coloured parts (per-face colours, Z-up,
floor at z = 0 before fitting). Each proxy keeps what makes its paper scene hard for active mapping:

- lego: many occluding parts, a hollow cab with a seat inside, a concave blade;
- ficus: thin branches and a dense canopy of small leaves above a hollow pot;
- mic: a thin stand and boom carrying one bulky head;
- ship: a wavy water plane hiding the lower hull, thin masts and rigging, sails;
- drums: thin cymbal discs that vanish edge-on, thin stands, drum shells;
- chair: an open frame (slatted back, stretchers) with a cavity under the seat;
- materials: coloured spheres on a flat slab.

``fit_into_box`` fits a proxy uniformly into a tight box: centred in x and y, floor at ``z_min``.
"""

import math
from collections.abc import Callable, Sequence

import numpy as np
import trimesh
from jaxtyping import Float
from trimesh.visual import ColorVisuals

Vec = Sequence[float | int] | np.ndarray  # a point or vector; beartype rejects ints as floats

Color = tuple[int, int, int]
_Z = np.array([0.0, 0.0, 1.0])


def _face_colors(mesh: trimesh.Trimesh) -> ColorVisuals:
    """The colours of a mesh built here: trimesh gives every new mesh ``ColorVisuals``."""
    assert isinstance(mesh.visual, ColorVisuals), f"a procedural mesh with {type(mesh.visual).__name__}"
    return mesh.visual


def _paint(mesh: trimesh.Trimesh, color: Color) -> trimesh.Trimesh:
    _face_colors(mesh).face_colors = np.array([*color, 255], dtype=np.uint8)
    return mesh


def _box(lo: Vec, hi: Vec, color: Color) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return _paint(trimesh.creation.box(bounds=np.stack([lo, hi])), color)


def _rod(p0: Vec, p1: Vec, radius: float, color: Color, sections: int = 8) -> trimesh.Trimesh:
    return _paint(trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], float), sections=sections), color)


def _sphere(center: Vec, radius: float, color: Color, subdivisions: int = 2) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(center)
    return _paint(mesh, color)


def _revolved(
    profile: Sequence[Vec],
    color: Color,
    sections: int = 32,
    angle: float = 2 * math.pi,
    transform: np.ndarray | None = None,
) -> trimesh.Trimesh:
    """Surface of revolution of an ``(r, z)`` polyline about +z, then ``transform``."""
    mesh = trimesh.creation.revolve(np.asarray(profile, float), angle=angle, sections=sections)
    if transform is not None:
        mesh.apply_transform(transform)
    return _paint(mesh, color)


def _recolor(mesh: trimesh.Trimesh, select: np.ndarray, color: Color) -> trimesh.Trimesh:
    """Repaint the faces ``select`` (bool per face)."""
    visual = _face_colors(mesh)
    colors = visual.face_colors.copy()
    colors[select] = [*color, 255]
    visual.face_colors = colors
    return mesh


def _pose(rotation_axis: Vec, angle: float, translation: Vec) -> np.ndarray:
    matrix = trimesh.transformations.rotation_matrix(angle, rotation_axis)
    matrix[:3, 3] = translation
    return matrix


def _assemble(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    mesh = trimesh.util.concatenate(parts)
    assert isinstance(mesh, trimesh.Trimesh), "triangle meshes concatenate to one"
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])  # floor at z = 0
    return mesh


def fit_into_box(mesh: trimesh.Trimesh, box: Float[np.ndarray, "2 3"]) -> trimesh.Trimesh:
    """Uniform scale ``min_k(box_extent_k / mesh_extent_k)``, centred in x and y, floor at ``box[0, 2]`` (PROTOCOL "
    "2.2)."""
    extent = mesh.bounds[1] - mesh.bounds[0]
    scale = float(np.min((box[1] - box[0]) / extent))
    fitted = mesh.copy()
    fitted.apply_scale(scale)
    lo, hi = fitted.bounds
    centre = (box[0] + box[1]) / 2.0
    fitted.apply_translation([centre[0] - (lo[0] + hi[0]) / 2.0, centre[1] - (lo[1] + hi[1]) / 2.0, box[0, 2] - lo[2]])
    return fitted


def default_object() -> trimesh.Trimesh:
    """Embedded scene: a mug with a handle, an arch hiding a ball, and a bowl on a plate (about 1.6 x 1.6 x 0.7)."""
    plate = _box((-0.8, -0.8, 0.0), (0.8, 0.8, 0.05), (150, 150, 150))
    mug_profile = [(0.0, 0.05), (0.25, 0.05), (0.25, 0.62), (0.21, 0.62), (0.21, 0.09), (0.0, 0.09)]
    mug = _revolved(mug_profile, (200, 40, 40), transform=_pose(_Z, 0.0, (-0.35, 0.3, 0.0)))
    centroid_r = np.linalg.norm(mug.triangles_center[:, :2] - [-0.35, 0.3], axis=1)
    mug = _recolor(mug, (centroid_r < 0.23) & (mug.triangles_center[:, 2] > 0.08), (240, 225, 180))
    handle = trimesh.creation.torus(0.14, 0.03, major_sections=24, minor_sections=8)
    handle.apply_transform(_pose((1, 0, 0), math.pi / 2, (-0.6, 0.3, 0.34)))
    handle.update_faces(handle.triangles_center[:, 0] < -0.58)
    handle.remove_unreferenced_vertices()
    handle = _paint(handle, (200, 40, 40))
    # arch: half of a rectangular ring about the y axis, on two pillars; a ball sits under it
    arch_top = _revolved(
        [(0.2, -0.1), (0.3, -0.1), (0.3, 0.1), (0.2, 0.1), (0.2, -0.1)],
        (40, 80, 200),
        sections=16,
        angle=math.pi,
        transform=_pose((1, 0, 0), math.pi / 2, (0.35, -0.3, 0.3)),
    )
    pillars = [
        _box((0.35 + s * 0.25 - 0.05, -0.4, 0.05), (0.35 + s * 0.25 + 0.05, -0.2, 0.3), (40, 80, 200))
        for s in (-1.0, 1.0)
    ]
    ball = _sphere((0.35, -0.3, 0.15), 0.1, (240, 200, 30))
    bowl = _revolved(
        [(0.0, 0.05), (0.12, 0.05), (0.28, 0.3), (0.25, 0.3), (0.1, 0.08), (0.0, 0.08)],
        (40, 160, 70),
        sections=28,
        transform=_pose(_Z, 0.0, (0.35, 0.4, 0.0)),
    )
    inner = (bowl.triangles_center[:, 2] > 0.06) & (
        np.einsum("ij,ij->i", bowl.face_normals[:, :2], bowl.triangles_center[:, :2] - [0.35, 0.4]) < 0
    )
    bowl = _recolor(bowl, inner, (240, 240, 160))
    block = _box((-0.7, -0.65, 0.05), (-0.15, -0.5, 0.45), (120, 60, 160))
    return _assemble([plate, mug, handle, arch_top, *pillars, ball, bowl, block])


def _lego() -> trimesh.Trimesh:
    """Bulldozer: tracks with wheels, body, hollow cab with a seat, engine with studs, arms and a concave blade."""
    yellow, grey, dark, red = (235, 190, 20), (90, 90, 95), (40, 40, 45), (200, 40, 30)
    parts = [_box((s * 0.6 - 0.13, -0.9, 0.0), (s * 0.6 + 0.13, 0.7, 0.3), dark) for s in (-1, 1)]
    for s in (-1, 1):
        for y in (-0.75, -0.4, -0.05, 0.3, 0.55):
            parts.append(_rod((s * 0.72, y, 0.15), (s * 0.76, y, 0.15), 0.11, grey, sections=12))
    parts.append(_box((-0.45, -0.85, 0.3), (0.45, 0.55, 0.6), yellow))
    # hollow cab: four posts, a back wall, a roof, a seat and a control stick inside
    posts = [(-0.38, -0.55), (0.38, -0.55), (-0.38, 0.02), (0.38, 0.02)]
    parts += [_box((x - 0.03, y - 0.03, 0.6), (x + 0.03, y + 0.03, 1.15), yellow) for x, y in posts]
    parts.append(_box((-0.38, -0.6, 0.6), (0.38, -0.55, 1.1), yellow))
    parts.append(_box((-0.42, -0.6, 1.15), (0.42, 0.06, 1.2), red))
    parts.append(_box((-0.15, -0.5, 0.6), (0.15, -0.25, 0.75), dark))
    parts.append(_box((-0.15, -0.55, 0.75), (0.15, -0.5, 0.95), dark))
    parts.append(_rod((0.0, -0.1, 0.6), (0.0, -0.1, 0.85), 0.02, red))
    # engine at the rear with studs and an exhaust
    parts.append(_box((-0.4, -0.9, 0.6), (0.4, -0.65, 0.8), grey))
    parts += [
        _rod((x, y, 0.8), (x, y, 0.84), 0.04, grey, sections=12) for x in (-0.24, 0.0, 0.24) for y in (-0.84, -0.72)
    ]
    parts.append(_rod((0.3, -0.78, 0.8), (0.3, -0.78, 1.1), 0.035, dark))
    # arms and the concave blade (a curved shell opening forward, +y)
    parts += [_box((s * 0.35 - 0.04, 0.5, 0.3), (s * 0.35 + 0.04, 0.95, 0.38), yellow) for s in (-1, 1)]
    parts.append(_rod((-0.35, 0.55, 0.45), (-0.35, 0.9, 0.4), 0.03, grey))
    parts.append(_rod((0.35, 0.55, 0.45), (0.35, 0.9, 0.4), 0.03, grey))
    blade = _revolved(
        [(0.4, -0.6), (0.43, -0.6), (0.43, 0.6), (0.4, 0.6), (0.4, -0.6)], yellow, sections=14, angle=math.radians(110)
    )
    blade.apply_transform(_pose(_Z, math.radians(-145), (0, 0, 0)))
    blade.apply_transform(_pose((0, 1, 0), math.pi / 2, (0.0, 1.35, 0.32)))
    parts.append(blade)
    return _assemble(parts)


def _ficus(rng: np.random.Generator) -> trimesh.Trimesh:
    """Potted plant: hollow pot, soil, thin trunk and branches, a dense canopy of small two-sided leaves."""
    pot = _revolved([(0.0, 0.0), (0.17, 0.0), (0.23, 0.42), (0.21, 0.42), (0.155, 0.03), (0.0, 0.03)], (190, 90, 50))
    soil = _revolved([(0.0, 0.36), (0.215, 0.36), (0.0, 0.36)], (70, 45, 25))
    trunk = [
        _rod((0, 0, 0.35), (0.02, -0.05, 0.9), 0.025, (110, 80, 50)),
        _rod((0.02, -0.05, 0.9), (0.0, -0.1, 1.35), 0.018, (110, 80, 50)),
    ]
    parts = [pot, soil, *trunk]
    n_branches, leaves_per_branch = 16, 45
    for _ in range(n_branches):
        z0 = rng.uniform(0.8, 1.35)
        base = np.array([0.01, -0.05 - 0.05 * (z0 - 0.9) / 0.45, z0])
        direction = np.array([rng.normal() * 0.55, rng.normal() * 0.9, rng.uniform(0.3, 1.0)])
        tip = base + 0.4 * direction / np.linalg.norm(direction) * rng.uniform(0.7, 1.3)
        parts.append(_rod(base, tip, 0.006, (100, 75, 45), sections=5))
        centres = tip + rng.normal(size=(leaves_per_branch, 3)) * [0.08, 0.11, 0.1]
        for c in centres:
            u, v = rng.normal(size=3), rng.normal(size=3)
            u /= np.linalg.norm(u)
            v -= u * (u @ v)
            v /= np.linalg.norm(v)
            a, b = 0.045 * u, 0.02 * v
            quad = trimesh.Trimesh(
                np.array([c - a, c + b, c + a, c - b]), np.array([[0, 1, 2], [0, 2, 3]]), process=False
            )
            green = (int(rng.integers(30, 70)), int(rng.integers(110, 170)), int(rng.integers(30, 60)))
            parts.append(_paint(quad, green))
    return _assemble(parts)


def _mic() -> trimesh.Trimesh:
    """Microphone on a stand: round base, thin pole, thin boom with a counterweight, one bulky head."""
    black, silver, dark = (30, 30, 30), (190, 190, 200), (60, 60, 70)
    base = _revolved(
        [(0.0, 0.0), (0.35, 0.0), (0.33, 0.06), (0.0, 0.06)], black, transform=_pose(_Z, 0.0, (0.55, -0.5, 0))
    )
    pole = _rod((0.55, -0.5, 0.06), (0.55, -0.5, 1.0), 0.018, silver)
    joint = _sphere((0.55, -0.5, 1.0), 0.04, black, subdivisions=1)
    boom = _rod((0.95, -0.85, 0.8), (-0.45, 0.4, 1.4), 0.014, silver)
    weight = _rod((0.9, -0.8, 0.82), (1.0, -0.89, 0.78), 0.06, black, sections=16)
    axis = np.array([-1.4, 1.25, 0.6]) / np.linalg.norm([-1.4, 1.25, 0.6])
    head = trimesh.creation.capsule(height=0.35, radius=0.2, count=[16, 16])
    head.apply_transform(trimesh.geometry.align_vectors(_Z, axis))
    head.apply_translation(np.array([-0.45, 0.4, 1.4]) + axis * 0.32)
    head = _paint(head, silver)
    band_pos = np.array([-0.45, 0.4, 1.4]) + axis * 0.3
    band = trimesh.creation.torus(0.2, 0.025, major_sections=24, minor_sections=6)
    band.apply_transform(trimesh.geometry.align_vectors(_Z, axis))
    band.apply_translation(band_pos)
    clip = _rod(np.array([-0.45, 0.4, 1.4]), band_pos, 0.05, dark)
    return _assemble([base, pole, joint, boom, weight, head, _paint(band, dark), clip])


def _ship(rng: np.random.Generator) -> trimesh.Trimesh:
    """Sailing ship on a wavy water plane: hull partly below water, three masts, yards, sails and thin rigging."""
    n = 41
    xs = np.linspace(-1.3, 1.3, n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    gz = 0.45 + 0.015 * np.sin(6 * gx + rng.uniform(0, 6)) * np.cos(5 * gy + rng.uniform(0, 6))
    idx = np.arange(n * n).reshape(n, n)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    water = trimesh.Trimesh(np.stack([gx, gy, gz], -1).reshape(-1, 3), faces, process=False)
    water = _paint(water, (40, 90, 160))
    water = _recolor(water, water.triangles_center[:, 2] > 0.455, (70, 130, 190))
    # hull along the diagonal: convex hull of a deck outline (z = 0.7) and a narrower keel (z = 0)
    t = np.linspace(-1.0, 1.0, 9)
    half_width = 0.28 * np.sqrt(np.clip(1 - t**2, 0.0, None)) + 0.04
    deck = np.concatenate([np.stack([0.95 * t, s * half_width, np.full_like(t, 0.7)], -1) for s in (-1, 1)])
    keel = np.concatenate([np.stack([0.8 * t, s * 0.4 * half_width, np.zeros_like(t)], -1) for s in (-1, 1)])
    hull = trimesh.convex.convex_hull(np.concatenate([deck, keel]))
    rot = _pose(_Z, math.pi / 4, (0, 0, 0))
    hull.apply_transform(rot)
    hull = _paint(hull, (120, 70, 35))
    hull = _recolor(hull, hull.triangles_center[:, 2] > 0.69, (200, 160, 100))
    along = rot[:3, :3] @ np.array([1.0, 0.0, 0.0])
    across = rot[:3, :3] @ np.array([0.0, 1.0, 0.0])
    parts = [water, hull]
    cabin_c = -0.65 * along
    parts.append(
        _paint(
            trimesh.creation.box(extents=(0.3, 0.3, 0.16), transform=_pose(_Z, math.pi / 4, cabin_c + [0, 0, 0.78])),
            (150, 90, 40),
        )
    )
    tops, feet = [], []
    for offset, height in ((-0.45, 1.1), (0.05, 1.25), (0.55, 1.05)):
        foot = offset * along + [0, 0, 0.7]
        top = offset * along + [0, 0, height]
        tops.append(top)
        feet.append(foot)
        parts.append(_rod(foot, top, 0.015, (90, 60, 30)))
        for frac, width in ((0.45, 0.35), (0.8, 0.25)):
            z = foot[2] + frac * (height - 0.7)
            centre = offset * along + [0, 0, z]
            parts.append(_rod(centre - width * across, centre + width * across, 0.008, (90, 60, 30), sections=6))
        low, high = foot[2] + 0.45 * (height - 0.7) - 0.02, foot[2] + 0.8 * (height - 0.7)
        corners = np.array(
            [
                offset * along - 0.3 * across + [0, 0, low + 0.02],
                offset * along + 0.3 * across + [0, 0, low + 0.02],
                offset * along + 0.22 * across + [0, 0, high],
                offset * along - 0.22 * across + [0, 0, high],
            ]
        )
        corners[2:] += 0.04 * np.cross(across, _Z)  # the upper edge bulges: the sail is not planar
        sail = trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False)
        parts.append(_paint(sail, (235, 230, 210)))
    bow, stern = 1.0 * along + [0, 0, 0.72], -0.95 * along + [0, 0, 0.72]
    parts.append(_rod(bow, bow + 0.35 * along + [0, 0, 0.15], 0.01, (90, 60, 30)))
    anchors = [bow + 0.35 * along + [0, 0, 0.15], stern]
    for i, (top, foot) in enumerate(zip(tops, feet, strict=True)):
        for side in (-1, 1):  # shrouds to the deck edge beside the mast
            parts.append(_rod(top, foot + side * 0.27 * across + [0, 0, 0.02], 0.004, (40, 30, 20), sections=4))
        target = anchors[0] if i == len(tops) - 1 else tops[i + 1]
        parts.append(_rod(top, target, 0.004, (40, 30, 20), sections=4))
    parts.append(_rod(tops[0], anchors[1], 0.004, (40, 30, 20), sections=4))
    return _assemble(parts)


def _drum(centre: Vec, axis: Vec, radius: float, depth: float, shell: Color) -> trimesh.Trimesh:
    """A cylinder with white heads (faces facing along the axis) and a coloured shell."""
    unit = np.asarray(axis, float) / np.linalg.norm(axis)
    centre = np.asarray(centre, float)
    drum = _rod(centre - unit * depth / 2, centre + unit * depth / 2, radius, shell, sections=24)
    return _recolor(drum, np.abs(drum.face_normals @ unit) > 0.9, (235, 235, 225))


def _cymbal(centre: Vec, radius: float, tilt: float) -> trimesh.Trimesh:
    """A thin, slightly domed bronze disc (about 1/60 of its radius thick), tilted about x."""
    profile = [(0.0, 0.05 * radius), (radius, 0.0), (radius, -0.015 * radius), (0.0, 0.035 * radius)]
    return _revolved(profile, (205, 165, 60), sections=32, transform=_pose((1, 0, 0), tilt, centre))


def _stand(foot: Vec, top: Vec) -> list[trimesh.Trimesh]:
    """A thin pole with a tripod of thin legs."""
    foot, top = np.asarray(foot, float), np.asarray(top, float)
    parts = [_rod(foot + [0, 0, 0.2], top, 0.01, (170, 170, 180), sections=6)]
    for k in range(3):
        angle = 2 * math.pi * k / 3
        parts.append(
            _rod(
                foot + [0, 0, 0.2],
                foot + [0.18 * math.cos(angle), 0.18 * math.sin(angle), 0.0],
                0.008,
                (170, 170, 180),
                sections=6,
            )
        )
    return parts


def _drums() -> trimesh.Trimesh:
    """Drum kit: bass drum, two toms, floor tom, snare, hi-hat and two cymbals on thin stands."""
    red = (170, 25, 35)
    parts = [_drum((0, 0.1, 0.33), (0, 1, 0), 0.33, 0.4, red)]
    parts += [_drum((s * 0.2, 0.05, 0.82), (0, -0.4, 1), 0.15, 0.14, red) for s in (-1, 1)]
    parts.append(_rod((0, 0.1, 0.66), (0, 0.05, 0.76), 0.015, (170, 170, 180)))
    parts.append(_drum((0.65, -0.2, 0.5), (0, 0, 1), 0.22, 0.3, red))
    parts += [
        _rod(
            (0.65 + 0.25 * math.cos(a), -0.2 + 0.25 * math.sin(a), 0.0),
            (0.65 + 0.22 * math.cos(a), -0.2 + 0.22 * math.sin(a), 0.5),
            0.008,
            (170, 170, 180),
            sections=6,
        )
        for a in (0.5, 2.6, 4.7)
    ]
    parts.append(_drum((-0.55, -0.3, 0.6), (0.1, 0, 1), 0.18, 0.12, (220, 220, 225)))
    parts += _stand((-0.55, -0.3, 0.0), (-0.55, -0.3, 0.54))
    parts += _stand((-0.95, 0.05, 0.0), (-0.95, 0.05, 0.9))
    parts += [_cymbal((-0.95, 0.05, 0.9), 0.2, 0.0), _cymbal((-0.95, 0.05, 0.93), 0.2, math.pi)]
    for x, y, z, r, tilt in ((-0.55, 0.45, 1.25, 0.3, 0.25), (0.75, 0.45, 1.35, 0.34, -0.3)):
        parts += _stand((x, y, 0.0), (x, y, z))
        parts.append(_cymbal((x, y, z), r, tilt))
    return _assemble(parts)


def _chair() -> trimesh.Trimesh:
    """Wooden chair: four legs with stretchers (a cavity under the seat), cushion, slatted open back, arms."""
    wood, dark_wood, cushion = (150, 100, 55), (105, 65, 35), (190, 60, 40)
    parts = []
    for x in (-0.55, 0.55):
        for y in (-0.55, 0.55):
            top = 2.0 if y > 0 else 0.9
            parts.append(_box((x - 0.04, y - 0.04, 0.0), (x + 0.04, y + 0.04, top), wood))
    parts.append(_box((-0.62, -0.62, 0.9), (0.62, 0.62, 0.98), wood))
    parts.append(_box((-0.55, -0.55, 0.98), (0.55, 0.5, 1.06), cushion))
    for y in (-0.55, 0.55):
        parts.append(_box((-0.51, y - 0.02, 0.3), (0.51, y + 0.02, 0.35), dark_wood))
    for x in (-0.55, 0.55):
        parts.append(_box((x - 0.02, -0.51, 0.3), (x + 0.02, 0.51, 0.35), dark_wood))
    parts.append(_box((-0.59, 0.51, 1.85), (0.59, 0.59, 1.97), wood))
    parts.append(_box((-0.51, 0.52, 1.1), (0.51, 0.58, 1.15), wood))
    parts += [_box((x - 0.035, 0.53, 1.15), (x + 0.035, 0.57, 1.85), dark_wood) for x in (-0.25, 0.0, 0.25)]
    for x in (-0.6, 0.6):
        parts.append(_box((x - 0.04, -0.6, 1.3), (x + 0.04, 0.55, 1.36), wood))
        parts.append(_box((x - 0.025, -0.55, 0.98), (x + 0.025, -0.5, 1.3), wood))
    return _assemble(parts)


def _materials() -> trimesh.Trimesh:
    """Slab with three rows of five spheres of different colours."""
    parts = [_box((-1.1, -0.85, 0.0), (1.1, 0.85, 0.08), (60, 60, 65))]
    palette = [
        (200, 40, 40),
        (230, 160, 30),
        (240, 240, 240),
        (40, 150, 70),
        (60, 90, 200),
        (150, 150, 160),
        (210, 180, 60),
        (120, 40, 150),
        (20, 20, 20),
        (220, 120, 150),
        (90, 200, 210),
        (180, 90, 40),
        (230, 230, 120),
        (100, 120, 130),
        (170, 210, 90),
    ]
    for i, colour in enumerate(palette):
        row, col = divmod(i, 5)
        parts.append(_sphere((-0.8 + 0.4 * col, -0.5 + 0.5 * row, 0.08 + 0.17), 0.17, colour))
    return _assemble(parts)


_SEED = 20240617
PROXIES: dict[str, Callable[[], trimesh.Trimesh]] = {
    "chair": _chair,
    "drums": _drums,
    "ficus": lambda: _ficus(np.random.default_rng(_SEED)),
    "lego": _lego,
    "materials": _materials,
    "mic": _mic,
    "ship": lambda: _ship(np.random.default_rng(_SEED + 1)),
}


RECIPES: dict[str, Callable[[], trimesh.Trimesh]] = {"default": default_object, **PROXIES}  # a scene's ``recipe``
