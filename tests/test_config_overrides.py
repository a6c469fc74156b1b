"""pipeline.config.validation.compose_run outside @hydra.main (kept apart from test_config.py, whose module fixture
holds Hydra's global state): every bad override is one line and status 2."""

import pytest

from pipeline.config.validation import compose_run
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
        ("method=fvs ablation=wo_vis", "ablation=wo_vis ablates method=nvf, not method=fvs"),  # else FVS, tabled apart
        ("method.label=", "method.label is empty"),  # else tabled as the bare mark
    ],
)
def test_compose_run_exits_with_one_line_on_any_bad_override(override, needle, capsys):
    with pytest.raises(SystemExit) as exit_info:
        compose_run(override.split())
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0]


HOSTILE_VALUES = [
    ("case_5_negative_seed", "seed=-1", "error: seed -1 is not an integer from 0 to 2^63-1"),
    (
        "case_5_seed_beyond_int64",
        "seed=99999999999999999999",
        "error: seed 99999999999999999999 is not an integer from 0",
    ),
    (
        "case_6_horizon_of_a_billion_steps",
        "budget.horizon=1000000000",
        "error: budget.horizon=1000000000 is more than 1000 steps",
    ),
    (
        "case_6_a_billion_label_samples",
        "train.label_samples=1000000000",
        "error: train.label_samples=1000000000 is more than 65536 samples per segment",
    ),
    ("case_9_unknown_plus_key", "+no_such_key=1", "error: unknown key 'no_such_key' (added with +no_such_key=...)"),
    (
        "case_9_unknown_plus_key_in_a_group",
        "+train.backbone.momentum=0.9",
        "error: unknown key 'train.backbone.momentum'",
    ),
    ("a_name_too_long_for_a_run_directory", "budget.name=" + "b" * 65, "has 65 characters, more than 64"),
    ("a_blender_timeout_of_zero", "render.timeout=0", "error: render.timeout=0.0 must be positive"),
    ("a_density_lattice_of_a_million", "train.label_lattice=1000000", "error: train.label_lattice=1000000 must be"),
    (
        "a_density_lattice_above_a_gibibyte",
        "budget=paper train.label_lattice=6",
        "a lattice of more than 268435456 vertices; lower train.label_lattice",
    ),
]


@pytest.mark.parametrize(("override", "needle"), [h[1:] for h in HOSTILE_VALUES], ids=[h[0] for h in HOSTILE_VALUES])
def test_bad_values_are_one_error_line_before_anything_runs(override, needle, capsys):
    """A negative or out-of-int64 seed was a traceback, a billion label samples or steps were
    accepted, ``+no_such_key=1`` was stored silently. Each is now one ``error:`` line, status 2."""
    with pytest.raises(SystemExit) as exit_info:
        compose_run(override.split())
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err


def test_overrides_that_agree_with_the_ablation_compose():
    assert compose_run(["ablation=ind_rays", "nvf.entropy.d0=0"]).nvf.entropy.d0 == 0.0
    auto = compose_run(["ablation=none", "nvf.entropy.d0=auto"])  # no ablation to undo
    assert auto.composed["nvf"]["entropy"]["d0"] == "auto"


@pytest.mark.parametrize("d0, want", [(None, 1.0), ("auto", 0.25 * 2.8152), (0.5, 0.5), (2, 2.0)])
def test_d0_resolves_to_the_scene_value_auto_or_the_number_given(d0, want):
    """(M13, METHOD 8) ``nvf.entropy.d0``: null = the scene's 1.0 (D4), auto = 0.25 x the diagonal of the
    default scene's object box (1.92 x 1.92 x 0.744), a number as given; the scorer gets a float."""
    overrides = [] if d0 is None else [f"nvf.entropy.d0={d0}"]
    settings = EpisodeSettings.of(compose_run(overrides), load_scene("default"))
    assert isinstance(settings.entropy.d0, float)
    assert settings.entropy.d0 == pytest.approx(want, abs=1e-4)
    assert settings.method.name == "nvf" and settings.scorer().d0 == settings.entropy.d0


@pytest.mark.parametrize(
    "overrides, stages",
    [
        ([], ("backbone", "variance", "visibility")),
        (["ablation=wo_vis"], ("backbone", "variance")),
        (["ablation=wo_vis", "train.stage_order=vis_first"], ("backbone", "visibility", "variance")),
        (["ablation=ind_rays"], ("backbone", "variance", "visibility")),
        (["method=wd"], ("backbone",)),
    ],
)
def test_a_step_trains_the_stages_its_scores_read(overrides, stages):
    """METHOD 11: w/o Vis. trains no visibility head where nothing reads it (``nvf.training.stages_to_train``)."""
    assert EpisodeSettings.of(compose_run(overrides), load_scene("default")).stages == stages


def test_a_scene_asset_path_is_read_as_its_normal_form_and_an_empty_one_is_refused(tmp_path):
    """``scene.asset`` written with a leading ``./`` missed the declared file's up axis (Y) and read the metric mesh
    Z-up; ``scene.asset=""`` was accepted as no file."""
    import dataclasses

    from pipeline.scenes.loading import _mesh_candidates
    from pipeline.scenes.scene import SceneError

    room = compose_run(["scene=room"]).scene
    cfg = {
        "name": "room",
        "files": [{"path": "room/room_nvf_gt_yup.obj", "up": "y"}],
        "asset": "./room/room_nvf_gt_yup.obj",
    }
    assert _mesh_candidates(cfg, tmp_path) == [(tmp_path / "room" / "room_nvf_gt_yup.obj", "y")]
    with pytest.raises(SceneError, match="scene.asset is empty"):
        load_scene(dataclasses.asdict(room) | {"asset": " "}, tmp_path)


def test_an_unknown_option_of_the_run_command_is_one_line(capsys, monkeypatch):
    """``python -m pipeline.run --bogus`` printed Hydra's eight-line usage; now one line and exit 2."""
    import sys

    from pipeline import run

    monkeypatch.setattr(sys, "argv", ["pipeline.run", "--bogus", "seed=1"])
    with pytest.raises(SystemExit) as exit_info:
        run.hydra_main()
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(err) == 1 and "unknown option --bogus" in err[0]
    assert run.unknown_flag(["-m", "seed=-1", "--cfg", "job"]) is None
