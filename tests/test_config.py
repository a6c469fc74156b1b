"""Hydra config tree: every group option composes, validates, and impossible values are rejected."""

import itertools

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

from pipeline.config.catalog import declared
from pipeline.config.validation import ConfigError, validate
from pipeline.repo import CONF
from pipeline.config.schema import register_configs


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


@pytest.fixture(scope="module")
def composer():
    register_configs()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        yield lambda *overrides, **kw: compose(config_name="config", overrides=list(overrides), **kw)


def test_every_group_has_its_options():
    assert len(_options("scene")) == 18 and "default" in _options("scene")
    assert _options("method") == sorted(["random", "wd", "activermap", "air", "activenerf", "neurar", "nvf"])
    assert _options("ablation") == sorted(["none", "wo_vis", "wo_var", "ind_rays", "loose"])
    assert _options("planner") == ["argmax", "opt"]
    assert _options("budget") == ["cpu", "paper", "smoke"]


@pytest.mark.parametrize("scene", _options("scene"))
def test_every_scene_composes(composer, scene):
    cfg = composer(f"scene={scene}")
    validate(cfg)
    assert cfg.scene.name == scene


@pytest.mark.parametrize("method", _options("method"))
def test_every_method_composes(composer, method):
    cfg = composer(f"method={method}")
    validate(cfg)
    assert cfg.method.name == method
    assert cfg.method.stages[0] == "backbone"


def test_every_ablation_budget_planner_combination(composer):
    """Groups that write outside their own package (ablation, budget) must not clobber each other."""
    for ablation, budget, planner in itertools.product(_options("ablation"), _options("budget"), _options("planner")):
        cfg = composer(f"ablation={ablation}", f"budget={budget}", f"planner={planner}")
        validate(cfg)
        assert (cfg.ablation.name, cfg.budget.name, cfg.planner.name) == (ablation, budget, planner)
        assert cfg.nvf.entropy.use_visibility == (ablation != "wo_vis")
        assert cfg.nvf.entropy.use_variance == (ablation != "wo_var")
        assert (cfg.nvf.entropy.d0 == 0.0) == (ablation == "ind_rays")
        assert (cfg.nvf.entropy.bound == "moment_matched") == (ablation == "loose")


@pytest.mark.slow
def test_full_cross_product_composes(composer):
    groups = [_options(g) for g in ("scene", "method", "ablation", "planner", "budget")]
    for scene, method, ablation, planner, budget in itertools.product(*groups):
        cfg = composer(f"scene={scene}", f"method={method}", f"ablation={ablation}", f"planner={planner}", f"budget={budget}")
        validate(cfg)


@pytest.mark.parametrize("experiment", _options("experiment"))
def test_every_experiment_composes(composer, experiment):
    cfg = composer(f"experiment={experiment}", return_hydra_config=True)
    params = cfg.hydra.sweeper.params
    assert params, f"experiment {experiment} sweeps nothing"
    for group, values in params.items():
        options = declared(group) if str(values).startswith("glob(") else str(values).split(",")  # glob(*): all
        for value in options:
            validate(composer(f"experiment={experiment}", f"{group}={value}"))


def test_budgets_scale_only_sizes(composer):
    paper, cpu = composer("budget=paper"), composer("budget=cpu")
    assert paper.budget.image_size == 512 and paper.planner.resolution == 300
    assert paper.train.backbone.iters == 5000 and paper.planner.num_candidates == 512
    assert cpu.nvf.entropy == paper.nvf.entropy
    assert cpu.sampler.step_size == paper.sampler.step_size


@pytest.mark.parametrize(
    ("key", "value", "needle"),
    [
        ("budget.horizon", -1, "budget.horizon"),
        ("planner.num_candidates", 0, "planner.num_candidates"),
        ("field.kind", "mlp", "field.kind"),
        ("nvf.entropy.bound", "exact", "nvf.entropy.bound"),
        ("planner.opt.ray_fraction", 1.5, "planner.opt.ray_fraction"),
        ("device", "tpu", "device"),
        ("device", "cudax", "device"),
        ("baseline.activenerf_variant", "B", "not implemented"),
        ("baseline.air_view_score", "topk", "not implemented"),
        ("baseline.neurar_loss", "nll", "not implemented"),
        ("baseline.neurar_detach", False, "baseline.neurar_detach"),
        ("train.precision", "fp64", "train.precision"),
    ],
)
def test_validation_names_the_key(composer, key, value, needle):
    cfg = composer()
    with open_dict(cfg):
        parent, _, leaf = key.rpartition(".")
        (_select(cfg, parent) if parent else cfg)[leaf] = value
    with pytest.raises(ConfigError, match=needle) as err:
        validate(cfg)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(("device", "visible"), [("cuda", 0), ("cuda:1", 1)])
def test_a_cuda_device_torch_cannot_see_is_one_line(composer, monkeypatch, device, visible):
    """``device=cuda`` on a machine without it fails at validation, not with torch's traceback mid-run."""
    monkeypatch.setattr(torch.cuda, "device_count", lambda: visible)
    cfg = composer(f"device={device}")
    with pytest.raises(ConfigError, match=f"device={device} but torch sees {visible} CUDA") as err:
        validate(cfg)
    assert "\n" not in str(err.value)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: visible + 1)
    validate(cfg)


@pytest.mark.parametrize(("precision", "needle"), [("bf16", "AVX512_BF16"), ("fp16", "AVX512_FP16")])
def test_a_precision_the_cpu_lacks_is_one_line_naming_what_it_has(composer, monkeypatch, precision, needle):
    """``train.precision`` must run natively on the run's device; otherwise one line says what is missing
    and which precisions this device has (commands turn it into ``error: ...`` and exit status 2)."""
    import nvf.precision

    monkeypatch.setattr(nvf.precision, "_cpu_bf16", lambda: False)
    monkeypatch.setattr(nvf.precision, "_cpu_fp16", lambda: False)
    cfg = composer(f"train.precision={precision}", "device=cpu")
    with pytest.raises(ConfigError, match=f"train.precision={precision}: .*{needle}.*available here: fp32$") as err:
        validate(cfg)
    assert "\n" not in str(err.value)
    monkeypatch.setattr(nvf.precision, "_cpu_bf16", lambda: True)
    monkeypatch.setattr(nvf.precision, "_cpu_fp16", lambda: True)
    validate(cfg)
    validate(composer("train.precision=fp32", "device=cpu"))  # float32 runs anywhere


def _select(cfg, dotted):
    node = cfg
    for part in dotted.split("."):
        node = node[part]
    return node
