"""pipeline.config.compose_config outside @hydra.main (kept apart from test_config.py, whose module fixture
holds Hydra's global state): every bad override is one line and status 2."""

import pytest

from pipeline.config import compose_config


@pytest.mark.parametrize(
    "override, needle",
    [
        ("nvf.entropy.d0=auto", "nvf.entropy.d0=auto: Value 'auto' of type 'str' could not be converted to Float"),
        ("nosuch.key=1", "Could not override 'nosuch.key'"),
        ("budget=nosuch", "Could not find 'budget/nosuch'"),
        ("train.backbone.iters=0", "train.backbone.iters=0 must be positive"),
        ("ablation=ind_rays nvf.entropy.d0=-1", "sets nvf.entropy.d0=0.0, but an override made it -1"),
        ("ablation=wo_vis nvf.entropy.use_visibility=true", "ablation=wo_vis sets nvf.entropy.use_visibility=False"),
    ],
)
def test_compose_config_exits_with_one_line_on_any_bad_override(override, needle, capsys):
    with pytest.raises(SystemExit) as exit_info:
        compose_config(override.split())
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0]


def test_overrides_that_agree_with_the_ablation_compose():
    assert compose_config(["ablation=ind_rays", "nvf.entropy.d0=0"]).nvf.entropy.d0 == 0.0
    assert compose_config(["ablation=none", "nvf.entropy.d0=-1"]).nvf.entropy.d0 == -1.0  # no ablation to undo
