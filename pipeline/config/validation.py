"""Validation of a run's configuration (the schema is ``pipeline.config.structured_configs``): ``validate`` runs
before any work, raises ``ConfigError`` with one line naming the key, and turns the composed config into the typed
``pipeline.config.typed_run.Run`` that everything below the entry points reads; ``compose_run`` composes and
validates a config outside ``@hydra.main`` (benchmarks, experiments).
"""

import dataclasses
import math
import re
import sys
from pathlib import Path
from typing import Any

import torch
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf

from nvf.config import field_ranges
from nvf.density_lattice import MAX_SUBDIVISIONS, MAX_VERTICES, lattice_vertices
from nvf.device import resolve_device
from nvf.methods import Method
from nvf.precision import unsupported_reason
from nvf.uncertainty import StepScorer
from pipeline.cli import BadInput, error_line
from pipeline.config.catalog import declared
from pipeline.config.memory import host_memory, too_large
from pipeline.config.method import MethodError, build_method
from pipeline.config.paths import unwritable
from pipeline.config.plain_containers import as_dict
from pipeline.config.settings_beyond_groups import changed_settings
from pipeline.config.structured_configs import RunConfig, register_configs
from pipeline.config.typed_run import Run, resolved_entropy, run_of
from pipeline.records.schema import MAX_HORIZON
from pipeline.records.store import run_dir
from pipeline.records.verify import record_value_problem
from pipeline.repo import CONF


class ConfigError(BadInput, ValueError):
    """An impossible configuration value; the message is one line naming the key."""


# D1: the corrected entropy's log-determinant coefficient, the paper's 0.5 or the reference code's 1.0
LOGDET_COEFFS = (0.5, 1.0)
MIN_EVAL_SIZE = 32  # budget.eval_size: LPIPS' AlexNet needs inputs of at least this many pixels a side

RANGES = field_ranges(RunConfig)
"""Every numeric setting's range, declared once on its field (``nvf.config.ranged``), by dotted key."""


# samples per camera-to-point segment (M17's train.label_samples, M29's planner.los_samples): the paper takes 200;
# every sample is a density query per point and camera, so 65536 (300x) already makes one step take hours
MAX_SEGMENT_SAMPLES = 65536


def _check_ablation(cfg: DictConfig) -> None:
    """An ablation applies to the method it ablates (its ``of``: another method would run unchanged and be tabled as
    a method of its own, ``method=fvs ablation=wo_vis``), and every value its file (``conf/ablation/<name>.yaml``)
    sets still holds: an override that undoes it (``ablation=ind_rays nvf.entropy.d0=auto``) would label another
    method as the ablation."""
    of = OmegaConf.select(cfg, "ablation.of")
    if cfg.ablation.name != "none" and of is not None and cfg.method.name != of:
        raise ConfigError(
            f"ablation={cfg.ablation.name} ablates method={of}, not method={cfg.method.name}; drop the ablation or "
            f"run method={of}"
        )
    sets = OmegaConf.to_container(OmegaConf.load(CONF / "ablation" / f"{cfg.ablation.name}.yaml"))
    changed = changed_settings(sets, OmegaConf.to_container(cfg, resolve=True))
    if changed:
        key, value = changed[0]
        raise ConfigError(
            f"ablation={cfg.ablation.name} sets {key}={value}, but an override made it {OmegaConf.select(cfg, key)}; "
            "drop the override or the ablation"
        )


def _non_finite(node: Any, prefix: str = "") -> tuple[str, float] | None:
    """The first float of a resolved config (dotted key, value) that is NaN or infinite."""
    if isinstance(node, dict):
        for key, value in node.items():
            found = _non_finite(value, f"{prefix}{key}.")
            if found is not None:
                return found
    elif isinstance(node, list):
        for index, value in enumerate(node):
            found = _non_finite(value, f"{prefix}{index}.")
            if found is not None:
                return found
    elif isinstance(node, float) and not math.isfinite(node):
        return prefix.rstrip("."), node
    return None


def _check_finite(cfg: DictConfig) -> None:
    """Every float of the config (all groups, not a list of keys) is finite, and every value is one a run
    record can hold (``pipeline.records.verify.record_value_problem``: text without control characters, ...)."""
    settings = {k: v for k, v in as_dict(cfg).items() if k != "hydra"}
    found = _non_finite(settings)
    if found is not None:
        raise ConfigError(f"{found[0]}={found[1]} must be a finite number")
    problem = record_value_problem(settings)
    if problem is not None:
        raise ConfigError(f"{problem}: a run record could not hold it; give a plain value")


def _unknown_keys(node: DictConfig, schema: type, prefix: str = "") -> list[str]:
    """Dotted keys of ``node`` that its schema dataclass does not declare (added with ``+key=value``);
    free-form mappings of the schema (``dict[str, Any]``) take any key."""
    declared_fields = {f.name for f in dataclasses.fields(schema)}
    found = []
    for key in map(str, node):
        kind = OmegaConf.get_type(node, key)
        if key not in declared_fields:
            found.append(f"{prefix}{key}")
        elif dataclasses.is_dataclass(kind):
            found += _unknown_keys(node[key], kind, f"{prefix}{key}.")
    return found


def _check_known_keys(cfg: DictConfig) -> None:
    """Every key is one the schema (``RunConfig``) declares: ``+no_such_key=1`` is refused as
    ``no_such_key=1`` is, instead of being stored and ignored."""
    unknown = [key for key in _unknown_keys(cfg, RunConfig) if key != "hydra"]
    if unknown:
        raise ConfigError(
            f"unknown key {unknown[0]!r} (added with +{unknown[0]}=...): the config has no such setting; "
            "drop it (python -m pipeline.run --help lists every key)"
        )


def _check_run_keys(run: Run) -> None:
    """The seed (an int64: it seeds every generator of the run) and the names that make the run's directory,
    as ``pipeline.records.store.run_dir`` takes them."""
    try:
        run_dir(Path(run.paths.outputs), *run.names, run.seed)
    except ValueError as err:
        raise ConfigError(str(err)) from None


def check_paths(paths: dict[str, str]) -> None:
    """Each of ``paths`` (config key -> a directory the run writes in) is, or can be made, a writable
    directory."""
    for key, path in paths.items():
        problem = unwritable(key, Path(path))
        if problem is not None:
            raise ConfigError(problem)


def _check_memory(run: Run) -> None:
    """The largest allocation of each size key fits the memory it lives in (``pipeline.config.memory``)."""
    device = resolve_device(str(run.device))
    host = host_memory()
    if device.type == "cuda" and torch.cuda.is_available():  # a device torch cannot see: _check_device's line
        index = 0 if device.index is None else device.index
        name = f"cuda:{index} ({torch.cuda.get_device_name(index)})"
        problem = too_large(run, host, float(torch.cuda.get_device_properties(index).total_memory), name)
    else:
        problem = too_large(run, host, host, "this machine")
    if problem is not None:
        raise ConfigError(problem)


def validate(cfg: DictConfig) -> Run:
    """The composed ``cfg`` as a typed ``Run``, after rejecting impossible values before any work starts (one
    line naming the key): keys the schema declares (``+key`` too; a choice outside its ``StrEnum`` is refused
    when the config is composed), the seed and run names, values a run record can hold, the method's own
    settings, finite floats, positive and bounded sizes, sizes that fit in memory, a device torch can see and
    a writable ``paths.outputs``."""
    _check_known_keys(cfg)
    d0 = cfg.nvf.entropy.d0
    if d0 != "auto" and (isinstance(d0, str) or (d0 is not None and d0 < 0)):
        raise ConfigError(
            f"nvf.entropy.d0={d0} must be a number >= 0 (0 = Ind. Rays), auto (0.25 x the object box's diagonal) "
            "or null (the scene's value)"
        )
    run = typed_run(cfg)
    _check_run_keys(run)
    _check_finite(cfg)
    if cfg.nvf.entropy.logdet_coeff not in LOGDET_COEFFS:
        raise ConfigError(
            f"nvf.entropy.logdet_coeff={cfg.nvf.entropy.logdet_coeff!r} is not one of "
            f"{', '.join(map(str, LOGDET_COEFFS))}"
        )
    if cfg.ablation.name not in declared("ablation"):
        raise ConfigError(f"ablation.name={cfg.ablation.name!r} is not one of {', '.join(declared('ablation'))}")
    _check_ablation(cfg)
    for key, allowed in RANGES.items():
        value = OmegaConf.select(cfg, key)
        problem = None if value is None else allowed.problem(key, value)  # None: an optional setting left unset
        if problem is not None:
            raise ConfigError(problem)
    for key in ("train.label_samples", "planner.los_samples"):
        if OmegaConf.select(cfg, key) > MAX_SEGMENT_SAMPLES:
            raise ConfigError(
                f"{key}={OmegaConf.select(cfg, key)} is more than {MAX_SEGMENT_SAMPLES} samples per segment (the paper "
                f"takes 200; each is a density query per point and camera); lower {key}"
            )
    if cfg.budget.horizon > MAX_HORIZON:
        raise ConfigError(
            f"budget.horizon={cfg.budget.horizon} is more than {MAX_HORIZON} steps (every step rewrites the run's "
            f"steps.jsonl, and records of more steps are refused when read); lower budget.horizon"
        )
    lattice = cfg.train.label_lattice
    if not 0 <= lattice <= MAX_SUBDIVISIONS:
        raise ConfigError(
            f"train.label_lattice={lattice} must be in 0..{MAX_SUBDIVISIONS} (the density lattice's subdivisions of "
            "an occupancy cell; 0 = the field itself)"
        )
    if lattice and lattice_vertices(cfg.sampler.grid_resolution, lattice) > MAX_VERTICES:
        raise ConfigError(
            f"train.label_lattice={lattice} with sampler.grid_resolution={cfg.sampler.grid_resolution}: a lattice "
            f"of more than {MAX_VERTICES} vertices; lower train.label_lattice"
        )
    if not 0.0 < cfg.planner.opt.ray_fraction <= 1.0:
        raise ConfigError(f"planner.opt.ray_fraction={cfg.planner.opt.ray_fraction} must be in (0, 1]")
    if cfg.planner.oversample < 1.0:
        raise ConfigError(f"planner.oversample={cfg.planner.oversample} must be >= 1")
    if cfg.field.max_resolution < cfg.field.base_resolution:
        raise ConfigError(
            f"field.max_resolution={cfg.field.max_resolution} is below "
            f"field.base_resolution={cfg.field.base_resolution}"
        )
    if cfg.budget.eval_size < MIN_EVAL_SIZE:
        raise ConfigError(
            f"budget.eval_size={cfg.budget.eval_size} must be >= {MIN_EVAL_SIZE} (LPIPS' AlexNet needs "
            f"{MIN_EVAL_SIZE}x{MIN_EVAL_SIZE} inputs)"
        )
    rival = cfg.diagnostics.rank_against
    if rival is not None and rival not in declared("ablation"):
        raise ConfigError(f"diagnostics.rank_against={rival!r} is not one of {', '.join(declared('ablation'))}")
    _check_device(str(cfg.device))
    _check_render(cfg)
    _check_precision(str(cfg.train.precision), str(cfg.device))
    _check_memory(run)
    check_paths({"paths.outputs": run.paths.outputs})
    return run


def typed_run(cfg: DictConfig) -> Run:
    """``cfg`` as a ``Run``: the method node builds its class (``pipeline.config.method``: every key one its
    dataclass declares, of the field's type, no alternative that is not implemented), with NVF's entropy
    settings resolved on the scene, and no -OPT for a method that scores whole views."""
    config = OmegaConf.to_object(cfg)
    assert isinstance(config, RunConfig), f"a composed run config, not {type(config).__name__}"
    config.nvf.entropy = resolved_entropy(config.nvf.entropy, config.scene)
    method = _method(cfg, config)
    if cfg.planner.name == "opt" and isinstance(method.scorer(), StepScorer):
        raise ConfigError(
            f"planner=opt: {method.name} scores whole views, without the per-pixel score -OPT refines "
            "(docs/METHOD.md 17); use planner=argmax"
        )
    rival = None
    if config.diagnostics.rank_against is not None:
        name = str(config.diagnostics.rank_against)
        merged = OmegaConf.merge(cfg, OmegaConf.load(CONF / "ablation" / f"{name}.yaml"))
        ablated = OmegaConf.to_object(merged)
        assert isinstance(ablated, RunConfig), "a run config merged with an ablation's mapping"
        ablated.nvf.entropy = resolved_entropy(ablated.nvf.entropy, ablated.scene)
        rival = name, _method(cfg, ablated)
    composed = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
    assert isinstance(composed, dict)
    return run_of(config, method, rival, {str(k): v for k, v in composed.items()})


def run_settings_of(config: RunConfig) -> dict[str, object]:
    """The run config's values a method may read as run settings (``nvf.methods.run_setting``): NVF's
    ``nvf.entropy``, Bayes' Rays' ``sampler.grid_resolution``."""
    return {"nvf.entropy": config.nvf.entropy, "sampler.grid_resolution": config.sampler.grid_resolution}


def method_yaml(name: object) -> str:
    """Where the method ``name``'s yaml was found: on Hydra's search path of the running command (an outside
    method's ``hydra.searchpath``) or the project's ``conf/method/<name>.yaml``."""
    relative = Path("method") / f"{name}.yaml"
    if HydraConfig.initialized():
        for source in HydraConfig.get().runtime.config_sources:
            folder = str(source.path).removeprefix("file://")
            found = Path(folder) / relative if folder else None
            if found is not None and found.is_file():
                return f"conf/{relative}" if found.parent.parent.resolve() == CONF.resolve() else str(found)
    return f"conf/{relative}"


def _method(cfg: DictConfig, config: RunConfig) -> Method:
    """The method ``config.method`` declares, with ``config``'s run settings (``run_settings_of``)."""
    try:
        return build_method(config.method, run_settings_of(config))
    except MethodError as err:
        raise ConfigError(f"{err} ({method_yaml(cfg.method.get('name'))})") from None


def _check_render(cfg: DictConfig) -> None:
    """The Blender backend anti-aliases with Cycles' samples (whether Blender's Python is there is the
    renderer's check, ``pipeline.scenes.ground_truth.renderer_problem``)."""
    if cfg.render.backend != "blender":
        return
    if cfg.budget.gt_samples != 1:
        raise ConfigError(
            f"budget.gt_samples={cfg.budget.gt_samples} supersamples the pyrender ground truth; with "
            "render.backend=blender "
            "Cycles filters each pixel over render.samples samples: set budget.gt_samples=1"
        )


def _check_precision(precision: str, device: str) -> None:
    """``train.precision`` runs natively on the run's device (``device=auto`` resolved)."""
    reason = unsupported_reason(precision, resolve_device(device))
    if reason is not None:
        raise ConfigError(f"train.precision={precision}: {reason}")


def _check_device(device: str) -> None:
    """``auto``, ``cpu``, or a CUDA device that torch can see here."""
    if device in ("auto", "cpu"):
        return
    if re.fullmatch(r"cuda(:\d+)?", device) is None:
        raise ConfigError(f"device={device!r} must be auto, cpu, cuda or cuda:N")
    index, count = int(device.partition(":")[2] or 0), torch.cuda.device_count()
    if index >= count:
        raise ConfigError(
            f"device={device} but torch sees {count} CUDA device(s) on this machine; use device=auto (CUDA when "
            "present) or device=cpu"
        )


def compose_run(overrides: list[str]) -> Run:
    """conf/config.yaml with ``overrides``, validated, as a typed ``Run``; an override Hydra cannot apply
    (unknown key, wrong type) or a bad value exits with one line (status 2)."""
    register_configs()
    try:
        with initialize_config_dir(str(CONF), version_base="1.3"):
            cfg = compose("config", overrides=overrides)
        return validate(cfg)
    except (HydraException, ConfigError) as err:
        print(error_line(err), file=sys.stderr)
        raise SystemExit(2) from None
