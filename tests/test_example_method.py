"""examples/depth_spread: a method from outside the repository's packages (its class on ``PYTHONPATH``, its yaml
on Hydra's search path) runs and reaches the tables exactly as docs/USAGE.md says, and its scorer is what
its docstring states."""

import json
import os
import subprocess
import sys

import pytest
import torch

from nvf.model import RenderResult
from nvf.rendering import Samples
from pipeline.repo import REPO

EXAMPLE = REPO / "examples" / "depth_spread"


def result(weights: list[float], t: list[float], ray_idx: list[int], n_rays: int) -> RenderResult:
    """A render of packed samples with the given weights and interval midpoints (intervals of length 0)."""
    w, mid, idx = torch.tensor(weights), torch.tensor(t), torch.tensor(ray_idx)
    samples = Samples(idx, mid, mid.clone(), n_rays)
    acc = torch.zeros(n_rays).index_add(0, idx, w)
    zeros = torch.zeros(len(weights))
    return RenderResult(samples, zeros, zeros, w, zeros, None, None, None, torch.zeros(n_rays, 3), zeros[:n_rays], acc)


def test_the_scorer_is_the_depth_variance_plus_the_background_share(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    from depth_spread import DepthSpreadScorer

    scorer = DepthSpreadScorer(background_weight=0.5)
    # ray 0: half its weight at t=1, half at t=3 (variance 1, no background); ray 1: 0.2 at t=2 (variance 0,
    # background 0.8); ray 2: no samples (background only)
    got = scorer.pixel_scores(result([0.5, 0.5, 0.2], [1.0, 3.0, 2.0], [0, 0, 1], 3))
    assert got.tolist() == pytest.approx([1.0, 0.5 * 0.8, 0.5])


def test_an_outside_method_runs_and_reaches_the_tables(tmp_path):
    """The command of docs/USAGE.md ("Your own method") at the smoke budget, then ``pipeline.tables``: the
    run records the method's own setting and its row (marked §: not in the paper) is in the tables."""
    env = {**os.environ, "PYTHONPATH": str(EXAMPLE), "OMP_NUM_THREADS": "1"}
    outputs, results = tmp_path / "outputs", tmp_path / "results"
    run = [sys.executable, "-m", "pipeline.run", "method=depth_spread", f"hydra.searchpath=[file://{EXAMPLE / 'conf'}]"]
    overrides = ["budget=smoke", "budget.horizon=2", "method.background_weight=0.25", f"paths.outputs={outputs}"]
    subprocess.run([*run, *overrides], cwd=REPO, env=env, check=True, capture_output=True)
    [record] = outputs.glob("default/depth_spread-argmax-none/smoke/seed_100/run.json")
    assert json.loads(record.read_text())["config"]["method"]["background_weight"] == 0.25
    tables = [sys.executable, "-m", "pipeline.tables", f"paths.outputs={outputs}", f"paths.results={results}"]
    subprocess.run(tables, cwd=REPO, env=env, check=True, capture_output=True)
    for table in ("all_runs", "methods"):
        assert "| DepthSpread§" in (results / "tables" / f"{table}.md").read_text(), table  # ° too from a dirty tree


def test_an_outside_method_with_a_bad_class_is_one_line_naming_its_yaml(tmp_path):
    """A ``_target_`` that does not import is one ``error:`` line (no Hydra log before it) naming the yaml where
    Hydra's search path found it, and no run starts (only Hydra's own log folder is made)."""
    method = tmp_path / "conf" / "method"
    method.mkdir(parents=True)
    text = (EXAMPLE / "conf" / "method" / "depth_spread.yaml").read_text()
    (method / "depth_spread.yaml").write_text(text.replace("depth_spread.DepthSpread", "depth_spread.Nope"))
    env = os.environ | {"PYTHONPATH": str(EXAMPLE)}
    argv = ["method=depth_spread", "budget=smoke", f"hydra.searchpath=[file://{tmp_path / 'conf'}]"]
    argv.append(f"paths.outputs={tmp_path / 'out'}")
    done = subprocess.run(
        [sys.executable, "-m", "pipeline.run", *argv], capture_output=True, text=True, env=env, cwd=REPO
    )
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.startswith("error: method._target_: cannot import method class 'depth_spread.Nope'")
    assert done.stderr.count("\n") == 1 and f"({method / 'depth_spread.yaml'})" in done.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [".hydra"]


@pytest.mark.slow
def test_a_newcomers_own_method_and_scene_go_everywhere_the_built_in_ones_go(tmp_path):
    """The newcomer's path at the smoke budget, with an outside method (the example) and an outside scene (a yaml
    in the newcomer's own config directory): episodes of both contenders, the tables, a duel of the two on that
    scene (the duel refused an outside method: its contender check read conf/ only) and ``scenes show`` (which
    refused an outside scene). Every command finds them through the same ``hydra.searchpath`` as pipeline.run."""
    conf = tmp_path / "conf"
    (conf / "scene").mkdir(parents=True)
    (conf / "method").mkdir()
    (conf / "method" / "depth_spread.yaml").write_text((EXAMPLE / "conf" / "method" / "depth_spread.yaml").read_text())
    scene = (REPO / "conf" / "scene" / "default.yaml").read_text().replace("name: default", "name: mything", 1)
    (conf / "scene" / "mything.yaml").write_text(scene)
    env = {**os.environ, "PYTHONPATH": str(EXAMPLE), "OMP_NUM_THREADS": "1"}
    search = f"hydra.searchpath=[file://{conf}]"
    outputs, results = tmp_path / "outputs", tmp_path / "results"
    common = ["budget=smoke", "budget.horizon=3", "scene=mything", search]

    def run(*argv: str) -> subprocess.CompletedProcess:
        found = subprocess.run([sys.executable, "-m", *argv], cwd=REPO, env=env, capture_output=True, text=True)
        assert found.returncode == 0, found.stderr[-2000:]
        return found

    run("pipeline.run", "-m", "method=depth_spread,nvf", *common, f"paths.outputs={outputs}")
    run("pipeline.tables", f"paths.outputs={outputs}", f"paths.results={results}")
    table = (results / "tables" / "all_runs.md").read_text()
    assert "| mything | DepthSpread§" in table and "a method of your own" in table
    duel = ["pipeline.experiments.duel", "method=depth_spread", "rival=nvf", "budget=smoke", search]
    run(
        *duel,
        "--scenes",
        "mything",
        "--seeds",
        "100",
        "--steps",
        "1",
        "--records",
        str(outputs),
        f"paths.results={results}",
    )
    rows = [
        json.loads(line) for line in (results / "pilots" / "duel" / "depth_spread_vs_nvf" / "decisions.jsonl").open()
    ]
    assert [r["set"] for r in rows] == [0, 1]  # the duel's two candidate sets by default
    assert {(r["scene"], r["method"], r["rival"]) for r in rows} == {("mything", "depth_spread", "nvf")}
    shown = run("pipeline.scenes", "show", "mything", search, f"paths.results={results}", "--res", "16")
    assert shown.stdout.strip().endswith("mything.png")


SEEN_NOVELTY = REPO / "examples" / "seen_novelty"


def test_a_whole_view_example_scores_the_object_it_sees_from_a_new_direction(monkeypatch):
    """examples/seen_novelty: a view along an observed direction scores 0; one from a new side scores its seen share
    times the angle; then the method runs an episode at the smoke budget as USAGE's command runs it."""
    monkeypatch.syspath_prepend(str(SEEN_NOVELTY))
    from seen_novelty import SeenNoveltyScorer

    from nvf.cameras import Intrinsics, look_at, pixel_rays
    from nvf.config import FieldConfig, SamplerConfig
    from nvf.model import SceneModel
    from nvf.observations import Observations
    from nvf.seeding import generator_factory

    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    model = SceneModel(
        box, FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32), SamplerConfig(grid_resolution=8)
    )
    model.grid.occupied[:] = True
    intr = Intrinsics.from_fov(8, 8)
    seen = look_at(torch.tensor([2.6, 0.0, 0.0]), torch.zeros(3))
    obs = Observations(torch.zeros(1, 8, 8, 4), seen[None], intr)
    views = SeenNoveltyScorer().prepare(model, obs, generator_factory(0, 0, "cpu"), 64)
    same = views.view_score(model, *pixel_rays(seen, intr), 64)
    side = views.view_score(model, *pixel_rays(look_at(torch.tensor([0.0, 2.6, 0.0]), torch.zeros(3)), intr), 64)
    assert float(same) == pytest.approx(0.0, abs=1e-6) and 0.0 < float(side) <= torch.pi / 2


def test_the_whole_view_example_runs_an_episode(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(SEEN_NOVELTY), "OMP_NUM_THREADS": "1"}
    run = [
        sys.executable,
        "-m",
        "pipeline.run",
        "method=seen_novelty",
        f"hydra.searchpath=[file://{SEEN_NOVELTY / 'conf'}]",
    ]
    done = subprocess.run(
        [*run, "budget=smoke", "budget.horizon=2", f"paths.outputs={tmp_path}"], cwd=REPO, env=env, capture_output=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "default" / "seen_novelty-argmax-none" / "smoke" / "seed_100" / "DONE").is_file()
