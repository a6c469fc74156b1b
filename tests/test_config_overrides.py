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
    ],
)
def test_compose_config_exits_with_one_line_on_any_bad_override(override, needle, capsys):
    with pytest.raises(SystemExit) as exit_info:
        compose_config([override])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0]
