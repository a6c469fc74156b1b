"""A method or a scene is declared once: a new one added from a temporary config directory (one yaml; a
method class here; a mesh the test writes) runs through a smoke episode and reaches the tables without
touching any other file of the repository."""

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
import trimesh
from jaxtyping import Float, Int
from torch import Tensor

from nvf.config import BaselineConfig, EntropyConfig
from nvf.methods import Method
from nvf.model import RenderResult
from pipeline.config.validation import compose_config
from pipeline.episode.runner import Outcome, run_episode
from pipeline.tables.build import build_tables


@dataclass(frozen=True)
class OpacityScorer:
    """A toy per-ray score: the ray's accumulated opacity (views that see the most surface win)."""

    name: ClassVar[str] = "toy"
    heads: ClassVar[frozenset[str]] = frozenset()
    sampler: ClassVar[str] = "occupancy"

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, "R"] | None = None) -> Float[Tensor, "R"]:
        return result.acc


class Toy(Method):
    """A toy method: the most opaque view next."""

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> OpacityScorer:
        return OpacityScorer()


TOY_METHOD = """name: toy
label: Toy method
rank: 50
implementation: test_declared.Toy
stages: [backbone]
"""

TOY_SCENE = """name: toy_box
kind: object
source: mesh
paper_scene: null
nerf_asset: false
rank: 30
files: []
object_aabb: [[-0.6, -0.6, -0.1], [0.6, 0.6, 0.9]]
camera_box: [[-1.5, -1.5, -0.1], [1.5, 1.5, 2.4]]
tight_box: [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.8]]
init_views: {rig: rule}
eval_views: {rig: rule}
"""


def smoke(conf: Path, outputs: Path, *overrides: str) -> Outcome:
    cfg = compose_config(
        [
            f"hydra.searchpath=[file://{conf}]",
            "budget=smoke",
            "budget.horizon=2",
            f"paths.outputs={outputs}",
            *overrides,
        ]
    )
    return run_episode(cfg)


def test_a_new_method_from_one_yaml_runs_and_reaches_the_tables(tmp_path):
    conf = tmp_path / "conf"
    (conf / "method").mkdir(parents=True)
    (conf / "method" / "toy.yaml").write_text(TOY_METHOD)
    directory = smoke(conf, tmp_path / "outputs", "method=toy").directory
    assert (directory / "DONE").is_file() and "Toy method" in (directory / "run.json").read_text()
    build_tables(tmp_path / "outputs", [], tmp_path / "results", figures=False)
    table = (tmp_path / "results" / "tables" / "all_runs.md").read_text()
    assert "| Toy method |" in table


def test_a_new_scene_from_one_yaml_and_its_mesh_runs_and_reaches_the_tables(tmp_path):
    conf, assets = tmp_path / "conf", tmp_path / "assets"
    (conf / "scene").mkdir(parents=True)
    (conf / "scene" / "toy_box.yaml").write_text(TOY_SCENE)
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.8))
    box.apply_translation((0.0, 0.0, 0.4))
    box.visual.face_colors = np.tile([200, 80, 40, 255], (len(box.faces), 1))
    (assets / "toy_box").mkdir(parents=True)
    box.export(assets / "toy_box" / "toy_box.ply")
    directory = smoke(conf, tmp_path / "outputs", "scene=toy_box", "method=random", f"paths.assets={assets}").directory
    assert (directory / "DONE").is_file() and directory.parts[-4] == "toy_box"
    build_tables(tmp_path / "outputs", [], tmp_path / "results", figures=False)
    table = (tmp_path / "results" / "tables" / "all_runs.md").read_text()
    assert "| toy_box |" in table and "toy_box (mesh toy_box/toy_box.ply" in table


@pytest.mark.parametrize("bad", ["nvf.methods.Nothing", "nvf.config.TrainConfig"])
def test_a_method_yaml_naming_no_method_class_is_one_line(tmp_path, bad, capsys):
    (tmp_path / "method").mkdir()
    (tmp_path / "method" / "bad.yaml").write_text(TOY_METHOD.replace("test_declared.Toy", bad))
    with pytest.raises(SystemExit) as info:
        compose_config([f"hydra.searchpath=[file://{tmp_path}]", "method=bad"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and len(err.strip().splitlines()) == 1 and "method.implementation" in err
