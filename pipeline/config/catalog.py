"""What ``conf/`` declares: the methods, ablations and scenes, one yaml each. Commands that need "every
method" or "every ablation" (the uncertainty experiment, the benchmarks, tests) read them here instead of
keeping lists of their own. No heavy imports."""

from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from pipeline.repo import CONF


def declared(group: str, conf_dir: Path = CONF) -> list[str]:
    """The options of a config group: the yaml file names under ``conf_dir/group``, sorted."""
    return sorted(path.stem for path in (Path(conf_dir) / group).glob("*.yaml"))


def method_configs(conf_dir: Path = CONF) -> dict[str, dict[str, Any]]:
    """Each method's yaml (name, label, rank, implementation, stages), in table order (``rank``)."""
    configs = {name: OmegaConf.to_container(OmegaConf.load(Path(conf_dir) / "method" / f"{name}.yaml"))
               for name in declared("method", conf_dir)}  # fmt: skip
    return dict(sorted(configs.items(), key=lambda item: (item[1].get("rank", 100), item[0])))


def ablation_configs(conf_dir: Path = CONF) -> dict[str, dict[str, Any]]:
    """Each ablation's ``ablation`` node (name, label, rank), in Table S2's order (``rank``)."""
    configs = {name: OmegaConf.to_container(OmegaConf.load(Path(conf_dir) / "ablation" / f"{name}.yaml"))["ablation"]
               for name in declared("ablation", conf_dir)}  # fmt: skip
    return dict(sorted(configs.items(), key=lambda item: (item[1].get("rank", 100), item[0])))
