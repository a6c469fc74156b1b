"""Settings a run record holds beyond its named config groups: what ``budget=cpu planner.num_candidates=512``
adds to ``budget=cpu``, so that a table never labels such a run as plain ``cpu``."""

import functools
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import HydraException
from omegaconf import OmegaConf

from pipeline.config.structured_configs import register_configs
from pipeline.records import compat
from pipeline.records.compat import drop_not_settings, drop_retired, with_legacy_defaults
from pipeline.records.store import to_jsonable
from pipeline.repo import CONF

GROUPS = ("scene", "method", "planner", "ablation", "budget")
LOCATIONS = ("paths", "seed")  # where files live; the seed is an identity key


def changed_settings(recorded: Any, named: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """``(dotted key, recorded value)`` wherever the record has a value that differs from ``named``;
    keys the record lacks (added to the code after the run) are not changes."""
    if isinstance(recorded, dict) and isinstance(named, dict):
        return [
            c for key in sorted(recorded) for c in changed_settings(recorded[key], named.get(key), f"{prefix}{key}.")
        ]
    return [] if recorded == named else [(prefix.rstrip("."), recorded)]


def _text(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


class NamedConfigs:
    """Today's resolved config of each combination of named groups under ``conf_dir``, composed once."""

    def __init__(self, conf_dir: Path):
        self.conf_dir = Path(conf_dir)
        self.named = functools.lru_cache(maxsize=None)(self._compose)
        register_configs()

    def _compose(self, groups: tuple[str, ...]) -> dict | None:
        overrides = [f"{group}={name}" for group, name in zip(GROUPS, groups, strict=True)]
        try:
            if GlobalHydra.instance().is_initialized():
                cfg = compose("config", overrides=overrides)
            else:
                with initialize_config_dir(str(self.conf_dir.resolve()), version_base="1.3"):
                    cfg = compose("config", overrides=overrides)
        except HydraException:
            return None  # a group that no longer exists: nothing to compare against
        return to_jsonable(OmegaConf.to_container(cfg, resolve=True))

    def budget_label(self, info: Mapping) -> str:
        """The record's budget plus its ``overrides`` (``cpu+planner.num_candidates=512``): what tables and
        reports call its budget, so a run with other settings is never labelled as the plain budget."""
        return "+".join([str(info["budget"]), *self.overrides(info)])

    def overrides(self, info: Mapping) -> tuple[str, ...]:
        """``key=value`` (sorted) for every setting in the record's config whose value differs from what
        its named groups give today: command-line overrides, or defaults changed since the run (a key
        added since is read as the value the run was made with, ``pipeline.records.compat``), except
        settings the run's method cannot read (``compat.inert_keys``: ``nvf.entropy.logdet_coeff=1.0`` on a
        WD run). Empty when its groups can no longer be composed."""
        named = self.named(tuple(str(info[group]) for group in GROUPS))
        config = info.get("config")
        if named is None or not isinstance(config, Mapping):
            return ()
        recorded = {
            k: v for k, v in drop_not_settings(drop_retired(to_jsonable(dict(config)))).items() if k not in LOCATIONS
        }
        recorded = with_legacy_defaults(recorded, named)  # keys added since the run: the value it was made with
        inert = compat.inert_keys(recorded)  # settings the run's method cannot read do not make it another run
        changed = changed_settings(recorded, named)
        return tuple(f"{key}={_text(value)}" for key, value in changed if not compat.is_inert(key, inert))


def config_label(composed: Mapping[str, Any]) -> str:
    """A composed config's (plain data, ``Run.composed``) budget plus every setting beyond its named groups
    (``cpu+train.precision=bf16``), as the tables label runs (``NamedConfigs.budget_label``; the diagnostics and
    ``save_images`` are not settings), so another setting never shares the plain budget's files."""
    info = {group: composed[group]["name"] for group in GROUPS} | {"config": dict(composed)}
    return NamedConfigs(CONF).budget_label(info)
