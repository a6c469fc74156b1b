"""How far from the object each method's picked views look: the angle between a picked view's axis (the
camera's -z) and the direction from its centre to the object AABB's centre, over the committed cpu records
(seeds 100-102, 20 picks each). Run from the repository root:
``python scripts/pilots/fvs_pick_angles.py > results/pilots/fvs_pick_angles/angles.txt``."""

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.config.validation import compose_run
from pipeline.scenes.blender import blender_python
from pipeline.scenes.loading import load_scene

METHODS = ("nvf-argmax-none", "fisherrf-argmax-none", "fvs-argmax-none", "random-argmax-none")


def angles(folder: Path, centre: np.ndarray) -> np.ndarray:
    """Degrees [picks] between each picked view's axis and the direction to ``centre``."""
    out = []
    for seed in (100, 101, 102):
        for line in (folder / f"seed_{seed}" / "steps.jsonl").read_text().splitlines():
            pose = np.asarray(json.loads(line)["selected_pose"], float)  # [qx, qy, qz, qw, x, y, z]
            axis = -Rotation.from_quat(pose[:4]).as_matrix()[:, 2]
            to_centre = centre - pose[4:]
            out.append(np.degrees(np.arccos(np.clip(axis @ to_centre / np.linalg.norm(to_centre), -1, 1))))
    return np.array(out)


for scene_name in ("default", "hotdog", "hubble"):
    cfg = compose_run([f"scene={scene_name}", "budget=cpu"])
    scene = load_scene(cfg.scene, Path(cfg.paths.assets), blender_python(cfg.paths.blender_python))
    centre = np.asarray(scene.object_aabb, float).mean(axis=0)
    for method in METHODS:
        a = angles(Path("results/runs") / scene_name / method / "cpu", centre)
        share = np.mean(a > 30)
        print(f"{scene_name:8s} {method:22s} median {np.median(a):5.1f} deg, over 30 deg {share:.2f} ({a.size} picks)")
