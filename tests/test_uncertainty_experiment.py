"""pipeline/experiments/uncertainty.py: PROTOCOL 4.4's stand-alone uncertainty experiment (one-sided training set,
every method's score against the per-pixel error on the evaluation views)."""

import argparse
import json
import math

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nvf.cameras import look_at
from pipeline.experiments import uncertainty
from pipeline.experiments.options import seed_list
from pipeline.experiments.uncertainty import S, least_seen_view, main, partial_views
from pipeline.scenes.loading import load_scene
from pipeline.scenes.scene import SceneError


def test_hotdog_partial_views_follow_protocol_4_4(assets_dir):
    scene = load_scene("hotdog", assets_dir)
    poses = partial_views(scene, torch.Generator().manual_seed(0))
    assert poses.shape == (20, 4, 4)
    dirs = poses[:, :3, 3] / torch.tensor([1.5, 1.5, 1.7], dtype=poses.dtype)  # position = (1.5, 1.5, 1.7) ⊙ dir
    torch.testing.assert_close(torch.linalg.norm(dirs, dim=-1), torch.ones(20, dtype=poses.dtype))
    theta, phi = torch.atan2(dirs[:, 1], dirs[:, 0]), torch.acos(dirs[:, 2])
    assert (theta.abs() <= math.pi / 4).all() and (phi >= math.pi / 4).all() and (phi <= math.pi / 2).all()
    assert theta.max() - theta.min() > math.pi / 4  # one side, but spread over it
    forward = -poses[:, :3, 2]  # each camera looks at a target in [-1/2, 1/2]^2 x [0, 1/2]: towards the object
    assert (torch.nn.functional.cosine_similarity(forward, -poses[:, :3, 3], dim=-1) > 0.7).all()
    torch.testing.assert_close(poses, partial_views(scene, torch.Generator().manual_seed(0)))
    assert not torch.allclose(poses, partial_views(scene, torch.Generator().manual_seed(1)))


def test_hubble_partial_views_and_other_scenes(assets_dir):
    hubble = load_scene("hubble", assets_dir)
    positions = partial_views(hubble, torch.Generator().manual_seed(0))[:, :3, 3]
    dirs = (positions / S - torch.tensor([0.0, 0.0, 3.0], dtype=positions.dtype)) / torch.tensor([10.0, 10.0, 15.0])
    torch.testing.assert_close(torch.linalg.norm(dirs, dim=-1), torch.ones(20, dtype=positions.dtype))
    assert (dirs[:, 0] >= 0).all() and (dirs[:, 1] >= 0).all()  # theta in [0, pi/2]
    room = load_scene("room", assets_dir)
    torch.testing.assert_close(partial_views(room, torch.Generator()), room.init_poses)
    with pytest.raises(SceneError, match="hubble, hotdog and room only"):
        partial_views(load_scene("default", assets_dir), torch.Generator())


def test_figure_shows_the_evaluation_view_looking_most_unlike_every_training_view(assets_dir):
    origin = torch.zeros(3)
    ring = torch.stack([look_at(torch.tensor([math.cos(a), math.sin(a), 0.3]), origin) for a in (0.0, 1.5, 3.0, 4.5)])
    assert least_seen_view(ring, ring[:1]) == 2  # the camera opposite the only training view
    assert least_seen_view(ring, ring[[0, 2]]) in (1, 3)  # both 1.5 rad from the nearest training view
    scene = load_scene("hotdog", assets_dir)
    train = partial_views(scene, torch.Generator().manual_seed(0))
    view = least_seen_view(scene.eval_poses, train)
    seen_side = torch.nn.functional.normalize(train[:, :2, 3].mean(0), dim=0)
    assert float(scene.eval_poses[view, :2, 3] @ seen_side) < 0  # on Hotdog's unseen half


def test_experiment_writes_every_entry_and_shares_nvf_model_with_its_ablations(assets_dir, tmp_path):
    tiny = ["budget=smoke", "train.backbone.iters=4", "train.variance.iters=1", "train.visibility.iters=1"]
    args = ["--out", str(tmp_path), "--entries", "wd,nvf-wo_vis,nvf", "--seeds", "100,101"]
    assert main([*tiny, f"paths.assets={assets_dir}", *args]) == 0
    # never the plain budget's or the whole experiment's files
    name = "hotdog_smoke+train.backbone.iters=4+train.variance.iters=1+train.visibility.iters=1"
    name += "+entries=nvf,nvf-wo_vis,wd+seeds=100,101"
    report = json.loads((tmp_path / f"{name}.json").read_text())
    rows = {row["label"]: row for row in report["rows"]}
    assert list(rows) == ["NVF", "w/o Vis.", "WD"] and report["partial_views"] == 20
    hotdog = load_scene("hotdog", assets_dir)
    train = partial_views(hotdog, torch.Generator().manual_seed(0))
    assert report["figure_view"] == least_seen_view(hotdog.eval_poses, train)
    assert rows["NVF"]["trained_as"] == rows["w/o Vis."]["trained_as"] == "nvf/none"  # ablations change the score only
    assert rows["WD"]["trained_as"] == "wd/none"
    assert rows["NVF"]["psnr"] == rows["w/o Vis."]["psnr"]  # the same model
    assert all(math.isfinite(row["patch_pearson"]) and -1 <= row["patch_pearson"] <= 1 for row in rows.values())
    assert rows["NVF"]["patch_pearson"] != rows["w/o Vis."]["patch_pearson"]  # but a different score
    # a row is the mean and population std over the seeds, and keeps each seed's numbers
    assert report["seeds"] == [100, 101] and report["torch_threads"] >= 1
    for row in rows.values():
        per_seed = [run["patch_pearson"] for run in row["seeds"]]
        assert [run["seed"] for run in row["seeds"]] == [100, 101]
        assert row["patch_pearson"] == pytest.approx(np.mean(per_seed))
        assert row["patch_pearson_std"] == pytest.approx(np.std(per_seed))
    assert rows["NVF"]["seeds"][0]["psnr"] != rows["NVF"]["seeds"][1]["psnr"]  # another seed trains another model
    first = rows["NVF"]["seeds"][0]
    assert first["view_error"] == rows["w/o Vis."]["seeds"][0]["view_error"] and len(first["view_error"]) == 20
    assert first["view_score"] != rows["w/o Vis."]["seeds"][0]["view_score"]  # the per-view sums the view r pairs
    table = (tmp_path / f"{name}.md").read_text()
    assert "| w/o Vis. |" in table and "patch r" in table and " ± " in table
    assert iio.imread(tmp_path / f"{name}.png").ndim == 3


def exit_code(argv: list[str]) -> int:
    """``main``'s exit status: bad input raises SystemExit (one line on stderr, pipeline.cli)."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    return info.value.code


def test_entries_select_a_subset_in_table_order_and_unknown_names_are_refused(capsys):
    assert uncertainty.select_entries(None) == uncertainty.ENTRIES
    assert uncertainty.select_entries(["air", "nvf-loose"]) == (("nvf", "loose"), ("air", "none"))
    for bad in (["nvf-wo_opt"], []):
        with pytest.raises(uncertainty.ArgumentError, match="choose from nvf,nvf-wo_vis"):
            uncertainty.select_entries(bad)
    assert exit_code(["--entries", "nvf,vnf"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "error: --entries: unknown ['vnf']; choose from "
        + ",".join(uncertainty.entry_name(*entry) for entry in uncertainty.ENTRIES)
    ]


def test_seeds_are_distinct_integers_and_a_seed_override_is_refused(capsys):
    assert seed_list("7,3") == (7, 3)
    for bad in ("100,100", "1,x", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="distinct integers"):
            seed_list(bad)
    assert exit_code(["--seeds", "100,100"]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(
        "error: python -m pipeline.experiments.uncertainty: argument --seeds: '100,100': give distinct"
    )
    assert exit_code(["seed=101"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: a seed= override: the experiment's seeds are --seeds (default 100,101,102)"
    ]


def test_unknown_scene_is_one_line_and_status_2(assets_dir, capsys):
    assert exit_code(["scene=default", f"paths.assets={assets_dir}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: PROTOCOL 4.4 defines the partial training set")


def test_a_killed_experiment_resumes_at_its_first_missing_seed(assets_dir, tmp_path, monkeypatch):
    """Each finished seed is kept beside the files; a re-run scores only the missing seeds and then
    removes them. Nothing is written until every seed is done."""
    args = ["budget=smoke", "train.backbone.iters=2", f"paths.assets={assets_dir}", "--out", str(tmp_path)]
    args += ["--entries", "wd", "--seeds", "100,101"]
    real, scored = uncertainty.score_seed, []

    def killed_at_101(overrides, seed, *rest):
        if seed == 101:
            raise KeyboardInterrupt
        scored.append(seed)
        return real(overrides, seed, *rest)

    monkeypatch.setattr(uncertainty, "score_seed", killed_at_101)
    with pytest.raises(KeyboardInterrupt):
        main(args)
    name = "hotdog_smoke+train.backbone.iters=2+entries=wd+seeds=100,101"
    assert [p.name for p in (tmp_path / f".{name}.seeds").iterdir()] == ["seed_100.npz"]
    assert not (tmp_path / f"{name}.json").exists()

    def counted(overrides, seed, *rest):
        scored.append(seed)
        return real(overrides, seed, *rest)

    monkeypatch.setattr(uncertainty, "score_seed", counted)
    assert main(args) == 0
    assert scored == [100, 101]  # seed 100 was not scored again
    report = json.loads((tmp_path / f"{name}.json").read_text())
    assert [run["seed"] for run in report["rows"][0]["seeds"]] == [100, 101] and report["seconds"] > 0
    assert not (tmp_path / f".{name}.seeds").exists()


def test_a_row_is_the_mean_and_population_std_over_the_seeds_that_have_the_number():
    runs = [
        {"seed": 100, "trained_as": "nvf/none", "psnr": 10.0, "lpips": None, "ause": math.nan, "view_error": [1.0]},
        {"seed": 101, "trained_as": "nvf/none", "psnr": 14.0, "lpips": 0.2, "ause": math.nan, "view_error": [2.0]},
    ]
    row = uncertainty.summary(runs)
    assert (row["psnr"], row["psnr_std"]) == (12.0, 2.0)
    assert (row["lpips"], row["lpips_std"]) == (
        0.2,
        0.0,
    )  # a missing value (None, as a saved seed keeps NaN) is skipped
    assert math.isnan(row["ause"]) and math.isnan(row["ause_std"])
    assert "seed" not in row and "view_error" not in row and row["seeds"] == runs
