"""Pictures that explain themselves and the results site: map ranges recorded for colour bars, trajectories,
the static site's pages, links and offline script, the tables command's choice of records, and every entry
point's --help page."""

import math
import re
from html.parser import HTMLParser
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pandas as pd
import pytest
from test_tables import make_run

import pipeline.tables.__main__ as tables_cli
from pipeline.records.files import RecordError
from pipeline.records.images import map_range, save_step_images
from pipeline.scenes.loading import scene_config
from pipeline.tables.build import build_tables
from pipeline.tables.figures import image_grid
from pipeline.tables.trajectory import chosen_poses, outline_of_config, trajectory_figure


def test_a_map_records_its_range_and_unit_and_an_empty_one_says_so(tmp_path):
    depth = np.linspace(0.5, 2.5, 64, dtype=np.float32).reshape(8, 8)
    score = np.full((8, 8), np.nan, dtype=np.float32)
    rgb = np.zeros((8, 8, 3), dtype=np.float32)
    save_step_images(tmp_path, 3, {"gt": rgb, "depth": depth, "score": score}, score_unit="nats")
    assert map_range(tmp_path / "step_03_depth.png") == (0.5, 2.5, "scene units")
    low, high, unit = map_range(tmp_path / "step_03_score.png")
    assert math.isnan(low) and math.isnan(high) and unit == "nats"
    assert map_range(tmp_path / "step_03_gt.png") is None  # a colour image has no range
    out = image_grid(tmp_path.parent / tmp_path.name, tmp_path / "grid.png", "default / Random / smoke budget / seed 0")
    assert out is None  # images/ is not there: the run saved none
    (tmp_path / "run" / "images").mkdir(parents=True)
    for step in (0, 1):
        save_step_images(tmp_path / "run" / "images", step, {"gt": rgb, "depth": depth, "score": score})
    grid = image_grid(tmp_path / "run", tmp_path / "grid.png", "default / Random / smoke budget / seed 0")
    assert iio.imread(grid).shape[0] > 200  # enlarged: two rows of 8-px images drawn hundreds of pixels high


def test_chosen_poses_read_the_recorded_quaternions():
    rows = [
        {"step": 0, "selected_pose": [0.0, 0.0, 0.0, 1.0, 1.0, 2.0, 3.0]},
        {"step": 1, "selected_pose": "corrupt"},
        {"step": 2, "selected_pose": [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]},  # 180 degrees about x
    ]
    steps, poses = chosen_poses(rows)
    assert steps == [0, 2]
    np.testing.assert_allclose(poses[0][:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(poses[1][:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_a_trajectory_without_its_asset_is_drawn_on_the_tight_box(tmp_path):
    outline = outline_of_config(scene_config("hubble"), tmp_path / "no_assets")
    assert outline.points is None and "tight box" in outline.note and len(outline.init_poses) == 3
    rows = [{"step": s, "selected_pose": [0.0, 0.0, 0.0, 1.0, 0.5 * s, 1.0, 1.5]} for s in range(4)]
    path = trajectory_figure(outline, rows, "hubble / NVF / smoke budget / seed 0", tmp_path / "trajectory.png")
    assert iio.imread(path).shape[1] > 600


class Links(HTMLParser):
    """The img sources, hrefs and script sources of a page."""

    def __init__(self):
        super().__init__()
        self.images, self.hrefs, self.scripts = [], [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs["src"])
        elif tag == "a" and "href" in attrs:
            self.hrefs.append(attrs["href"])
        elif tag == "script" and "src" in attrs:
            self.scripts.append(attrs["src"])


def links(page: Path) -> Links:
    parser = Links()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


def test_the_site_links_every_picture_and_needs_no_network(tmp_path):
    out, results = tmp_path / "out", tmp_path / "res"
    for seed in (100, 101):
        for method in ("random", "nvf"):
            make_run(out, scene="hubble", method=method, seed=seed, final={"psnr": 20.0 + seed % 2})
    own = make_run(out, scene="hubble", method="nvf", seed=102)  # a run with its own pictures
    iio.imwrite(own.directory / "trajectory.png", np.zeros((4, 4, 3), np.uint8))
    (results / "pilots" / "a_pilot").mkdir(parents=True)
    (results / "pilots" / "a_pilot" / "README.md").write_text(
        "# A pilot\n\n| a | b |\n|--|--|\n| 1 | 2 |\n\n[data](x.csv)\n"
    )
    iio.imwrite(results / "pilots" / "a_pilot" / "curve.png", np.zeros((4, 4, 3), np.uint8))
    before = sorted(p for p in out.rglob("*"))
    build_tables(out, [], results, assets=tmp_path / "no_assets")
    assert sorted(p for p in out.rglob("*")) == before  # records are never written to
    site = results / "site"
    assert sorted(p.name for p in site.rglob("*.js")) == ["plotly.min.js"]
    index = links(site / "index.html")
    assert index.hrefs[:2] == ["index.html", "pilots.html"] and "scenes/hubble_smoke.html" in index.hrefs
    page = site / "scenes" / "hubble_smoke.html"
    found = links(page)
    assert found.scripts == ["../plotly.min.js"]
    assert len(found.images) == 5 and all((page.parent / src).resolve().is_file() for src in found.images)
    assert sum(src.endswith("out/hubble/nvf-argmax-none/smoke/seed_102/trajectory.png") for src in found.images) == 1
    assert all(src.startswith("../runs/") for src in found.images if "seed_102" not in src)  # drawn for the site
    text = page.read_text(encoding="utf-8")
    assert len(re.findall(r"<tr><td>hubble</td>", text)) == 2  # the table: Random and NVF
    assert "psnr-curves" in text and "http://" not in text.replace("http://www.w3.org", "")
    pilots = (site / "pilots.html").read_text(encoding="utf-8")
    assert "<table>" in pilots and 'href="../pilots/a_pilot/x.csv"' in pilots
    assert all((site / src).resolve().is_file() for src in links(site / "pilots.html").images)


def test_the_duel_page_lists_a_row_per_rival_marked_where_the_interval_excludes_zero(tmp_path):
    """Duel.html from pilots/duel/summary.csv: per scene one row per rival (a long table, as narrow for one method as
    for many), a gain whose interval excludes zero in bold, one that spans zero not, names escaped; the overview
    links it only when the table exists."""
    from pipeline.tables.site import DUEL_SUMMARY
    from pipeline.tables.site.duel_page import duel_page

    row = {"n": 12, "same_pick": 0.5, "cpu_hours": 1.5, "episode_diff": 0.4, "episode_ci_low": -1.0}
    rows = [
        row | {"method": "nvf", "rival": "wd", "scene": "hubble", "gain_mean": 0.5, "ci_low": 0.1, "ci_high": 0.9},
        row | {"method": "nvf", "rival": "<b>x", "scene": "hubble", "gain_mean": 0.2, "ci_low": -0.1, "ci_high": 0.5},
    ]
    summary = pd.DataFrame([r | {"episode_ci_high": 1.8} for r in rows])
    page = duel_page(summary)
    assert "<strong>+0.50 [+0.10, +0.90]</strong>" in page and "<strong>+0.20" not in page
    assert "+0.20 [-0.10, +0.50]" in page and "&lt;b&gt;x" in page and "<b>x" not in page
    assert "<td>+0.40 [-1.00, +1.80]</td>" in page and page.count("<h2>hubble</h2>") == 1
    body = page[page.index("<tbody>") :]
    labels = r'<tr><td class="label">([^<]*)</td><td class="label">([^<]*)</td><td class="label">([^<]*)</td>'
    assert re.findall(labels, body) == [
        ("NVF", "WD", "-"),
        ("NVF", "&lt;b&gt;x", "-"),
    ]  # summary.md's order: the method, each rival down the rows by its label (a name no yaml declares as it is)
    assert (
        "<td>12</td><td><strong>+0.50" in body
        and "<td>50%</td>" in body
        and "<td>1.50</td><td>not measured</td>" in body
    )
    assert "An episodes cell reads" in page
    results = tmp_path / "res"
    build_tables(tmp_path / "out", [], results, assets=tmp_path / "none")
    assert 'href="duel.html"' not in (results / "site" / "index.html").read_text()
    (results / DUEL_SUMMARY).parent.mkdir(parents=True)
    summary.to_csv(results / DUEL_SUMMARY, index=False)
    build_tables(tmp_path / "out", [], results, assets=tmp_path / "none")
    assert 'href="duel.html"' in (results / "site" / "index.html").read_text()
    assert "&lt;b&gt;x" in (results / "site" / "duel.html").read_text()
    wide = summary.copy()
    wide.loc[1, ["ci_low", "ci_high"]] = [-577.4, 600.0]  # two decisions' t-interval: wider than any gain
    wide.to_csv(results / DUEL_SUMMARY, index=False)
    build_tables(tmp_path / "out", [], results, assets=tmp_path / "none")
    assert "-577.40" in (results / "site" / "duel.html").read_text()
    before = {path: path.read_bytes() for path in (results / "site").rglob("*.html")}
    wide.loc[1, "same_pick"] = 7.0  # a share above 1: the summary does not read back
    wide.to_csv(results / DUEL_SUMMARY, index=False)
    with pytest.raises(RecordError, match="same_pick"):
        build_tables(tmp_path / "out", [], results, assets=tmp_path / "none")
    assert {path: path.read_bytes() for path in (results / "site").rglob("*.html")} == before  # all or nothing


def test_the_duel_page_ends_with_the_note_on_paper_trained_states(tmp_path):
    """Where ``pilots/paper_states/README.md`` exists, duel.html ends with it (Markdown as HTML, under "At the
    paper's scale"); without it the page has no such section."""
    from pipeline.tables.site import DUEL_SUMMARY, PAPER_STATES_NOTE

    row = {"method": "nvf", "rival": "wd", "scene": "hubble", "gain_mean": 0.5, "ci_low": 0.1, "ci_high": 0.9}
    row |= {"n": 12, "same_pick": 0.5, "cpu_hours": 1.5, "episode_diff": 0.4, "episode_ci_low": -1.0}
    results = tmp_path / "res"
    (results / DUEL_SUMMARY).parent.mkdir(parents=True)
    pd.DataFrame([row | {"episode_ci_high": 1.8}]).to_csv(results / DUEL_SUMMARY, index=False)
    build_tables(tmp_path / "out", [], results, assets=tmp_path / "none")
    assert "At the paper's scale" not in (results / "site" / "duel.html").read_text()
    (results / PAPER_STATES_NOTE).parent.mkdir(parents=True)
    (results / PAPER_STATES_NOTE).write_text("| pair | Spearman |\n|---|---|\n| wo_vis | 0.99 |\n")
    build_tables(tmp_path / "out", [], results, assets=tmp_path / "none")
    page = (results / "site" / "duel.html").read_text()
    assert "<h2>At the paper's scale</h2>" in page
    assert page.index("<h2>hubble</h2>") < page.index("scale</h2>") < page.index("<td>wo_vis</td>")


def lead_boxes(index: Path) -> dict[str, str]:
    """The index's scene boxes by scene name: each box's HTML."""
    text = index.read_text(encoding="utf-8")
    boxes = text.split('<div class="lead">')[1:]
    return {re.search(r"<h3><a [^>]*>([^<]*)</a></h3>", box).group(1): box.split("</div>")[0] for box in boxes}


def test_the_index_names_the_best_per_scene_with_its_paired_interval_its_picture_and_the_floor(tmp_path):
    """The index leads, per scene, with the best method by mean final PSNR and its interval paired by seed against
    the runner-up (separated on Hubble, not on Room), a PSNR picture linking the scene's page, and the floor's flag
    on Room (every method below PSNR_FLOOR_DB, one NVF seed above it) but not on Hubble."""
    from pipeline.tables.site.index_page import PSNR_FLOOR_DB
    from pipeline.tables.stats import paired

    psnr = {
        ("hubble", "nvf"): (22.0, 23.0, 24.0),
        ("hubble", "random"): (20.0, 20.5, 21.2),
        ("room", "nvf"): (12.0, 9.0, 16.0),
        ("room", "random"): (11.0, 11.5, 10.0),
    }
    out, results = tmp_path / "out", tmp_path / "res"
    for (scene, method), values in psnr.items():
        for seed, value in zip((100, 101, 102), values, strict=True):
            make_run(out, scene=scene, method=method, seed=seed, final={"psnr": value})
    build_tables(out, [], results, assets=tmp_path / "no_assets")
    index = results / "site" / "index.html"
    boxes = lead_boxes(index)
    assert list(boxes) == ["hubble", "room"]

    def interval(scene):
        return paired(*(pd.Series(psnr[(scene, method)]) for method in ("nvf", "random")))

    hubble, room = interval("hubble"), interval("room")
    assert hubble.low > 0 and room.low < 0 < room.high
    assert "Best: NVF, 23.00 dB (mean final PSNR over 3 seeds). Runner-up: Random, 20.57 dB." in boxes["hubble"]
    assert f"Paired difference {hubble.text()} dB (95% interval over the 3 seeds both ran)" in boxes["hubble"]
    assert "separated from Random (the interval excludes zero)" in boxes["hubble"] and "not sep" not in boxes["hubble"]
    assert "Best: NVF, 12.33 dB" in boxes["room"] and f"Paired difference {room.text()} dB" in boxes["room"]
    assert "not separated from Random (the interval includes zero)" in boxes["room"]
    assert f"{PSNR_FLOOR_DB:g} dB" in index.read_text(encoding="utf-8")  # the page states its floor
    assert (
        f'<p class="flag" role="note">Below the {PSNR_FLOOR_DB:g} dB floor' in boxes["room"]
        and "flag" not in boxes["hubble"]
    )
    assert "barely learns this scene at this budget" in boxes["room"]
    found = Links()
    found.feed(boxes["hubble"])
    assert found.hrefs == ["scenes/hubble_smoke.html", "scenes/hubble_smoke.html"]  # name and picture
    assert found.images == ["scenes/psnr_hubble_smoke.png"]
    picture = iio.imread(index.parent / found.images[0])
    assert picture.shape[0] > 200 and picture.shape[1] > picture.shape[0]
    assert 'alt="hubble, smoke budget: mean PSNR over the steps per method, the best NVF in blue' in boxes["hubble"]
    assert "Every method, smoke budget" in index.read_text(encoding="utf-8")  # the methods x scenes table follows


def test_a_lead_says_when_there_is_no_interval_or_no_runner_up():
    """A lead line without a runner-up, with one seed in common, and with identical values on every seed."""
    from pipeline.tables.site.index_page import SceneLead, lead_text
    from pipeline.tables.stats import Interval

    alone = SceneLead((("NVF", 20.0, 3),), Interval.of(np.array([])))
    assert lead_text(alone) == "Best: NVF, 20.00 dB (mean final PSNR over 3 seeds). The only method run here."
    one = SceneLead((("NVF-OPT", 9.0, 1), ("NVF", 8.5, 3)), Interval.of(np.array([0.5])))
    assert lead_text(one).endswith("Paired difference +0.50 dB over 1 seed both ran: too few pairs for an interval.")
    same = SceneLead((("Loose", 14.2, 3), ("NVF", 14.2, 3)), Interval.of(np.zeros(3)))
    assert "Identical final PSNR on each of the 3 seeds both ran: not separated from NVF" in lead_text(same)
    assert same.below_floor and not alone.below_floor


def test_tables_read_your_runs_and_with_committed_the_committed_ones(tmp_path, capsys, monkeypatch):
    committed = tmp_path / "repo_results"
    make_run(committed / "runs", seed=100)  # the same run as yours: counted once
    make_run(committed / "runs", seed=101)
    make_run(tmp_path / "out", seed=100)
    monkeypatch.setattr(tables_cli, "RESULTS", committed)
    args = [f"paths.outputs={tmp_path / 'out'}", f"paths.results={tmp_path / 'res'}"]
    assert tables_cli.main(args) == 0
    assert set(pd.read_csv(tmp_path / "res" / "runs.csv")["seed"]) == {100}
    drawn = Path("site", "runs", "hubble", "nvf-argmax-none", "smoke", "seed_101", "trajectory.png")
    (committed / drawn).parent.mkdir(parents=True)
    iio.imwrite(committed / drawn, np.zeros((4, 4, 3), np.uint8))  # the committed site drew it already
    assert tables_cli.main([*args, "--with-committed"]) == 0
    runs = pd.read_csv(tmp_path / "res" / "runs.csv")
    assert set(runs["seed"]) == {100, 101} and len(runs[runs["seed"] == 100]) == len(runs[runs["seed"] == 101])
    assert not (tmp_path / "res" / drawn).exists() and (tmp_path / "res" / drawn.parent.parent / "seed_100").is_dir()
    assert "repo_results/site/runs/hubble" in (tmp_path / "res" / "site" / "scenes" / "hubble_smoke.html").read_text()
    assert "site/index.html" in capsys.readouterr().out
    assert tables_cli.main([*args, "--with-comitted"]) == 2
    assert "unknown argument '--with-comitted'" in capsys.readouterr().err


def entry_points():
    from pipeline.bench.__main__ import main as bench
    from pipeline.experiments import budget_curve, discriminate, duel, duel_summary, uncertainty, visibility_study
    from pipeline.scenes.__main__ import main as scenes

    return {
        "tables": tables_cli.main,
        "experiments.budget_curve": budget_curve.main,
        "bench": bench,
        "scenes": scenes,
        "experiments.uncertainty": uncertainty.main,
        "experiments.discriminate": discriminate.main,
        "experiments.visibility_study": visibility_study.main,
        "experiments.duel": duel.main,
        "experiments.duel_summary": duel_summary.main,
    }


@pytest.mark.parametrize(
    "name",
    [
        "tables",
        "experiments.budget_curve",
        "bench",
        "scenes",
        "experiments.uncertainty",
        "experiments.discriminate",
        "experiments.visibility_study",
        "experiments.duel",
        "experiments.duel_summary",
    ],
)
def test_every_entry_point_has_a_plain_help_page(name, capsys):
    try:
        code = entry_points()[name](["--help"])
    except SystemExit as exit_:
        code = exit_.code
    page = capsys.readouterr().out
    assert code in (0, None)
    assert f"python -m pipeline.{name}" in page and "``" not in page and len(page.splitlines()) >= 5


def test_a_pilot_note_is_text_and_a_linked_note_is_not_read(tmp_path):
    """A pilot README with raw HTML (``<img src=x onerror=...>``) went into pilots.html live (its
    script ran in headless Chromium), and a README that is a symbolic link to a system file was rendered too. Now
    raw HTML is shown as text, links go only to http(s), mailto and the files beside the note, and a linked note is
    one line saying it is not shown."""
    from pipeline.tables.site.pilot_notes import pilots_page

    pilots = tmp_path / "pilots"
    (pilots / "hostile").mkdir(parents=True)
    (pilots / "linked").mkdir()
    (pilots / "hostile" / "README.md").write_text(
        "# Notes\n\n<img src=x onerror=alert(1)> [x](javascript:alert(1)) ![y](data:text/html,z) [fine](run.md) "
        "[web](https://example.org)\n\n<script>alert(2)</script>\n"
    )
    (tmp_path / "passwd").write_text("root:x:0:0:secret\n")
    (pilots / "linked" / "README.md").symlink_to(tmp_path / "passwd")
    page = pilots_page(pilots, tmp_path / "site" / "pilots.html")
    tags = re.findall(r"<(\w+)([^>]*)>", page)
    assert not [tag for tag, _ in tags if tag in ("script", "iframe", "object", "embed")]
    assert not [attrs for _, attrs in tags if re.search(r"\bon\w+=|javascript:|data:", attrs)]
    assert "&lt;img src=x onerror=alert(1)&gt;" in page and "&lt;script&gt;alert(2)&lt;/script&gt;" in page
    assert 'href="../pilots/hostile/run.md"' in page and 'href="https://example.org"' in page
    assert "secret" not in page and f"not shown: {pilots / 'linked' / 'README.md'}: a symbolic link" in page


def test_the_overview_prints_the_mean_alone_from_one_seed(tmp_path):
    """The overview showed "12.85 ± 0.00" from one seed where the tables print the mean alone; now it does too."""
    out, results = tmp_path / "out", tmp_path / "res"
    make_run(out, scene="hubble", method="nvf", seed=100, final={"psnr": 20.0})
    for seed in (100, 101):
        make_run(out, scene="hubble", method="random", seed=seed, final={"psnr": 18.0 + seed % 2})
    build_tables(out, [], results, assets=tmp_path / "no_assets")
    index = (results / "site" / "index.html").read_text(encoding="utf-8")
    assert '<td title="1 seeds">20.00</td>' in index and '<td title="2 seeds">18.50 ± 0.50</td>' in index


def test_the_first_page_and_the_duel_page_say_which_verdicts_hold_at_the_papers_scale(tmp_path):
    """Where the paper states' transfer table exists, the index and the duel page show it, and each of NVF's duel
    rows says whether its verdict holds at the paper's scale ("not measured" for a rival the states lack)."""
    from pipeline.records.experiment_columns import TRANSFER_TABLE as TRANSFER
    from pipeline.tables.site import DUEL_SUMMARY

    results = tmp_path / "res"
    (results / DUEL_SUMMARY).parent.mkdir(parents=True)
    (results / TRANSFER).parent.mkdir(parents=True)
    row = {
        "n": 12,
        "same_pick": 0.5,
        "cpu_hours": 1.5,
        "episode_diff": 0.4,
        "episode_ci_low": -1.0,
        "episode_ci_high": 1.8,
    }
    pd.DataFrame(
        [
            row | {"method": "nvf", "rival": rival, "scene": "all", "gain_mean": 0.5, "ci_low": 0.1, "ci_high": 0.9}
            for rival in ("wo_vis", "fisherrf")
        ]
    ).to_csv(results / DUEL_SUMMARY, index=False)
    transfer = {"states": 5, "paper_differ": 3, "paper_gain": -0.2, "paper_low": -0.4, "paper_high": -0.05}
    transfer |= {"cpu_differ": 2, "cpu_gain": 0.2, "cpu_low": 0.1, "cpu_high": 0.3, "sign_agrees": 1}
    pd.DataFrame([transfer | {"rival": "wo_vis", "label": "w/o Vis.", "verdict": "flips"}]).to_csv(
        results / TRANSFER, index=False
    )
    build_tables(tmp_path / "out", [], results, assets=tmp_path / "none")
    index = (results / "site" / "index.html").read_text()
    duel = (results / "site" / "duel.html").read_text()
    assert "Do the verdicts hold at the paper" in index and "<td>flips</td>" in index
    assert "<td>flips</td></tr>" in duel and "<td>not measured</td></tr>" in duel
