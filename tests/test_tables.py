"""pipeline/tables/: long CSV, aggregation over seeds at the last step, paper-style tables, figures."""

import json
import os
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pandas as pd
import pytest

from pipeline.config.settings_beyond_groups import NamedConfigs
from pipeline.config.validation import compose_run
from pipeline.records.store import DIGEST_KEY, RunRecord, record_digest, run_dir
from pipeline.repo import CONF, REPO
from pipeline.tables import build, escape
from pipeline.tables.__main__ import main
from pipeline.tables.build import build_tables
from pipeline.tables.figures import image_grid, safe_name
from pipeline.tables.labels import row_name
from pipeline.tables.load import LONG_COLUMNS
from pipeline.tables.paper import paper_numbers
from pipeline.tables.summary import summarize_run

METRICS = ("psnr", "ssim", "lpips", "rgb", "acc", "comp", "cr", "vis")
POSE = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0]


def make_run(
    root: Path,
    scene="hubble",
    method="nvf",
    planner="argmax",
    ablation="none",
    seed=100,
    final=None,
    status="done",
    lpips_reason=None,
    steps=3,
    config=None,
    source=None,
    ground_truth=None,
    extra=None,
    repo=None,
) -> RunRecord:
    """A synthetic run: `steps` step rows (smoke's horizon, 3), the last one carrying `final` metric values
    (others 0); its config's horizon is `steps` unless `config` sets one."""
    record = RunRecord(run_dir(root, scene, method, planner, ablation, "smoke", seed))
    source = source or ("proxy" if scene.endswith("_proxy") else "mesh")
    keys = {"scene": scene, "method": method, "planner": planner, "ablation": ablation, "budget": "smoke", "seed": seed}
    config = dict(config or {})
    config["budget"] = {"horizon": steps, **config.get("budget", {})}
    info = {**keys, "scene_source": source, "field": "densegrid", "device": "cpu", "config": config}
    if ground_truth is not None:
        info["ground_truth"] = ground_truth
    info["lpips_missing_reason"] = lpips_reason
    record.start({**info, **(extra or {})}, repo=repo or root)
    base = {m: 0.5 for m in METRICS}
    for step in range(steps):
        metrics = {**base, **(final or {})} if step == steps - 1 else {m: 0.0 for m in METRICS}
        if lpips_reason:
            metrics["lpips"] = None
        row = {
            "step": step,
            "n_views": 3 + step,
            "status": "ok",
            "metrics": {**metrics, "vis_area": 0.1},
            "selected_pose": POSE,
        }
        record.append_step(row)
    if status == "done":
        record.mark_done()
    elif status == "failed":
        record.mark_failed("step 1: training diverged")
    return record


def read(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def label(method: str, planner: str, ablation: str) -> str:
    cfg = compose_run([f"method={method}", f"planner={planner}", f"ablation={ablation}"])
    return row_name(cfg.composed).label


def test_method_labels():
    """Labels come from the method and ablation yamls; -OPT from the planner's name."""
    assert label("activermap", "argmax", "none") == "ActiveRMAP"
    assert label("neurar", "opt", "none") == "NeurAR-OPT"
    assert label("nvf", "argmax", "ind_rays") == "Ind. Rays"
    assert label("nvf", "argmax", "none") == "NVF"
    ablated = {"method": {"name": "air", "label": "AIR"}, "planner": {"name": "argmax"}}
    ablated["ablation"] = {"name": "wo_vis", "label": "w/o Vis.", "of": "nvf"}  # a record of another method's ablation
    assert row_name(ablated).label == "AIR w/o Vis."


def test_long_csv_has_exactly_the_columns(tmp_path):
    make_run(tmp_path / "out", seed=100)
    make_run(tmp_path / "out", seed=101, status="running")  # unfinished: not in runs.csv
    build_tables(tmp_path / "out", [], tmp_path / "res", figures=False)
    frame = pd.read_csv(tmp_path / "res" / "runs.csv")
    assert tuple(frame.columns) == LONG_COLUMNS
    assert set(frame["seed"]) == {100}
    assert set(frame["metric"]) == {*METRICS, "vis_area"}
    assert sorted(set(frame["step"])) == [0, 1, 2] and sorted(set(frame["n_views"])) == [3, 4, 5]
    assert set(frame["scene_source"]) == {"mesh"}


def test_tables_and_summaries_say_which_file_and_backend_made_the_ground_truth(tmp_path):
    """Each scene's asset file and ground-truth backend in the table header and the run summary; a record
    from before the Blender backend (no ``ground_truth``) is pyrender's."""
    out = tmp_path / "out"
    blender = {"backend": "blender", "asset": "room/room.blend", "samples": 64, "device": "CPU", "blender": "5.0.1"}
    room = make_run(out, scene="room", source="blend", ground_truth=blender)
    make_run(out, scene="hubble")
    build_tables(out, [], tmp_path / "res", figures=False)
    md = read(tmp_path / "res" / "tables" / "all_runs.md")
    assert "room (blend room/room.blend, ground truth Blender Cycles 64 spp)" in md
    assert "hubble (mesh, ground truth pyrender)" in md
    summary = read(summarize_run(room.directory))
    assert "Scene source: blend (room/room.blend). Ground truth: Blender Cycles 64 spp." in summary


def test_aggregation_mean_population_std_best_and_n(tmp_path):
    out = tmp_path / "out"
    for seed, psnr in zip((100, 101, 102), (20.0, 21.0, 23.0), strict=True):
        make_run(out, method="nvf", seed=seed, final={"psnr": psnr, "lpips": 0.1, "rgb": 0.02})
        make_run(out, method="random", seed=seed, final={"psnr": 15.0, "lpips": 0.3, "rgb": 0.01})
    written, skipped = build_tables(out, [], tmp_path / "res")
    assert not skipped
    md = read(tmp_path / "res" / "tables" / "main.md")
    std = np.std([20.0, 21.0, 23.0])  # population std, 1.247
    assert f"**21.33 ± {std:.2f}**" in md  # higher PSNR wins
    assert "**0.100 ± 0.000**" in md  # lower LPIPS wins
    assert "**0.0100 ± 0.0000**" in md  # lower RGB wins: Random
    assert "15.00 ± 0.00" in md and "**15.00" not in md
    assert "Budget: smoke." in md and "hubble (mesh, ground truth pyrender)" in md and "step 2" in md
    csv = pd.read_csv(tmp_path / "res" / "tables" / "main.csv", comment="#")
    assert list(csv["Method"]) == ["Random", "NVF"] and list(csv["n"]) == [3, 3]
    assert list(csv.columns[2:10]) == ["PSNR↑", "SSIM↑", "LPIPS↓", "RGB↓", "Acc.↓", "Comp.↓", "C.R.↑", "Vis.↑"]
    tex = read(tmp_path / "res" / "tables" / "main.tex")
    assert r"\textbf{21.33 $\pm$ 1.25}" in tex and r"PSNR$\uparrow$" in tex and r"\end{tabular}" in tex
    assert tmp_path / "res" / "figures" / "curves_hubble_smoke.png" in written


def test_a_best_is_bold_only_where_its_paired_interval_excludes_every_other_row(tmp_path):
    """(Issue: significance in every table.) Hubble: NVF's 3 seeds against Random's one seed in common
    establish nothing (a tie); hotdog: NVF ahead by 1.0, 1.5, 2.0 dB on three seeds (interval [0.26, 2.74])
    is bold, and Random's PSNR difference to NVF is printed with its interval."""
    out = tmp_path / "out"
    for seed, psnr in zip((100, 101, 102), (20.0, 21.0, 23.0), strict=True):
        make_run(out, method="nvf", seed=seed, final={"psnr": psnr})
    make_run(out, method="random", seed=100, final={"psnr": 15.0})
    for seed, gap in zip((100, 101, 102), (1.0, 1.5, 2.0), strict=True):
        make_run(out, method="random", seed=seed, scene="hotdog", final={"psnr": 15.0})
        make_run(out, method="nvf", seed=seed, scene="hotdog", final={"psnr": 15.0 + gap})
    build_tables(out, [], tmp_path / "res", figures=False)
    md = read(tmp_path / "res" / "tables" / "all_runs.md")
    assert "21.33 ± 1.25≈" in md and "**21.33" not in md and "15.00≈" in md  # hubble: tied
    assert "**16.50 ± 0.41**" in md  # hotdog: NVF's lead holds on every seed
    assert "-1.50 [-2.74, -0.26]" in md and "| -5.00 " in md  # one pair: the mean, no interval
    assert "ΔPSNR vs NVF" in md and "Bold: a scene's best mean" in md
    tex = read(tmp_path / "res" / "tables" / "all_runs.tex")
    assert r"$^\approx$" in tex and r"$\Delta$PSNR" in tex


def test_every_table_written_and_no_runs_yet(tmp_path):
    written, _ = build_tables(tmp_path / "missing", [tmp_path / "also_missing"], tmp_path / "res")
    names = ("main", "table1_opt", "table2_ablation", "table34_nerf_assets", "methods", "all_runs", "paper_comparison")
    for name in names:
        for flavor in ("md", "csv", "tex"):
            text = read(tmp_path / "res" / "tables" / f"{name}.{flavor}")
            assert "No runs yet" in text, (name, flavor)
    assert "experiment=table1_opt" in read(tmp_path / "res" / "tables" / "table1_opt.md")
    assert "experiment=methods" in read(tmp_path / "res" / "tables" / "methods.md")
    assert tuple(pd.read_csv(tmp_path / "res" / "runs.csv").columns) == LONG_COLUMNS


def test_nan_metrics_are_footnoted(tmp_path):
    out = tmp_path / "out"
    make_run(out, seed=100, final={"acc": None, "comp": None}, lpips_reason="AlexNet weights unavailable offline")
    make_run(out, seed=101, lpips_reason="AlexNet weights unavailable offline")
    build_tables(out, [], tmp_path / "res", figures=False)
    md = read(tmp_path / "res" / "tables" / "main.md")
    assert "LPIPS missing in 2 of 2 runs: AlexNet weights unavailable offline." in md
    assert "Acc. is NaN/null in 1 of 2 runs" in md
    assert "| 0.5000† |" in md  # Acc is the one seed that has it: no spread to show
    row = [line for line in md.splitlines() if line.startswith("| hubble")][0]
    assert row.split("|")[5].strip() == "-"  # LPIPS column: no value at all


def test_unfinished_and_failed_runs_are_excluded_and_counted(tmp_path):
    out = tmp_path / "out"
    make_run(out, seed=100)
    make_run(out, seed=101, status="running")
    make_run(out, seed=102, status="failed")
    build_tables(out, [], tmp_path / "res", figures=False)
    md = read(tmp_path / "res" / "tables" / "main.md")
    assert "Excluded: 1 unfinished, 1 failed run(s)" in md
    assert "Failed: hubble NVF seed 102 (smoke): step 1: training diverged." in md
    assert "| 1 |" in md.replace("  ", " ").replace("  ", " ")  # n = 1


def test_truncated_steps_and_bad_records_are_skipped_with_the_reason(tmp_path):
    out = tmp_path / "out"
    running = make_run(out, seed=101, status="running")
    partial = read(running.steps_path) + '{"step": 3, "met'  # a kill mid-write: the rows before it count
    running.steps_path.write_text(partial)
    finished = make_run(out, seed=100)
    changed = read(finished.steps_path) + '{"step": 3, "met'  # a finished record does not grow
    finished.steps_path.write_text(changed)
    (out / "junk").mkdir()
    (out / "junk" / "run.json").write_text("{not json")
    written, skipped = build_tables(out, [], tmp_path / "res", figures=False)
    assert read(running.steps_path) == partial and read(finished.steps_path) == changed  # tables never modify records
    assert len(skipped) == 2
    assert "truncated last line" in skipped[0] and "of a finished run" in skipped[0] and "seed_100" in skipped[0]
    assert "junk/run.json: not valid JSON" in skipped[1]
    assert "2 run record(s) skipped: they fail a check" in read(tmp_path / "res" / "tables" / "main.md")
    all_runs = read(tmp_path / "res" / "tables" / "all_runs.md")
    notes = [escape.markdown("Skipped run record: " + line.split(": ", 1)[1] + ".") for line in skipped]
    assert all(f"- {note}" in all_runs for note in notes)
    assert "Excluded: 1 unfinished run(s)" in all_runs


def test_the_same_run_with_other_settings_is_left_out_and_listed(tmp_path):
    first, second = tmp_path / "out", tmp_path / "res" / "runs"
    make_run(first, seed=100, final={"psnr": 30.0}, config={"planner": {"num_candidates": 512}})
    make_run(second, seed=100, final={"psnr": 10.0}, config={"planner": {"num_candidates": 128}})
    make_run(first, seed=101, final={"psnr": 20.0}, config={"planner": {"num_candidates": 512}})
    make_run(second, seed=101, final={"psnr": 20.0}, config={"planner": {"num_candidates": 512}})  # no conflict
    written, lines = build_tables(first, [second], tmp_path / "res", figures=False)
    assert len(lines) == 1
    assert lines[0].startswith(f"left out {second / 'hubble'}")
    assert "the same run as" in lines[0] and "config.planner.num_candidates (128 here, 512 there)" in lines[0]
    md = read(tmp_path / "res" / "tables" / "main.md")
    assert "Budget: smoke+planner.num_candidates=512." in md  # 512 is not smoke's own value (8)
    assert "1 conflict(s) between copies of a run left records out" in md
    assert "25.00 ± 5.00" in md  # seeds 100 (the first root's 30 dB, not 10) and 101 (20 dB)


def test_two_finished_copies_with_different_rows_are_both_named_and_neither_tabulated(tmp_path):
    """A copy of a finished run under another folder with its final PSNR set to 99 and its
    digest recomputed replaced the real run without a word. Now both are named in one line and neither counts
    until one is removed; then the other counts."""
    real = make_run(tmp_path / "out", seed=100, final={"psnr": 20.0})
    forged = tmp_path / "res" / "runs" / real.directory.relative_to(tmp_path / "out")
    shutil.copytree(real.directory, forged)
    lines = (forged / "steps.jsonl").read_text().splitlines()
    lines[-1] = lines[-1].replace('"psnr":20.0', '"psnr":99.0')
    (forged / "steps.jsonl").write_text("\n".join(lines) + "\n")
    info = json.loads((forged / "run.json").read_text())
    info[DIGEST_KEY] = record_digest(info, (forged / "steps.jsonl").read_bytes())  # a consistent forgery
    (forged / "run.json").write_text(json.dumps(info))
    written, lines = build_tables(tmp_path / "out", [tmp_path / "res" / "runs"], tmp_path / "res", figures=False)
    assert list(lines) == [
        f"left out every copy of one run: {real.directory} and {forged} are finished copies that differ "
        "(step 2 metrics.psnr (20.0 in the first, 99.0 in the second)); remove the ones that are wrong"
    ]
    assert "No runs yet" in read(tmp_path / "res" / "tables" / "all_runs.md")
    shutil.rmtree(forged)
    written, lines = build_tables(tmp_path / "out", [tmp_path / "res" / "runs"], tmp_path / "res", figures=False)
    assert not lines and "| 20.00 " in read(tmp_path / "res" / "tables" / "all_runs.md")


def test_runs_with_settings_beyond_their_budget_get_their_own_budget_label(tmp_path):
    out = tmp_path / "out"
    named = NamedConfigs(CONF).named(("hubble", "nvf", "argmax", "none", "smoke"))
    wider = {**named, "planner": {**named["planner"], "num_candidates": 512}}
    make_run(out, seed=100, final={"psnr": 30.0}, config=wider)
    make_run(out, seed=101, final={"psnr": 10.0}, config=named)
    build_tables(out, [], tmp_path / "res", figures=False)
    md = read(tmp_path / "res" / "tables" / "main.md")
    assert "Budget: smoke, smoke+planner.num_candidates=512." in md
    rows = [line for line in md.splitlines() if "| hubble" in line]
    assert len(rows) == 2 and all(line.rstrip(" |").endswith("1") for line in rows)  # never averaged together
    assert any("smoke+planner.num_candidates=512" in line and "30.00" in line for line in rows)
    frame = pd.read_csv(tmp_path / "res" / "runs.csv")
    assert set(frame["budget"]) == {"smoke", "smoke+planner.num_candidates=512"}


def test_committed_runs_and_object_mean_and_paper_comparison(tmp_path):
    committed = tmp_path / "res" / "runs"
    for scene, psnr in (("lego_proxy", 20.0), ("hotdog", 24.0)):
        for seed in (100, 101):
            record = make_run(committed, scene=scene, seed=seed, final={"psnr": psnr + seed - 100})
            (record.directory / "DONE").unlink()  # committed copies: run.json + steps.jsonl only
    make_run(committed, scene="hotdog", method="nvf", planner="opt", seed=100)
    build_tables(tmp_path / "none", [committed], tmp_path / "res", figures=False)
    t34 = read(tmp_path / "res" / "tables" / "table34_nerf_assets.md")
    assert "| hotdog " in t34 and "| lego_proxy " in t34
    assert "| object-scene mean | NVF " in t34 and "22.50 ± 0.50" in t34  # per-seed means 22 and 23
    comparison = read(tmp_path / "res" / "tables" / "paper_comparison.md")
    assert "24.50 ± 0.50 / 26.10" in comparison  # hotdog NVF vs Table S3
    assert "| object-scene mean (2 of 8) | NVF " in comparison  # the row says how many scenes it averages
    assert "22.50 ± 0.50 / 24.17" in comparison  # object-scene mean vs the 8-scene mean
    t1 = read(tmp_path / "res" / "tables" / "table1_opt.md")
    assert "NVF-OPT" in t1


def test_cli_reads_outputs_and_committed_runs(tmp_path, capsys):
    record = make_run(tmp_path / "out", seed=100)
    (record.directory / "images").mkdir()
    iio.imwrite(record.directory / "images" / "step_00_gt.png", np.zeros((8, 8, 3), np.uint8))
    make_run(tmp_path / "res" / "runs", seed=101)
    assert main([f"paths.outputs={tmp_path / 'out'}", f"paths.results={tmp_path / 'res'}"]) == 0
    assert "pipeline.tables: wrote" in capsys.readouterr().out
    assert set(pd.read_csv(tmp_path / "res" / "runs.csv")["seed"]) == {100, 101}
    assert (tmp_path / "res" / "figures" / "curves_hubble_smoke.png").is_file()
    grids = list((tmp_path / "res" / "figures" / "grids").iterdir())
    assert [p.name for p in grids] == ["grid_hubble_nvf-argmax-none_smoke_seed100.png"]


def test_cli_says_when_the_outputs_directory_is_missing(tmp_path, capsys):
    """A mistyped paths.outputs still gives the committed runs' tables, and one line saying so."""
    make_run(tmp_path / "res" / "runs", seed=101)
    assert main([f"paths.outputs={tmp_path / 'typo'}", f"paths.results={tmp_path / 'res'}"]) == 0
    err = capsys.readouterr().err
    assert f"paths.outputs={tmp_path / 'typo'} is not a directory; only {tmp_path / 'res' / 'runs'} was read" in err
    assert set(pd.read_csv(tmp_path / "res" / "runs.csv")["seed"]) == {101}


def test_cli_rejects_unknown_arguments(capsys):
    assert main(["paths.foo=1"]) == 2
    assert "unknown argument 'paths.foo=1'" in capsys.readouterr().err


def test_image_grid(tmp_path):
    run = tmp_path / "run"
    assert image_grid(run, tmp_path / "grid.png") is None
    (run / "images").mkdir(parents=True)
    for step in (0, 1):
        iio.imwrite(run / "images" / f"step_{step:02d}_gt.png", np.zeros((8, 8, 3), np.uint8))
        iio.imwrite(run / "images" / f"step_{step:02d}_depth.png", np.full((8, 8), 128, np.uint8))
    iio.imwrite(run / "images" / "step_00_score.png", np.zeros((8, 8, 4), np.uint8))
    out = image_grid(run, tmp_path / "figs" / "grid.png")
    assert out == tmp_path / "figs" / "grid.png" and iio.imread(out).ndim == 3
    one_row = image_grid(run, tmp_path / "figs" / "one.png", max_rows=1)
    assert iio.imread(one_row).shape[0] < iio.imread(out).shape[0]


def test_summarize_run_lists_steps_and_the_paper_row(tmp_path):
    record = make_run(tmp_path, scene="lego_proxy", final={"psnr": 22.5}, lpips_reason="no weights", steps=3)
    path = summarize_run(record.directory)
    text = path.read_text()
    assert path == record.directory / "summary.md"
    assert "# lego_proxy / NVF / smoke budget / seed 100" in text
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines() if line.startswith("|")]
    assert cells[4][:3] == ["2", "5", "22.50"] and cells[4][4] == "-"  # header, rule, steps 0-2, paper
    assert cells[5][:3] == ["paper (S4)", "", "23.97"]  # Table S4, lego, NVF
    assert "LPIPS missing: no weights." in text and "Status: done" in text


def test_tables_load_without_torch_open3d_or_lpips():
    """Regenerating tables needs only the metrics' data (pipeline.metrics.info), not the metrics' code, and
    composing a run's named config groups (pipeline.config.settings_beyond_groups) needs only the schema, not the
    method library."""
    code = (
        "import sys, pipeline.repo, pipeline.tables.__main__, pipeline.config.settings_beyond_groups as o; "
        "o.NamedConfigs(pipeline.repo.CONF).named(('hubble', 'nvf', 'argmax', 'none', 'smoke')); "
        "print(sorted({'torch', 'open3d', 'lpips'} & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip() == "[]"


def test_paper_numbers_means_match_tables_s3_s4():
    paper = paper_numbers()
    per_scene = paper[paper["table"].isin(["S3", "S4"])].groupby("method")[list(METRICS)].mean()
    means = paper[paper["table"] == "mean8"].set_index("method")[list(METRICS)]
    assert len(per_scene) == 7
    assert set(paper.loc[paper["table"] == "S3", "scene"]) == {"chair", "drums", "ficus", "hotdog"}
    np.testing.assert_allclose(per_scene.loc[means.index].to_numpy(), means.to_numpy(), rtol=2e-3)


def test_a_run_whose_run_json_was_deleted_is_listed_not_dropped(tmp_path):
    record = make_run(tmp_path / "out", seed=100)
    record.run_json.unlink()  # DONE and steps.jsonl kept
    _, skipped = build_tables(tmp_path / "out", [], tmp_path / "res", figures=False)
    assert skipped == (
        f"skipped run record: {record.directory}: steps.jsonl and DONE without run.json, so the "
        "settings they were made with are unknown; delete the directory",
    )


def test_safe_name_keeps_plain_names_and_reduces_the_rest():
    assert safe_name("cpu+planner.num_candidates=512") == "cpu+planner.num_candidates=512"
    assert safe_name("lego_proxy") == "lego_proxy"
    crafted = safe_name("smoke+planner.los_source=/../../x")
    assert re.fullmatch(r"smoke\+planner\.los_source=_\.\._\.\._x-[0-9a-f]{8}", crafted)
    assert safe_name("..") != safe_name("__") and "/" not in safe_name("a/b") and not safe_name(".x").startswith(".")
    assert len(safe_name("k=" + "v" * 500)) == 80 + 9


def test_a_crafted_record_cannot_write_outside_the_results_folder(tmp_path):
    """Records travel (results/runs): a setting's text in a record becomes part of the budget label and
    of figure names. Every file written stays under paths.results, whatever the record says."""
    out, results = tmp_path / "a" / "b" / "out", tmp_path / "a" / "b" / "res"
    named = NamedConfigs(CONF).named(("hubble", "nvf", "argmax", "none", "smoke"))
    crafted = {**named, "planner": {**named["planner"], "los_source": "/../../x"}, "method": {"name": "nvf/../../y"}}
    record = make_run(out, seed=100, config=crafted)
    (record.directory / "images").mkdir()
    iio.imwrite(record.directory / "images" / "step_00_gt.png", np.zeros((8, 8, 3), np.uint8))
    before = {p for p in tmp_path.rglob("*")}
    written, _ = build_tables(out, [], results)
    created = {p for p in tmp_path.rglob("*")} - before
    assert created and all(p == results or results in p.parents for p in created), sorted(map(str, created))
    assert all(results in p.parents for p in written)
    budgets = set(pd.read_csv(results / "runs.csv")["budget"])
    assert len(budgets) == 1 and "los_source=/../../x" in budgets.pop()  # the label still says what the record holds
    figures = sorted(p.name for p in (results / "figures").rglob("*.png"))
    assert len(figures) == 2 and all("/" not in name and not name.startswith(".") for name in figures)


def test_a_build_is_all_or_nothing_and_leaves_no_stale_output(tmp_path, monkeypatch):
    """Every output is built into new folders and then swapped in: a build that fails while writing the site
    (runs.csv, the tables and the figures of a new run made by then) leaves every previous file as it was and no
    folder of its own behind; the next build keeps no page, curve or row of a run no longer there, and carries what
    another command put in figures/ and the grid of a run whose images are gone."""
    out, results = tmp_path / "out", tmp_path / "res"
    make_run(out, scene="hubble", seed=100)
    hotdog = make_run(out, scene="hotdog", seed=100)
    (hotdog.directory / "images").mkdir()
    iio.imwrite(hotdog.directory / "images" / "step_00_gt.png", np.zeros((8, 8, 3), np.uint8))
    build_tables(out, [], results)
    (results / "figures" / "scenes").mkdir()
    (results / "figures" / "scenes" / "hubble.png").write_bytes(b"an outline pipeline.scenes drew")

    def files() -> dict[Path, bytes]:
        return {p.relative_to(results): p.read_bytes() for p in results.rglob("*") if p.is_file()}

    before = files()
    grid = Path("figures", "grids", "grid_hotdog_nvf-argmax-none_smoke_seed100.png")
    assert grid in before and Path("site", "scenes", "hubble_smoke.html") in before
    make_run(out, scene="hubble", seed=101)

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    with monkeypatch.context() as patch:
        patch.setattr(build, "write_site", full_disk)
        with pytest.raises(OSError, match="No space left"):
            build_tables(out, [], results)
    assert files() == before and sorted(p.name for p in results.iterdir()) == ["figures", "runs.csv", "site", "tables"]
    shutil.rmtree(out / "hubble")
    shutil.rmtree(hotdog.directory / "images")
    written, _ = build_tables(out, [], results)
    after = files()
    assert not any("hubble" in str(path) for path in after if path.parts[:2] != ("figures", "scenes"))
    assert after[Path("figures", "scenes", "hubble.png")] == before[Path("figures", "scenes", "hubble.png")]
    assert after[grid] == before[grid] and results / grid not in written  # carried, not drawn
    assert "hubble" not in (results / "runs.csv").read_text() and all(path.is_file() for path in written)
    assert sorted(p.name for p in results.iterdir()) == ["figures", "runs.csv", "site", "tables"]


def test_written_tables_and_figures_follow_the_umask(tmp_path):
    make_run(tmp_path / "out", seed=100)
    previous = os.umask(0o027)
    try:
        written, _ = build_tables(tmp_path / "out", [], tmp_path / "res")
    finally:
        os.umask(previous)
    modes = {stat.S_IMODE(path.stat().st_mode) for path in written}
    assert modes == {0o640}


def test_rows_planned_with_the_mesh_line_of_sight_are_marked(tmp_path):
    """``planner.los_source=mesh`` acts on the collision-free sampler (Room): an oracle the tables mark
    (‡ and a footnote); on other scenes it has no effect and no mark."""
    out = tmp_path / "out"
    mesh = {"planner": {"los_source": "mesh", "collision_free": None}}
    for seed in (100, 101):
        make_run(out, scene="room", seed=seed, config=mesh)
        make_run(out, scene="hubble", seed=seed, config=mesh)
    make_run(out, scene="room", method="random", seed=100, config={"planner": {"los_source": "model"}})
    build_tables(out, [], tmp_path / "res", figures=False)
    md = read(tmp_path / "res" / "tables" / "main.md")
    table = pd.read_csv(tmp_path / "res" / "tables" / "main.csv", comment="#")
    rows = set(zip(table["Scene"], table["Method"], strict=True))
    assert rows == {("room", "NVF‡"), ("hubble", "NVF"), ("room", "Random")}
    assert md.count("‡") == 2 and "‡ Planned with an oracle: M29's line-of-sight filter used the scene mesh" in md
    assert r"NVF$^\ddagger$" in read(tmp_path / "res" / "tables" / "main.tex")
    assert "‡" not in read(tmp_path / "res" / "tables" / "table34_nerf_assets.md")


def test_rows_whose_seeds_were_made_otherwise_are_marked(tmp_path):
    """A row pooling a seed of another torch thread count, or one made from a checkout with uncommitted changes,
    is marked (° and a footnote); rows whose seeds were made alike are not."""
    out, repo = tmp_path / "out", tmp_path / "repo"
    repo.mkdir()
    for args in (
        ["init", "-q"],
        ["-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty", "-m", "x"],
    ):
        subprocess.run(["git", "-C", str(repo), *args], check=True)
    (repo / "changed.py").write_text("")
    make_run(out, seed=100, extra={"torch_threads": 1})
    make_run(out, seed=101, extra={"torch_threads": 2})
    make_run(out, scene="room", seed=100, extra={"torch_threads": 1}, repo=repo)
    for seed in (100, 101):
        make_run(out, method="random", seed=seed, extra={"torch_threads": 1})
    build_tables(out, [], tmp_path / "res", figures=False)
    table = pd.read_csv(tmp_path / "res" / "tables" / "main.csv", comment="#")
    rows = set(zip(table["Scene"], table["Method"], strict=True))
    assert rows == {("hubble", "NVF°"), ("room", "NVF°"), ("hubble", "Random")}
    assert "° Not made as its siblings" in read(tmp_path / "res" / "tables" / "main.md")


def test_rows_scored_with_the_mesh_visibility_are_marked(tmp_path):
    """``nvf.entropy.visibility_source=mesh`` is an oracle for NVF's score (‡ and its own footnote); for w/o Vis.,
    which reads no visibility, and for other methods the key changes nothing and earns no mark."""
    out = tmp_path / "out"
    oracle = {"nvf": {"entropy": {"visibility_source": "mesh", "use_visibility": True}}, "method": {"name": "nvf"}}
    blind = {"nvf": {"entropy": {"visibility_source": "mesh", "use_visibility": False}}, "method": {"name": "nvf"}}
    make_run(out, scene="hubble", seed=100, config=oracle)
    make_run(out, scene="hubble", ablation="wo_vis", seed=100, config=blind)
    build_tables(out, [], tmp_path / "res", figures=False)
    md = read(tmp_path / "res" / "tables" / "table2_ablation.md")
    table = pd.read_csv(tmp_path / "res" / "tables" / "table2_ablation.csv", comment="#")
    assert sorted(table["Variant"]) == ["NVF‡", "w/o Vis."]
    assert "‡ Scored with an oracle: NVF's visibility came from the scene mesh" in md
    assert "M29's line-of-sight filter" not in md


def test_a_method_the_paper_lacks_is_marked_and_compared_with_nvf(tmp_path):
    """FisherRF (docs/METHOD.md 17, M30-M32) joins the main table and Tables S3-S4 like the paper's methods: its
    row carries the not-in-paper mark (§, its footnote saying its -OPT is n/a) and its paired PSNR difference to NVF
    with the 95% Student-t interval; it has no paper reference numbers, so the paper comparison leaves it out.
    """
    out = tmp_path / "out"
    nvf, fisher = (22.0, 23.0, 21.5), (21.0, 21.5, 21.2)
    for scene in ("hubble", "hotdog", "chair_proxy"):
        for seed, a, b in zip((100, 101, 102), nvf, fisher, strict=True):
            make_run(out, scene=scene, method="nvf", seed=seed, final={"psnr": a})
            make_run(out, scene=scene, method="fisherrf", seed=seed, final={"psnr": b})
    build_tables(out, [], tmp_path / "res", figures=False)
    tables = tmp_path / "res" / "tables"
    main_table = pd.read_csv(tables / "main.csv", comment="#").set_index(["Scene", "Method"])
    diffs = np.subtract(fisher, nvf)
    half = 4.302653 * diffs.std(ddof=1) / np.sqrt(3)  # t(0.975, 2 degrees of freedom)
    expected = f"{diffs.mean():+.2f} [{diffs.mean() - half:+.2f}, {diffs.mean() + half:+.2f}]"
    assert main_table.loc[("hubble", "FisherRF§"), "ΔPSNR vs NVF"] == expected
    assert main_table.loc[("hubble", "NVF"), "ΔPSNR vs NVF"] == "-"
    md = read(tables / "main.md")
    assert md.count("FisherRF§") == 2  # hubble and the object-scene mean
    assert "§ Not in the paper: FisherRF, this benchmark's;" in md and "-OPT variant of them (n/a)" in md
    assert r"FisherRF$^\S$" in read(tables / "main.tex")
    objects = pd.read_csv(tables / "table34_nerf_assets.csv", comment="#")
    assert set(objects["Method"]) == {"NVF", "FisherRF§"}
    assert "FisherRF" not in read(tables / "paper_comparison.md")
    assert "§" not in read(tables / "table1_opt.md")


# ----------------------------------------------------------------------------- hostile records


def test_a_results_folder_linked_outside_is_refused_before_anything_is_written(tmp_path, capsys):
    """A ``tables/`` link under paths.results made pipeline.tables write 23 files outside it.
    Now a link out of paths.results is one ``error:`` line, exit 2, and nothing is written anywhere."""
    make_run(tmp_path / "out", seed=100)
    results, elsewhere = tmp_path / "res", tmp_path / "elsewhere"
    for linked in ("tables", "figures"):
        results.mkdir(exist_ok=True)
        elsewhere.mkdir(exist_ok=True)
        (results / linked).symlink_to(elsewhere)
        assert main([f"paths.outputs={tmp_path / 'out'}", f"paths.results={results}"]) == 2
        err = capsys.readouterr().err.splitlines()
        assert err == [
            f"error: paths.results: {results / linked} is a symbolic link to {elsewhere}, outside {results}; "
            f"records and results are never read or written through such a link: remove it (or point it "
            f"inside {results})"
        ]
        assert not list(elsewhere.iterdir()) and sorted(p.name for p in results.iterdir()) == [linked]
        (results / linked).unlink()


def test_records_behind_a_link_leaving_their_root_are_skipped(tmp_path):
    """A run folder reached through a link out of paths.outputs is one skip line, never read."""
    make_run(tmp_path / "elsewhere", scene="room", seed=100)
    make_run(tmp_path / "out", seed=100)
    (tmp_path / "out" / "room").symlink_to(tmp_path / "elsewhere" / "room")
    _, lines = build_tables(tmp_path / "out", [], tmp_path / "res", figures=False)
    assert list(lines) == [
        f"skipped run records under {tmp_path / 'out' / 'room'}: a symbolic link to "
        f"{tmp_path / 'elsewhere' / 'room'}, outside {tmp_path / 'out'}"
    ]
    assert set(pd.read_csv(tmp_path / "res" / "runs.csv")["scene"]) == {"hubble"}


def _rewrite(record: RunRecord, info_changes: dict | None = None, last_row: tuple[str, str] | None = None) -> None:
    """Edit a finished record as an attacker would, recomputing its digest so that only the value is at fault."""
    if last_row is not None:
        lines = record.steps_path.read_text().splitlines(keepends=True)
        lines[-1] = lines[-1].replace(*last_row, 1)
        record.steps_path.write_text("".join(lines))
    info = {**json.loads(record.run_json.read_text()), **(info_changes or {})}
    info[DIGEST_KEY] = record_digest(info, record.steps_path.read_bytes())
    record.run_json.write_text(json.dumps(info))


CRAFTED = [
    ("seed_of_301_digits", {"seed": 10**300}, None, "run.json: holds seed: an integer of 301 digits, beyond int64"),
    ("metric_of_401_digits", None, ('"psnr":0.5', f'"psnr":{10**400}'), "holds metrics.psnr: an integer of 401 digits"),
    (
        "steps_line_of_100000_nested_brackets",
        None,
        ('"metrics"', '"x":' + "[" * 100_000 + "]" * 100_000 + ',"metrics"'),
        "dropped a corrupt last line (line 3) of a finished run",
    ),
    (
        "names_of_200_characters",
        {key: key[0] * 200 for key in ("scene", "method", "planner", "ablation", "budget")},
        None,
        "has 200 characters, more than 64",
    ),
    (
        "rank_that_is_text",
        {"config": {"budget": {"horizon": 3}, "method": {"name": "nvf", "rank": "first"}}},
        None,
        "config.method.rank is 'first', not int",
    ),
]


@pytest.mark.parametrize(("case", "info", "row", "problem"), CRAFTED, ids=[c[0] for c in CRAFTED])
def test_one_crafted_record_is_one_skip_line_and_the_tables_go_on(tmp_path, capsys, case, info, row, problem):
    """One crafted record stopped pipeline.tables (exit 1, a traceback: OverflowError,
    RecursionError, File name too long after runs.csv was written). Now it is one skip line, the other
    records are tabulated, and the command exits 0."""
    make_run(tmp_path / "out", seed=101, final={"psnr": 21.0})
    crafted = make_run(tmp_path / "out", seed=100)
    (crafted.directory / "images").mkdir()
    iio.imwrite(crafted.directory / "images" / "step_00_gt.png", np.zeros((8, 8, 3), np.uint8))
    _rewrite(crafted, info, row)
    assert main([f"paths.outputs={tmp_path / 'out'}", f"paths.results={tmp_path / 'res'}"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "is not a directory" not in line]
    assert (
        len(err) == 1
        and err[0].startswith(f"pipeline.tables: skipped run record: {crafted.directory}")
        and problem in err[0]
    )
    assert set(pd.read_csv(tmp_path / "res" / "runs.csv")["seed"]) == {101}
    assert "| 21.00 " in read(tmp_path / "res" / "tables" / "all_runs.md")


def test_long_names_are_shortened_before_any_file_is_written(tmp_path):
    """Names of the longest allowed length (64 characters each) still give figure names a file system takes
    (at most 200 characters, cut with a hash), decided before runs.csv is written."""
    names = {"scene": "s" * 64, "method": "m" * 64, "planner": "p" * 64, "ablation": "a" * 64}
    record = make_run(tmp_path / "out", seed=100, **names)
    _rewrite(record, {"budget": "b" * 64})
    (record.directory / "images").mkdir()
    iio.imwrite(record.directory / "images" / "step_00_gt.png", np.zeros((8, 8, 3), np.uint8))
    written, lines = build_tables(tmp_path / "out", [], tmp_path / "res")
    assert all(line.startswith("pictures of") for line in lines)  # no scene of that name to draw a trajectory over
    grids = [p for p in written if p.parent.name == "grids"]
    assert (
        len(grids) == 1 and len(grids[0].name) == 200
    )  # grid_<scene>_<method-planner-ablation>_<budget label>_seed100
    assert re.fullmatch(r"grid_s{64}_m{64}-p{15}-[0-9a-f]{8}_b+-[0-9a-f]{8}\.png", grids[0].name)
    assert all(len(p.name) <= 200 for p in written)


def test_record_text_is_escaped_in_markdown_latex_and_csv(tmp_path):
    """A config value ``a|b\\n| injected | row |\\n\\input{...}`` put a live ``\\input`` line in
    all_runs.tex and an extra row in the .md tables. A value with line breaks is refused (one skip line); one
    without is escaped: no extra cell, row or line, no live LaTeX command."""
    named = NamedConfigs(CONF).named(("hubble", "nvf", "argmax", "none", "smoke"))
    hostile = r"a|b | injected | row | \input{/etc/passwd} <script>"
    config = {
        **named,
        "method": {**named["method"], "label": hostile},
        "planner": {**named["planner"], "los_source": hostile},
    }
    make_run(tmp_path / "out", seed=100, config=config)
    broken = make_run(tmp_path / "out", seed=101)
    _rewrite(broken, {"config": {**config, "planner": {"los_source": "a|b\n| injected | row |\n\\input{/etc/passwd}"}}})
    _, lines = build_tables(tmp_path / "out", [], tmp_path / "res", figures=False)
    assert len(lines) == 1 and "holds config.planner.los_source: a text with a control character" in lines[0]
    md, tex = (read(tmp_path / "res" / "tables" / f"all_runs.{flavor}") for flavor in ("md", "tex"))
    rows = [line for line in md.splitlines() if line.startswith("|")]
    cells = {len(re.findall(r"(?<!\\)\|", line)) for line in rows}
    assert len(rows) == 3 and len(cells) == 1  # header, rule, one run; every row has the same cells
    assert r"a\|b \| injected \| row \| \\input{/etc/passwd} &lt;script>" in md
    assert not any(line.lstrip().startswith("\\input") for line in tex.splitlines())
    assert r"\textbackslash{}input\{/etc/passwd\}" in tex  # in the cells and notes; in the header's comment lines
    assert all("\\input{" not in line for line in tex.splitlines() if not line.startswith("% "))  # it stays inert
    frame = pd.read_csv(tmp_path / "res" / "tables" / "all_runs.csv", comment="#")
    assert len(frame) == 1 and hostile in frame.iloc[0]["Method"]


@pytest.mark.parametrize("psnr", [-1e308, 1e308])
def test_a_metric_outside_its_range_is_one_skip_line_and_the_site_is_written(tmp_path, capsys, psnr):
    """A record whose PSNR is -1e308 (finite, its digest recomputed) stopped pipeline.tables in
    the figures (``arange: cannot compute length``), so no site was written; +1e308 showed as ``inf ± inf``. Now
    the record is skipped in one line naming the file and the metric, and the others are tabulated."""
    make_run(tmp_path / "out", seed=101, final={"psnr": 21.0})
    crafted = make_run(tmp_path / "out", seed=100)
    lines = crafted.steps_path.read_text().splitlines(keepends=True)
    crafted.steps_path.write_text("".join(line.replace('"psnr":0.0', f'"psnr":{psnr!r}') for line in lines))
    _rewrite(crafted)
    assert main([f"paths.outputs={tmp_path / 'out'}", f"paths.results={tmp_path / 'res'}"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "is not a directory" not in line]
    assert len(err) == 1 and err[0].startswith(f"pipeline.tables: skipped run record: {crafted.steps_path}: step 0")
    assert f"metric psnr = {psnr:.6g}, outside its range [0, 100]" in err[0]
    assert (tmp_path / "res" / "site" / "index.html").is_file()
    tables = read(tmp_path / "res" / "tables" / "all_runs.md")
    assert "| 21.00 " in tables and "inf" not in tables


def test_labels_render_as_text_in_every_table(tmp_path):
    """Labels holding Markdown (``**99.99 ± 0.01**``, a link to a ``javascript:`` address) stayed
    live in the .md tables, the site's table turned ``**...**`` into ``<strong>`` (the "significant best" mark), and
    runs.csv wrote a cell starting with ``=`` (a spreadsheet formula) as it was. Now each renders as text."""
    import html

    import markdown

    named = NamedConfigs(CONF).named(("hubble", "nvf", "argmax", "none", "smoke"))
    hostile = "**99.99 ± 0.01** [x](javascript:alert(1)) `code` _em_ ~~gone~~ <b>"
    make_run(tmp_path / "out", seed=100, config={**named, "method": {**named["method"], "label": hostile}})
    crafted = make_run(tmp_path / "out", scene="room", seed=100, source="=HYPERLINK(1)")  # a build no version writes
    written, skipped = build_tables(tmp_path / "out", [], tmp_path / "res")
    md = markdown.markdown(read(tmp_path / "res" / "tables" / "all_runs.md"), extensions=["tables"])
    assert not re.search(r"<(strong|em|a|code|del|b)\b", md) and hostile in html.unescape(md)
    page = next(p for p in written if p.parent.name == "scenes" and p.name.startswith("hubble_"))
    assert "**99.99 ± 0.01**" in read(page) and "<strong>99.99" not in read(page)
    cells = pd.read_csv(tmp_path / "res" / "runs.csv", dtype=str, keep_default_na=False)
    assert crafted.is_done() and any("scene_source is '=HYPERLINK(1)'" in line for line in skipped)
    assert not (cells.map(lambda cell: cell.startswith(("=", "@", "+"))).any().any())


def test_every_tables_error_line_starts_with_error(tmp_path, capsys):
    """Pipeline.tables' errors began ``pipeline.tables: error:``, unlike every other command."""
    a_file = tmp_path / "file"
    a_file.write_text("x")
    for args in (["paths.foo=1"], [f"paths.results={a_file}"]):
        assert main(args) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("error: "), err


def test_a_runs_images_are_read_as_untrusted_files(tmp_path):
    """A run's images travel with its record: a link to a file elsewhere, a file that is no PNG and an image of a
    shape no grid shows leave their cells empty; the grid is still drawn, and nothing outside is read."""
    run = tmp_path / "run"
    (run / "images").mkdir(parents=True)
    iio.imwrite(run / "images" / "step_00_gt.png", np.zeros((8, 8, 3), np.uint8))
    (run / "images" / "step_00_pred.png").write_bytes(b"not a png")
    iio.imwrite(run / "images" / "step_00_depth.png", np.zeros((8, 8, 2), np.uint8))
    (tmp_path / "secret.png").write_bytes((run / "images" / "step_00_gt.png").read_bytes())
    (run / "images" / "step_00_score.png").symlink_to(tmp_path / "secret.png")
    assert image_grid(run, tmp_path / "grid.png") == tmp_path / "grid.png"
    (run / "images" / "step_00_gt.png").unlink()
    (run / "images" / "step_00_depth.png").unlink()
    (run / "images" / "step_00_pred.png").unlink()
    assert image_grid(run, tmp_path / "none.png") is None  # a link is not one of the run's images


def test_a_record_joins_the_tables_its_method_and_scene_declare_today():
    """Which tables a run joins is today's declaration (``conf/``), not the list its record carries: a record
    made when Hubble declared only main is in table2_ablation once Hubble declares it."""
    from pipeline.tables.load import describe

    cfg = compose_run(["scene=hubble", "method=nvf", "ablation=wo_vis"]).composed
    cfg["scene"]["experiments"] = ["main"]
    cfg["method"]["experiments"] = ["main"]
    info = {"scene": "hubble", "method": "nvf", "planner": "argmax", "ablation": "wo_vis", "budget": "cpu"}
    row, scene = describe({**info, "config": cfg}, NamedConfigs(CONF))
    assert "table2_ablation" in scene.experiments and "table2_ablation" in row.experiments
    gone = describe({**info, "scene": "no_such_scene", "config": cfg}, NamedConfigs(CONF))[1]
    assert gone.experiments == ("main",)  # a group conf/ no longer has: the record's own list


def test_as_csv_quotes_a_named_text_column_cell_a_spreadsheet_would_read_as_a_formula():
    frame = pd.DataFrame({"scene": ["=HYPERLINK(1)", "-0.5", None], "diffs": ["-0.7 -0.5", "1", "2"], "n": [1, 2, 3]})
    lines = escape.as_csv(frame, ("scene", "method")).splitlines()
    assert lines == ["scene,diffs,n", "'=HYPERLINK(1),-0.7 -0.5,1", "-0.5,1,2", ",2,3"]


def test_a_build_removes_the_folders_a_killed_build_left_and_keeps_a_running_ones(tmp_path):
    """A build killed (``kill -9``) between making its new folders and renaming them left hidden
    ``.tables.<pid>.<random>.new`` folders under ``paths.results`` for good, one per kill. The next build removes
    those whose writer no longer runs and keeps one of a running writer."""
    import subprocess

    outputs, results = tmp_path / "outputs", tmp_path / "results"
    make_run(outputs, steps=2)
    gone = subprocess.Popen(["true"])  # a finished process: its pid runs no writer
    gone.wait()
    abandoned = results / f".tables.{gone.pid}.0123abcd.new"
    running = results / f".tables.{os.getpid()}.89abcdef.new"
    for folder in (abandoned, running):
        (folder / "main.md").parent.mkdir(parents=True)
        (folder / "main.md").write_text("half")
    build_tables(outputs, [], results, figures=False)
    assert not abandoned.exists() and (running / "main.md").read_text() == "half"
    assert (results / "tables" / "main.md").is_file()


def test_the_command_says_each_stage_on_a_terminal_and_nothing_elsewhere(tmp_path, capsys, monkeypatch):
    """``pipeline.tables`` was silent for minutes on the committed records; on a terminal it now says each stage."""
    out = tmp_path / "out"
    make_run(out, seed=100)
    main([f"paths.outputs={out}", f"paths.results={tmp_path / 'quiet'}"])
    assert "reading and verifying" not in capsys.readouterr().err
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    main([f"paths.outputs={out}", f"paths.results={tmp_path / 'res'}"])
    err = capsys.readouterr().err
    assert "pipeline.tables: reading and verifying the run records ..." in err and "the results site ..." in err
