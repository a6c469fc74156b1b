"""pipeline/config/settings_beyond_groups.py: the settings a run record holds beyond its named config groups."""

import copy

from hydra import compose, initialize_config_dir

from pipeline.config.settings_beyond_groups import NamedConfigs
from pipeline.config.validation import typed_run
from pipeline.episode.runner import run_settings
from pipeline.repo import CONF

GROUPS = ["scene=default", "method=nvf", "planner=argmax", "ablation=none", "budget=smoke", "seed=101"]


def _info(*overrides: str) -> dict:
    """run.json's identity and config for a run made with the named groups plus ``overrides``."""
    with initialize_config_dir(str(CONF), version_base="1.3"):
        return run_settings(typed_run(compose("config", overrides=[*GROUPS, *overrides, "paths.outputs=/elsewhere"])))


def test_a_run_of_the_named_groups_has_no_overrides():
    assert NamedConfigs(CONF).overrides(_info()) == ()  # seed and paths are not settings


def test_command_line_overrides_are_found_with_their_recorded_values():
    info = _info("planner.num_candidates=9", "nvf.entropy.corr=exp")
    assert NamedConfigs(CONF).overrides(info) == ("nvf.entropy.corr=exp", "planner.num_candidates=9")


def test_keys_a_record_lacks_are_not_overrides_and_unknown_groups_give_none():
    info = _info()
    older = copy.deepcopy(info)
    del older["config"]["planner"]["los_unobserved_free"]  # a key added to the code after this run
    named = NamedConfigs(CONF)
    assert named.overrides(older) == ()
    assert named.overrides({**info, "scene": "no_such_scene"}) == ()


def test_settings_a_method_cannot_read_do_not_split_its_rows():
    """``compat.inert_keys``: NVF's entropy keys do not act on WD (no NVF score, no variance head), the
    visibility head's keys and the visibility source not on w/o Vis. (it reads no v); on NVF they do. With
    ``train.stage_order=vis_first`` the trained visibility head feeds the variance head w/o Vis. reads."""
    named = NamedConfigs(CONF)
    c1, margin = "nvf.entropy.logdet_coeff=1.0", "train.label_margin=0.2"
    assert named.overrides(_info("method=wd", c1, margin)) == ()
    assert named.overrides(_info("ablation=wo_vis", margin, "nvf.entropy.visibility_source=labels")) == ()
    assert named.overrides(_info("ablation=wo_vis", c1)) == ("nvf.entropy.logdet_coeff=1.0",)
    assert named.overrides(_info(c1, margin)) == ("nvf.entropy.logdet_coeff=1.0", "train.label_margin=0.2")
    vis_first = _info("ablation=wo_vis", margin, "train.stage_order=vis_first")
    assert named.overrides(vis_first) == ("train.label_margin=0.2", "train.stage_order=vis_first")
    assert named.overrides(_info("method=activenerf", "train.variance.iters=7")) == ()
