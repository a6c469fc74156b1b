"""A method or a scene is declared once: a new one added from a temporary config directory (one yaml; a
method class here, with a setting of its own; a mesh the test writes) joins every experiment it declares,
runs through a smoke episode and reaches every table that should hold it, without touching any other
file of the repository."""

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import pytest
import trimesh
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from jaxtyping import Float, Int
from torch import Tensor

from nvf.methods import Method
from nvf.model import RenderResult
from pipeline.config.structured_configs import register_configs
from pipeline.config.validation import compose_run
from pipeline.episode.runner import run_episode
from pipeline.repo import CONF
from pipeline.tables.build import build_tables


@dataclass(frozen=True)
class OpacityScorer:
    """A toy per-ray score: the ray's accumulated opacity, raised to ``power`` (views that see the most
    surface win)."""

    power: float
    name: ClassVar[str] = "toy"
    heads: ClassVar[frozenset[str]] = frozenset()
    sampler: ClassVar[str] = "occupancy"

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None) -> Float[Tensor, " R"]:
        return result.acc**self.power


@dataclass(frozen=True, kw_only=True)
class Toy(Method):
    """A toy method: the most opaque view next; a setting of its own, ``power``, and a choice, ``mode``."""

    power: float
    mode: Literal["plain", "squared"]

    def scorer(self) -> OpacityScorer:
        return OpacityScorer(self.power * (2.0 if self.mode == "squared" else 1.0))


TOY_EXPERIMENTS = ("main", "table1_opt", "table34_nerf_assets")
TOY_SCENE_EXPERIMENTS = ("main", "table1_opt")  # a NeRF asset that stays out of table34: declared, not by kind
TOY_METHOD = f"""_target_: test_declared.Toy
name: toy
label: Toy method
rank: 50
stages: [backbone]
experiments: [{", ".join(TOY_EXPERIMENTS)}]
power: 1.0
mode: plain
"""

TOY_SCENE = f"""name: toy_box
kind: object
source: mesh
paper_scene: toy_box
nerf_asset: true
rank: 30
experiments: [{", ".join(TOY_SCENE_EXPERIMENTS)}]
files: []
object_aabb: [[-0.6, -0.6, -0.1], [0.6, 0.6, 0.9]]
camera_box: [[-1.5, -1.5, -0.1], [1.5, 1.5, 2.4]]
tight_box: [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.8]]
init_views: {{rig: rule}}
eval_views: {{rig: rule}}
"""
PAPER_EXPERIMENTS = ("main", "table1_opt", "table2_ablation", "table34_nerf_assets")


def toy_conf(tmp_path: Path) -> Path:
    """A config directory with the toy method and the toy scene."""
    conf = tmp_path / "conf"
    for group, name, text in (("method", "toy", TOY_METHOD), ("scene", "toy_box", TOY_SCENE)):
        (conf / group).mkdir(parents=True)
        (conf / group / f"{name}.yaml").write_text(text)
    return conf


def swept(conf: Path, experiment: str) -> dict[str, set[str]]:
    """The methods and scenes an experiment sweeps, as Hydra's basic sweeper reads them (its params resolved
    in the composed config, then parsed by Hydra's override grammar)."""
    register_configs()
    with initialize_config_dir(str(CONF), version_base="1.3"):
        overrides = [f"hydra.searchpath=[file://{conf}]", f"experiment={experiment}"]
        cfg = compose("config", overrides=overrides, return_hydra_config=True)
    params = [f"{key}={value}" for key, value in cfg.hydra.sweeper.params.items() if key in ("method", "scene")]
    parsed = OverridesParser.create().parse_overrides(params)
    return {o.key_or_group: set(o.sweep_string_iterator()) if o.is_sweep_override() else {o.value()} for o in parsed}


@pytest.mark.parametrize("experiment", PAPER_EXPERIMENTS)
def test_the_experiments_sweep_every_method_and_scene_that_declares_them(tmp_path, experiment):
    values = swept(toy_conf(tmp_path), experiment)
    assert ("toy" in values["method"]) == (experiment in TOY_EXPERIMENTS)
    assert ("toy_box" in values["scene"]) == (experiment in TOY_SCENE_EXPERIMENTS)
    assert "nvf" in values["method"] and "hotdog" in values["scene"]  # the declared ones stay


def test_a_new_method_and_scene_reach_every_table_that_should_hold_them(tmp_path):
    conf, assets, outputs = toy_conf(tmp_path), tmp_path / "assets", tmp_path / "outputs"
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.8))
    box.apply_translation((0.0, 0.0, 0.4))
    box.visual.face_colors = np.tile([200, 80, 40, 255], (len(box.faces), 1))
    (assets / "toy_box").mkdir(parents=True)
    box.export(assets / "toy_box" / "toy_box.ply")
    overrides = ["budget=smoke", "budget.horizon=2", f"paths.outputs={outputs}", f"paths.assets={assets}"]
    cfg = compose_run(
        [f"hydra.searchpath=[file://{conf}]", "scene=toy_box", "method=toy", "method.power=2.0", *overrides]
    )
    directory = run_episode(cfg).directory
    record = (directory / "run.json").read_text()
    assert (directory / "DONE").is_file() and directory.parts[-4] == "toy_box"
    assert "Toy method" in record and '"power": 2.0' in record
    build_tables(outputs, [], tmp_path / "results", figures=False)
    tables = tmp_path / "results" / "tables"
    for table in ("all_runs", *PAPER_EXPERIMENTS):
        text = (tables / f"{table}.md").read_text()
        holds = table == "all_runs" or (table in TOY_EXPERIMENTS and table in TOY_SCENE_EXPERIMENTS)
        assert ("| Toy method§ |" in text) == holds, table  # § a method the paper does not have
        assert ("toy_box (mesh toy_box/toy_box.ply" in text) == holds, table


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("_target_", "nvf.methods.Nothing", "method._target_"),
        ("_target_", "nvf.config.TrainConfig", "method._target_"),
        ("mode", "cubed", "method.mode='cubed' must be one of plain, squared"),
        ("power", "strong", "method.power"),
    ],
)
def test_a_method_yaml_with_a_bad_value_is_one_line(tmp_path, key, value, message, capsys):
    (tmp_path / "method").mkdir()
    lines = [f"{key}: {value}" if line.startswith(f"{key}:") else line for line in TOY_METHOD.splitlines()]
    (tmp_path / "method" / "bad.yaml").write_text("\n".join(lines) + "\n")
    with pytest.raises(SystemExit) as info:
        compose_run([f"hydra.searchpath=[file://{tmp_path}]", "method=bad"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and len(err.strip().splitlines()) == 1 and message in err
