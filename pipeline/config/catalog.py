"""What ``conf/`` declares: the methods, ablations and scenes, one yaml each. Commands that need "every
method" or "every ablation" (the uncertainty experiment, the benchmarks, tests) read them here instead of
keeping lists of their own, and the experiments sweep the methods and scenes that declare them
(``${declared:GROUP,EXPERIMENT}``, ``members``). No heavy imports."""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from pipeline.config.plain_containers import as_dict
from pipeline.repo import CONF


def declared(group: str, conf_dir: Path = CONF) -> list[str]:
    """The options of a config group: the yaml file names under ``conf_dir/group``, sorted."""
    return sorted(path.stem for path in (Path(conf_dir) / group).glob("*.yaml"))


def method_configs(conf_dir: Path = CONF) -> dict[str, dict[str, Any]]:
    """Each method's yaml (name, label, rank, implementation, stages), in table order (``rank``)."""
    configs = {
        name: as_dict(OmegaConf.load(Path(conf_dir) / "method" / f"{name}.yaml"), resolve=False)
        for name in declared("method", conf_dir)
    }
    return dict(sorted(configs.items(), key=lambda item: (item[1].get("rank", 100), item[0])))


def ablation_configs(conf_dir: Path = CONF) -> dict[str, dict[str, Any]]:
    """Each ablation's ``ablation`` node (name, label, rank), in Table S2's order (``rank``)."""
    configs = {
        name: as_dict(OmegaConf.load(Path(conf_dir) / "ablation" / f"{name}.yaml"), resolve=False)["ablation"]
        for name in declared("ablation", conf_dir)
    }
    return dict(sorted(configs.items(), key=lambda item: (item[1].get("rank", 100), item[0])))


def study_defaults(name: str, conf_dir: Path = CONF) -> dict[str, Any]:
    """A study's defaults, ``conf/study/<name>.yaml`` as plain data (its scenes, steps, contenders, ...): each study's
    parameters declared once, in a file, not in its code."""
    return as_dict(OmegaConf.load(Path(conf_dir) / "study" / f"{name}.yaml"), resolve=False)


def contender_label(name: str, conf_dir: Path = CONF) -> str:
    """How tables name a contender of the duel or the paper states: an ablation's label (``w/o Vis.``) or a method's
    (``FVS (facing)``); a name ``conf_dir`` does not declare (a user's own method) as it is."""
    ablations = ablation_configs(conf_dir)
    if name in ablations:
        return str(ablations[name]["label"])
    return str(method_configs(conf_dir).get(name, {}).get("label", name))


def conf_dirs(searchpath: Sequence[str] = ()) -> list[Path]:
    """``conf/`` and the config directories of a Hydra ``hydra.searchpath`` (its ``file://DIR`` entries), in the
    order Hydra looks in them."""
    return [CONF, *(Path(entry.removeprefix("file://")) for entry in searchpath if entry.startswith("file://"))]


def searchpath_override(overrides: Sequence[str]) -> list[str]:
    """The command line's ``hydra.searchpath=[...]`` override alone (an empty list without one): what a config of
    the command's own methods and scenes needs beyond the project's ``conf/``, without its other settings."""
    return [o for o in overrides if o.partition("=")[0].lstrip("+") == "hydra.searchpath"]


def searchpath_of(overrides: Sequence[str]) -> list[str]:
    """The entries of a command line's ``hydra.searchpath=[...]`` override (none without one): where a user's own
    methods and scenes are declared, as ``pipeline.run`` reads them."""
    found = searchpath_override(overrides)
    if not found:
        return []
    value = found[0].partition("=")[2]
    return [entry.strip().strip("'\"") for entry in value.strip().strip("[]").split(",") if entry.strip()]


def option_problem(group: str, name: str, dirs: Sequence[Path]) -> str | None:
    """Why ``name`` is no option of ``group`` in any of ``dirs`` (``conf_dirs``: the project's and a search path's),
    listing the options each directory declares; None when one declares it."""
    found = {Path(d): declared(group, d) for d in dirs}
    if any(name in names for names in found.values()):
        return None
    listed = "; ".join(f"{', '.join(names)} ({folder / group})" for folder, names in found.items() if names)
    outside = "" if len(found) > 1 else "; a config directory of your own joins with hydra.searchpath=[file://DIR]"
    return f"unknown {group} {name!r}: choose one of {listed}{outside}"


def members(group: str, experiment: str, dirs: Sequence[Path] = (CONF,)) -> list[str]:
    """The options of ``group`` (``method`` or ``scene``) whose yaml lists ``experiment`` under ``experiments``
    (an option found in an earlier directory of ``dirs`` hides one of the same name in a later one), sorted."""
    found: dict[str, bool] = {}
    for conf_dir in dirs:
        for name in declared(group, conf_dir):
            if name not in found:
                node = as_dict(OmegaConf.load(Path(conf_dir) / group / f"{name}.yaml"), resolve=False)
                found[name] = experiment in (node.get("experiments") or [])
    return sorted(name for name, joins in found.items() if joins)


def _declared_members(group: str, experiment: str, *, _root_: Any) -> str:
    """The resolver ``${declared:GROUP,EXPERIMENT}``: ``members`` as a Hydra sweep's comma-separated values,
    read from ``conf/`` and the run's ``hydra.searchpath``."""
    searchpath = OmegaConf.select(_root_, "hydra.searchpath", default=None) or []
    found = members(group, experiment, conf_dirs(list(searchpath)))
    if not found:
        raise ValueError(f"no {group} declares experiments: [{experiment}] (conf/{group}/<name>.yaml)")
    return ",".join(found)


def register_resolvers() -> None:
    """Register ``${declared:GROUP,EXPERIMENT}`` (the experiments' sweeps) with OmegaConf, once."""
    if not OmegaConf.has_resolver("declared"):
        OmegaConf.register_new_resolver("declared", _declared_members)
