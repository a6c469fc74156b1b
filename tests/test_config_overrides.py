"""pipeline.config.validation.compose_config outside @hydra.main (kept apart from test_config.py, whose module fixture
holds Hydra's global state): every bad override is one line and status 2."""

import pytest

from nvf.methods import NVF
from pipeline.config.validation import compose_config
from pipeline.episode.settings import EpisodeSettings
from pipeline.scenes.loading import load_scene


@pytest.mark.parametrize(
    "override, needle",
    [
        ("nvf.entropy.d0=automatic", "nvf.entropy.d0=automatic must be a number >= 0 (0 = Ind. Rays), auto"),
        ("nvf.entropy.d0=-1", "nvf.entropy.d0=-1 must be a number >= 0"),
        ("nvf.entropy.use_visibility=maybe", "nvf.entropy.use_visibility=maybe: Value 'maybe' is not a valid bool"),
        ("nosuch.key=1", "Could not override 'nosuch.key'"),
        ("budget=nosuch", "Could not find 'budget/nosuch'"),
        ("train.backbone.iters=0", "train.backbone.iters=0 must be positive"),
        ("ablation=ind_rays nvf.entropy.d0=auto", "sets nvf.entropy.d0=0.0, but an override made it auto"),
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
    assert compose_config(["ablation=none", "nvf.entropy.d0=auto"]).nvf.entropy.d0 == "auto"  # no ablation to undo


@pytest.mark.parametrize("d0, want", [(None, 1.0), ("auto", 0.25 * 2.8152), (0.5, 0.5), (2, 2.0)])
def test_d0_resolves_to_the_scene_value_auto_or_the_number_given(d0, want):
    """(M13, METHOD 8) ``nvf.entropy.d0``: null = the scene's 1.0 (D4), auto = 0.25 x the diagonal of the
    default scene's object box (1.92 x 1.92 x 0.744), a number as given; the scorer gets a float."""
    overrides = [] if d0 is None else [f"nvf.entropy.d0={d0}"]
    settings = EpisodeSettings.of(compose_config(overrides), load_scene("default"))
    assert isinstance(settings.entropy.d0, float)
    assert settings.entropy.d0 == pytest.approx(want, abs=1e-4)
    assert settings.scorer(NVF()).d0 == settings.entropy.d0
