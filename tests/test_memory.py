"""The per-stage memory model (``pipeline.config.memory.stage_peaks``) and the device chosen in one place
(``nvf.device``): the model's terms grow with the sizes that make them, and it stays within 2x of every
peak measured at the paper's sizes (the committed results/bench/paper_shape.json)."""

import json
import math

import pytest
import torch
from hydra import compose, initialize_config_dir

from nvf import device as devices
from pipeline.config import memory
from pipeline.config.structured_configs import register_configs
from pipeline.config.validation import typed_run
from pipeline.episode import evaluation
from pipeline.repo import CONF, RESULTS

PAPER_SHAPE = RESULTS / "bench" / "paper_shape.json"


@pytest.fixture(scope="module")
def composer():
    register_configs()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        yield lambda *overrides: typed_run(compose(config_name="config", overrides=list(overrides)))


def test_marched_samples_follow_m6s_steps_along_the_object_box(composer):
    """The default scene's box diagonal is 2.82: 250 fixed steps to the cone's knee at 1.73, then ln(2.82/1.73)
    / 0.004 = 122 steps; Room's 20.6 give 870, and the cap (``sampler.max_samples_per_ray``) bounds both."""
    assert memory.marched_per_ray(composer("budget=paper")) == 372
    assert memory.marched_per_ray(composer("budget=paper", "scene=room")) == 870
    assert memory.marched_per_ray(composer("budget=paper", "scene=room", "sampler.max_samples_per_ray=500")) == 500


def test_each_stage_grows_with_its_own_sizes(composer):
    base = memory.stage_peaks(composer("budget=paper"), views=3)
    assert set(base) == set(memory.STAGES) and min(base.values()) > memory.PROCESS_BYTES
    for override, stage in (
        ("train.backbone.batch=8192", "backbone"),
        ("train.variance.batch=8192", "variance"),
        ("train.visibility.batch=131072", "visibility"),
        ("planner.resolution=600", "opt"),
        ("budget.recon_batch=32768", "mesh_metrics"),
        ("budget.gt_points=5000000", "mesh_metrics"),
        ("field.log2_hashmap_size=21", "backbone"),
        ("train.label_lattice=4", "visibility"),
    ):
        grown = memory.stage_peaks(composer("budget=paper", override), views=3)
        assert grown[stage] > base[stage], override
    more_views = memory.stage_peaks(composer("budget=paper"), views=23)
    assert all(more_views[stage] > base[stage] for stage in memory.STAGES)
    on_device = memory.stage_peaks(composer("budget=paper"), views=3, on_device=True)
    assert all(on_device[stage] < base[stage] - memory.PROCESS_BYTES for stage in memory.STAGES)


def test_the_density_lattice_is_counted_and_refused_where_it_does_not_fit(composer):
    """``train.label_lattice=4`` on the paper's 128³ grid: 513³ vertices, a float32 value and a boolean mark
    each (675 MB), in the visibility stage's peak and as an allocation that a 0.5 GiB device refuses, naming
    the lattice; without a lattice, nothing."""
    cfg = composer("budget=paper", "train.label_lattice=4")
    assert memory.lattice_bytes(cfg) == 5 * 513**3
    assert memory.lattice_bytes(composer("budget=paper")) == 0.0
    assert "train.label_lattice" not in {a.key for a in memory.allocations(composer("budget=paper"))}
    without = memory.stage_peaks(composer("budget=paper"), views=3)["visibility"]
    assert memory.stage_peaks(cfg, views=3)["visibility"] - without == 5 * 513**3
    line = memory.too_large(cfg, host_bytes=1e12, device_bytes=0.5 * memory.GIB, device_name="a small GPU")
    assert line is not None and line.startswith("train.label_lattice=4: the density lattice")
    assert "lower train.label_lattice or sampler.grid_resolution" in line
    assert memory.too_large(composer("budget=paper"), 1e12, 0.5 * memory.GIB, "a small GPU") is None


def test_the_models_constants_are_the_codes():
    assert memory.RENDER_CHUNK == evaluation.RENDER_CHUNK
    assert memory.alexnet_floats(512) == 64 * 127**2 + 192 * 63**2 + 896 * 31**2  # LPIPS' AlexNet at 512 px


def test_the_model_is_within_2x_of_every_peak_measured_at_the_papers_sizes(composer):
    """Every stage of the committed paper-size run: the model gives today what the run recorded as its
    prediction, and that prediction is within 2x of the measured peak (resident memory on the CPU)."""
    report = json.loads(PAPER_SHAPE.read_text())
    cuts = {cut["key"]: cut["used"] for cut in report["cuts"]}
    eval_views = int(cuts.get("evaluation views (--eval-views)", memory.EVAL_VIEWS))
    checked = set()
    for scene in {row["scene"] for row in report["stages"]}:
        rows = [row for row in report["stages"] if row["scene"] == scene]
        views = next(row["count"] for row in rows if row["name"] == "ground_truth") - eval_views
        cfg = composer("budget=paper", f"scene={scene}")
        predicted = memory.stage_peaks(cfg, views, eval_views, on_device=report["device"].startswith("cuda"))
        for row in rows:
            stage = row["name"].removesuffix("_paper_samples")
            assert math.isclose(row["predicted_gib"], predicted[stage] / memory.GIB, rel_tol=1e-9), (scene, stage)
            assert 0.5 <= row["peak_rss_gib"] / row["predicted_gib"] <= 2.0, (scene, row["name"])
            checked.add((scene, stage))
    assert {stage for _, stage in checked} == set(memory.STAGES)


def test_the_device_is_chosen_in_one_place(monkeypatch):
    assert devices.resolve_device("cpu") == torch.device("cpu")
    assert devices.resolve_device("cuda:1") == torch.device("cuda", 1)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert devices.resolve_device("auto") == torch.device("cpu")
    devices.synchronize()  # a no-op without CUDA
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert devices.resolve_device("auto") == torch.device("cuda")
