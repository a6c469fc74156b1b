"""Hydra config tree: every group option composes, validates, and impossible values are rejected."""

import dataclasses
import itertools
import math
import os
import re
import typing
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from omegaconf import OmegaConf, open_dict

from nvf.config import POSITIVE
from pipeline.config import validation
from pipeline.config.catalog import declared
from pipeline.config.memory import SIZE_KEYS_BOUNDED, allocations, too_large
from pipeline.config.plain_containers import as_dict, as_list
from pipeline.config.structured_configs import RunConfig, register_configs
from pipeline.config.validation import ConfigError, error_line, typed_run, validate
from pipeline.repo import CONF


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


@pytest.fixture(scope="module")
def composer():
    register_configs()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        yield lambda *overrides, **kw: compose(config_name="config", overrides=list(overrides), **kw)


def test_every_group_has_its_options():
    assert len(_options("scene")) == 18 and "default" in _options("scene")
    assert _options("method") == sorted(
        [
            "random",
            "wd",
            "activermap",
            "air",
            "activenerf",
            "neurar",
            "nvf",
            "fisherrf",
            "fvs",
            "bayesrays",
            "fvs_facing",
            "cover",
            "warprf",
        ]
    )
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


def _covering_runs() -> list[tuple[str, str, str, str, str]]:
    """(scene, method, ablation, planner, budget) runs holding every (scene, method, budget) and every (method,
    ablation, planner, budget) combination (so every pair of options of any two groups), the group left out
    taken in turn: 672 runs instead of the whole product's 4320 (Hydra's compose dominates: tens of minutes on
    two cores)."""
    scenes, methods, ablations, planners, budgets = (
        _options(g) for g in ("scene", "method", "ablation", "planner", "budget")
    )
    runs = [
        (scene, method, ablations[i % len(ablations)], planners[i % len(planners)], budget)
        for i, (scene, method, budget) in enumerate(itertools.product(scenes, methods, budgets))
    ]
    runs += [
        (scenes[i % len(scenes)], method, ablation, planner, budget)
        for i, (method, ablation, planner, budget) in enumerate(
            itertools.product(methods, ablations, planners, budgets)
        )
    ]
    return runs


WHOLE_VIEW_METHODS = ("fisherrf", "fvs", "bayesrays", "fvs_facing", "cover", "warprf")
"""The methods whose scorer reads whole views (a ``StepScorer``): -OPT is refused for them."""


@pytest.mark.slow
def test_every_pair_of_group_options_composes(composer):
    runs = _covering_runs()
    options = [_options(g) for g in ("scene", "method", "ablation", "planner", "budget")]
    for a, b in itertools.combinations(range(5), 2):  # the cover holds every pair of any two groups' options
        assert {(r[a], r[b]) for r in runs} == set(itertools.product(options[a], options[b]))
    for scene, method, ablation, planner, budget in runs:
        cfg = composer(
            f"scene={scene}", f"method={method}", f"ablation={ablation}", f"planner={planner}", f"budget={budget}"
        )
        if method in WHOLE_VIEW_METHODS and planner == "opt":  # whole-view scores: nothing for -OPT to refine
            with pytest.raises(ConfigError, match=f"planner=opt: {method} scores whole views"):
                validate(cfg)
        elif ablation != "none" and method != "nvf":  # an ablation of NVF on another method would be mislabelled
            with pytest.raises(ConfigError, match=f"ablation={ablation} ablates method=nvf, not method={method}"):
                validate(cfg)
        else:
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


def _flat(node, prefix=""):
    """``{dotted key: value}`` of a resolved config's leaves."""
    if isinstance(node, dict):
        return {k: v for key, value in node.items() for k, v in _flat(value, f"{prefix}{key}.").items()}
    return {prefix.rstrip("."): node}


def _departures(composer, budget: str) -> dict:
    """Keys whose value at ``budget`` differs from ``paper`` and is not a size (an integer count,
    resolution, iteration or batch, which budgets scale), with both values."""
    paper, other = (_flat(OmegaConf.to_container(composer(f"budget={b}"), resolve=True)) for b in ("paper", budget))
    changed = {key: (paper[key], other[key]) for key in paper if paper[key] != other[key] and key != "budget.name"}
    return {k: v for k, v in changed.items() if not all(isinstance(x, int) and not isinstance(x, bool) for x in v)}


# A smaller budget changes the method only here (docs/DEVIATIONS.md lists each).
BUDGET_DEPARTURES = {
    "cpu": {
        "train.variance.lr": (1e-3, 1e-2),  # 30 iterations at 1e-3 leave the heads untrained
        "train.visibility.lr": (1e-3, 1e-2),
        "planner.los_source": ("model", "mesh"),  # Room's M29 from the scene mesh: an oracle, marked in tables
        "planner.los_unobserved_free": (False, True),  # read only with los_source=model
        "render.backend": ("blender", "pyrender"),  # flat ground truth: the committed records' (BUDGETS.md)
        "train.label_cutoff": (1e-3, 0.0),  # M17 exact below the paper's sizes
    },
    "smoke": {
        "planner.los_unobserved_free": (False, True),
        "render.backend": ("blender", "pyrender"),
        "train.label_cutoff": (1e-3, 0.0),
    },
}


@pytest.mark.parametrize("budget", ["cpu", "smoke"])
def test_budgets_scale_only_sizes_except_the_documented_departures(composer, budget):
    assert _departures(composer, budget) == BUDGET_DEPARTURES[budget]
    deviations = (CONF.parent / "docs" / "DEVIATIONS.md").read_text()
    assert all(f"`{key}" in deviations for key in BUDGET_DEPARTURES[budget])
    paper, cpu = composer("budget=paper"), composer("budget=cpu")
    assert paper.budget.image_size == 512 and paper.planner.resolution == 300
    assert paper.train.backbone.iters == 5000 and paper.planner.num_candidates == 512
    assert cpu.nvf.entropy == paper.nvf.entropy


def _float_keys(composer) -> list[str]:
    return [
        key
        for key, value in _flat(OmegaConf.to_container(composer(), resolve=True)).items()
        if isinstance(value, float)
    ]


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_every_float_key_rejects_nan_and_inf(composer, value):
    """Found by walking the composed config, not from a list: a NaN learning rate or oversampling factor
    used to pass validation and fail mid-run, leaving run.json marked running."""
    keys = _float_keys(composer)
    assert {"train.backbone.lr", "planner.oversample", "nvf.entropy.beta", "sampler.far"} <= set(keys)
    for key in keys:
        cfg = composer()
        with open_dict(cfg):
            parent, _, leaf = key.rpartition(".")
            _select(cfg, parent)[leaf] = value
        with pytest.raises(ConfigError, match=rf"^{re.escape(key)}={value} must be a finite number$"):
            validate(cfg)


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        (
            ["budget.image_size=100000"],
            r"^budget.image_size=100000: one ground-truth render of 100000x100000 RGBA "
            r"float32 samples .* needs 149.0 GiB, more than the [0-9.]+ GiB of memory",
        ),
        (
            ["budget.image_size=20000", "budget.gt_samples=8"],
            r"^budget.image_size=20000: .* of 160000x160000 .* 381.5 GiB",
        ),
        (
            ["sampler.grid_resolution=100000"],
            r"^sampler.grid_resolution=100000: the occupancy grid .* needs 5587935.4 GiB",
        ),
        (
            ["field.kind=densegrid", "field.dense_resolution=4000"],
            r"^field.dense_resolution=4000: the dense feature grid",
        ),
        (["budget.eval_size=200000"], r"^budget.eval_size=200000: the 20 evaluation views' RGB float32 ground truth"),
    ],
)
def test_sizes_that_do_not_fit_in_memory_are_refused_with_the_number(composer, monkeypatch, overrides, needle):
    monkeypatch.setattr(validation, "host_memory", lambda: 64.0 * 2**30)  # the same numbers on every machine
    with pytest.raises(ConfigError, match=needle) as err:
        validate(composer(*overrides))
    assert "more than the 64.0 GiB of memory of this machine" in str(err.value)
    for budget in ("paper", "cpu", "smoke"):  # every budget fits on a 64 GiB machine
        validate(composer(f"budget={budget}"))


# (key, value, overrides that make the allocation happen): each size key set far beyond any memory
SCALED = [
    ("budget.image_size", 10**5, ()),
    ("budget.eval_size", 10**5, ()),
    ("budget.horizon", 10**6, ()),
    ("planner.resolution", 10**5, ()),
    ("planner.num_candidates", 10**9, ()),
    ("sampler.grid_resolution", 10**4, ()),
    ("budget.gt_points", 10**9, ()),
    ("budget.recon_points", 10**9, ()),
    ("budget.recon_batch", 10**9, ()),
    ("field.dense_resolution", 10**4, ("field.kind=densegrid",)),
    ("field.log2_hashmap_size", 40, ("field.max_resolution=100000",)),
    ("field.num_levels", 10**7, ()),
    ("field.hidden_dim", 10**6, ()),
    ("train.backbone.batch", 10**9, ()),
    ("train.variance.batch", 10**9, ()),
    ("train.visibility.batch", 10**9, ()),
    ("train.label_samples", 10**9, ()),
    ("train.target_samples", 10**12, ("train.schedule=reference",)),
    ("planner.los_samples", 10**9, ("planner.collision_free=true", "planner.los_source=model")),
    ("sampler.uniform_samples", 10**9, ("nvf.entropy.sampler=uniform",)),
]


def test_every_positive_size_key_has_an_allocation_or_a_reason_it_has_none():
    """The memory estimate covers every per-batch allocation a size key scales: each validated positive key is
    either in SCALED (an allocation of its own) or in SIZE_KEYS_BOUNDED (time, a rate, a cap, or bounded by
    another key's allocation), never neither."""
    scaled = {key for key, _, _ in SCALED}
    positive = {key for key, allowed in validation.RANGES.items() if allowed == POSITIVE}
    assert positive == scaled | set(SIZE_KEYS_BOUNDED) and not scaled & set(SIZE_KEYS_BOUNDED)


def _numeric_keys(schema: type, prefix: str = "") -> list[str]:
    """The dotted keys of ``schema``'s int and float fields (optional ones too), nested dataclasses walked."""
    keys, hints = [], typing.get_type_hints(schema)
    for item in dataclasses.fields(schema):
        kind = hints[item.name]
        if dataclasses.is_dataclass(kind):
            keys += _numeric_keys(kind, f"{prefix}{item.name}.")
        elif kind in (int, float, int | None, float | None):
            keys.append(prefix + item.name)
    return keys


def test_every_numeric_setting_declares_its_range_once_on_its_field():
    """(One declaration per setting) every int and float field of the run's schema carries its ``Range``
    (``nvf.config.ranged``), which validation reads: a new field without one fails here."""
    keys = _numeric_keys(RunConfig)
    assert len(keys) > 70 and sorted(keys) == sorted(validation.RANGES)


@pytest.mark.parametrize(
    ("override", "says"),
    [
        ("planner.los_threshold=1.5", "planner.los_threshold=1.5 must be in [0, 1]"),
        ("planner.opt.ray_fraction=0", "planner.opt.ray_fraction=0.0 must be in (0, 1]"),
        ("train.label_cutoff=1", "train.label_cutoff=1.0 must be in [0, 1)"),
        ("planner.oversample=0.5", "planner.oversample=0.5 must be in [1, inf]"),
        ("sampler.near=-1", "sampler.near=-1.0 must be in [0, inf]"),
        ("nvf.entropy.var_bg=0", "nvf.entropy.var_bg=0.0 must be positive"),
    ],
)
def test_a_value_outside_its_declared_range_is_one_line_naming_it(composer, override, says):
    with pytest.raises(ConfigError, match=f"^{re.escape(says)}$"):
        validate(composer(override))


@pytest.mark.parametrize(("key", "value", "overrides"), SCALED, ids=[key for key, _, _ in SCALED])
def test_every_size_key_beyond_memory_is_refused_naming_it(composer, key, value, overrides):
    """``train.label_samples=1000000000`` allocated ~8.9 GB and died with an allocator traceback
    after 26 s; ``budget.horizon=1000000000`` ran until killed. Every size key now has its allocation in the
    estimate (here against 1 GiB), so a value far beyond memory is refused before the run, naming the key."""
    cfg = composer(*overrides, f"{key}={value}")
    problem = too_large(typed_run(cfg), float(2**30), float(2**30), "a 1 GiB device")
    assert problem is not None and problem.startswith(f"{key}={value}: "), problem
    assert too_large(typed_run(composer(*overrides)), float(2**30), float(2**30), "a 1 GiB device") is None


def test_largest_allocations_are_lower_bounds_of_real_arrays(composer):
    """Each estimate is the size of one array the run really allocates (here: at the smoke budget)."""
    cfg = composer("budget=smoke")
    sizes = {a.key: a.nbytes for a in allocations(typed_run(cfg))}
    assert sizes["sampler.grid_resolution"] == 32**3 * (4 + 1 + 1)  # OccupancyGrid: occ, occupied, observed
    assert sizes["budget.image_size"] == 24 * 24 * 4 * 4  # render_rgba: [H, W, 4] float32
    assert sizes["field.log2_hashmap_size"] == 2**12 * 2 * 4  # one level's table, 2 float32 features


def test_an_unusable_outputs_directory_is_refused(composer, tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(
        ConfigError, match=rf"^paths.outputs={a_file} is a file, not a directory; pass paths.outputs=DIR$"
    ):
        validate(composer(f"paths.outputs={a_file}"))
    with pytest.raises(ConfigError, match=rf"^paths.outputs={a_file / 'x'} lies under {a_file}, which is a file"):
        validate(composer(f"paths.outputs={a_file / 'x'}"))
    validate(composer(f"paths.outputs={tmp_path / 'new' / 'dir'}"))  # created when the run starts


def _read_only_directory(tmp_path):
    """A directory this process cannot write in: mode 0555 (not read-only for root), else a read-only mount."""
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    if not os.access(locked, os.W_OK):
        return locked
    for candidate in (Path("/proc/sys"), Path("/sys")):
        if candidate.is_dir() and not os.access(candidate, os.W_OK):
            return candidate
    pytest.skip("running as root with no read-only mount to write into")


def test_a_read_only_outputs_directory_is_refused(composer, tmp_path):
    read_only = _read_only_directory(tmp_path)
    with pytest.raises(
        ConfigError,
        match=rf"^paths.outputs={read_only / 'runs'} would be created in {read_only}, which is not writable here",
    ):
        validate(composer(f"paths.outputs={read_only / 'runs'}"))
    with pytest.raises(ConfigError, match=rf"^paths.outputs={read_only} is not writable here; pass paths.outputs=DIR$"):
        validate(composer(f"paths.outputs={read_only}"))


@pytest.mark.parametrize(
    ("key", "value", "needle"),
    [
        ("budget.horizon", -1, "budget.horizon"),
        ("planner.num_candidates", 0, "planner.num_candidates"),
        ("planner.opt.ray_fraction", 1.5, "planner.opt.ray_fraction"),
        ("device", "tpu", "device"),
        ("device", "cudax", "device"),
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


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        (["field.kind=mlp"], "field.kind"),
        (["nvf.entropy.bound=exact"], "nvf.entropy.bound"),
        (["train.precision=fp64"], "train.precision"),
        (["method=activenerf", "method.variant=B"], "not implemented"),
        (["method=air", "method.view_score=topk"], "not implemented"),
        (["method=neurar", "method.loss=nll"], "not implemented"),
        (["method=neurar", "method.detach=false"], "method.detach"),
    ],
)
def test_a_choice_outside_its_field_is_one_line_naming_the_key(composer, overrides, needle):
    """A settings choice (a StrEnum field, checked when composed) or a method's own setting (its dataclass's
    field, checked when the method is built) outside what it allows: one line (``error_line``, as printed)."""
    with pytest.raises((HydraException, ConfigError)) as err:
        validate(composer(*overrides))
    line = error_line(err.value)
    assert "\n" not in line and needle in line


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


def test_an_ablation_name_that_conf_does_not_declare_is_one_line(composer):
    with pytest.raises(ConfigError, match=r"^ablation.name='no_such' is not one of .*wo_vis"):
        validate(composer("ablation.name=no_such"))


def test_plain_containers_resolve_on_request_and_refuse_the_other_kind():
    node = OmegaConf.create({"base": 2, "items": ["${base}", 3], "nested": {"x": "${base}"}})
    assert as_list(node["items"]) == [2, 3]
    assert as_list(node["items"], resolve=False) == ["${base}", 3]
    assert as_dict(node["nested"]) == {"x": 2}
    with pytest.raises(TypeError, match="sequence"):
        as_list(node["nested"])
    with pytest.raises(TypeError, match="mapping"):
        as_dict(node["items"])


def test_the_candidate_draw_counts_every_drawn_pose(composer):
    """``planner.num_candidates=10**9`` asked for 16 bytes a candidate and passed on a 24 GiB machine while its draw
    needed 33.6 GB: the estimate counts the poses drawn (1.2 N, 3 N collision-free) and what each holds at the
    draw's peak (its pose, the draw's intermediates, the density filter's encoding), and refuses it."""
    from pipeline.config.memory import CANDIDATE_FLOATS, drawn_poses

    run = typed_run(composer("planner.num_candidates=1000000000"))
    assert drawn_poses(run) == 1_200_000_000
    found = {a.key: a.nbytes for a in allocations(run)}["planner.num_candidates"]
    assert found == CANDIDATE_FLOATS * 4 * 1_200_000_000 > 33.6e9
    assert too_large(run, 24.0 * 2**30, 24.0 * 2**30, "24 GiB").startswith("planner.num_candidates=1000000000: ")
    assert drawn_poses(typed_run(composer("scene=room", "planner.num_candidates=10"))) == 30
