"""The results site in a real browser (slow): a smoke sweep, its tables and site, then headless Chromium (Debian's
chromium and chromium-driver, `make browser`) opens the index and a scene page from file:// and checks that
they load without console errors, that the tables hold the expected rows, that the plot drew and that every
image loads; a site of synthetic records with the committed duel summary shows who wins where on the index (best,
paired interval, picture, the floor's flag) and a duel page that fits 1400 px without scrolling sideways.
Screenshots stay in the test's folder (pytest's tmp_path, printed)."""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from test_tables import make_run

from pipeline.config.catalog import contender_label

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1300,1000",
)
missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.is_file()]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """A smoke sweep's results site (``python -m pipeline.run -m experiment=smoke``, then ``pipeline.tables``), its
    records made as from outside a git checkout (``GIT_DIR`` naming none), so that the tables' provenance mark
    does not depend on whether the checkout running the test has uncommitted changes."""
    root = tmp_path_factory.mktemp("smoke")
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "GIT_DIR": str(root / "no-git")}
    for command in (
        ["pipeline.run", "-m", "experiment=smoke", f"paths.outputs={root / 'outputs'}", "hydra/launcher=joblib"],
        ["pipeline.tables", f"paths.outputs={root / 'outputs'}", f"paths.results={root / 'results'}"],
    ):
        subprocess.run(
            [sys.executable, "-m", *command], cwd=REPO, env=env, check=True, capture_output=True, timeout=1800
        )
    return root / "results" / "site"


@pytest.fixture
def browser():
    webdriver = pytest.importorskip("selenium.webdriver")
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in FLAGS:
        options.add_argument(flag)
    profile = tempfile.mkdtemp(prefix="chromium-profile-")
    options.add_argument(f"--user-data-dir={profile}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=str(CHROMEDRIVER)))
    try:
        yield driver
    finally:
        driver.quit()


def errors(driver) -> list[str]:
    """The console's errors since the last call (a missing file, a script error)."""
    return [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]


def table_rows(driver, css: str) -> list[list[str]]:
    rows = driver.find_elements("css selector", f"{css} tbody tr")
    return [[cell.text for cell in row.find_elements("css selector", "td")] for row in rows]


def broken_images(driver) -> list[str]:
    script = "return [...document.images].filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src)"
    return driver.execute_script(script)


@pytest.mark.skipif(
    bool(missing), reason=f"needs {' and '.join(missing)} (Debian's chromium, chromium-driver: make browser)"
)
def test_the_smoke_sweeps_site_loads_in_chromium(site, browser, tmp_path):
    browser.get((site / "index.html").as_uri())
    assert browser.title == "nvf-bench results" and errors(browser) == []
    overview = table_rows(browser, "table")
    assert [row[0] for row in overview] == ["Random", "NVF"] and all(len(row) == 2 for row in overview)
    lead = browser.find_element("css selector", ".lead")
    assert lead.find_element("css selector", "h3").text == "default"
    assert lead.find_element("css selector", ".best").text.startswith("Best: ")  # one seed each: no interval
    assert len(lead.find_elements("css selector", "img")) == 1 and broken_images(browser) == []
    browser.save_screenshot(str(tmp_path / "index.png"))
    browser.find_element("link text", "default").click()
    assert browser.title == "default, smoke budget" and errors(browser) == []
    table = table_rows(browser, ".wide table")
    assert [row[1] for row in table] == ["Random", "NVF"] and all(row[0] == "default" for row in table)
    assert browser.find_elements("css selector", "#psnr-curves .main-svg"), "plotly drew no chart"
    images = browser.find_elements("css selector", ".run img")
    assert len(images) == 4 and broken_images(browser) == []  # per run: its grid and its trajectory
    browser.save_screenshot(str(tmp_path / "scene.png"))
    browser.get((site / "pilots.html").as_uri())
    assert errors(browser) == [] and broken_images(browser) == []
    print(f"screenshots: {tmp_path / 'index.png'}, {tmp_path / 'scene.png'}")


@pytest.mark.skipif(
    bool(missing), reason=f"needs {' and '.join(missing)} (Debian's chromium, chromium-driver: make browser)"
)
def test_a_pilot_notes_html_does_not_run_in_chromium(browser, tmp_path):
    """In a browser: a pilot README's raw HTML (an image whose onerror runs a script, a script
    element, a javascript: link) is shown as text on pilots.html and runs nothing."""
    from pipeline.atomic_write import atomic_write_text
    from pipeline.tables.site.pilot_notes import pilots_page

    (tmp_path / "pilots" / "hostile").mkdir(parents=True)
    (tmp_path / "pilots" / "hostile" / "README.md").write_text(
        '<img src=x onerror="window.ran = 1">\n\n<script>window.ran = 2</script>\n\n[link](javascript:window.ran=3)\n'
    )
    page = tmp_path / "site" / "pilots.html"
    atomic_write_text(page, pilots_page(tmp_path / "pilots", page))
    browser.get(page.as_uri())
    for link in browser.find_elements("link text", "link"):
        link.click()
    assert browser.execute_script("return window.ran === undefined") and errors(browser) == []
    assert "<script>window.ran = 2</script>" in browser.find_element("css selector", ".pilot").text


def lead_of(driver, scene: str):
    """The index's box of ``scene``."""
    return next(
        box for box in driver.find_elements("css selector", ".lead") if box.find_element("tag name", "h3").text == scene
    )


def no_sideways_scroll(driver) -> bool:
    """Neither the page nor any of its scrolling boxes is wider than the window shows."""
    script = (
        "const boxes = [document.documentElement, ...document.querySelectorAll('.wide')];"
        "return boxes.every(b => b.scrollWidth <= b.clientWidth)"
    )
    return driver.execute_script(script)


@pytest.mark.skipif(
    bool(missing), reason=f"needs {' and '.join(missing)} (Debian's chromium, chromium-driver: make browser)"
)
def test_the_index_says_who_wins_where_and_the_duel_fits_in_chromium(browser, tmp_path):
    """Synthetic records: on Hubble NVF is ahead of Random on every seed (separated), on Room every method is below
    the floor and NVF's lead spans zero (not separated, flagged); each box's picture loads and opens the scene's
    page. The committed duel summary's page fits 1400 px with one row per rival a scene has."""
    from pipeline.tables.build import build_tables
    from pipeline.tables.site import DUEL_SUMMARY
    from pipeline.tables.site.index_page import PSNR_FLOOR_DB

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
    summary = (REPO / "results" / DUEL_SUMMARY).read_text(encoding="utf-8")
    (results / DUEL_SUMMARY).parent.mkdir(parents=True)
    (results / DUEL_SUMMARY).write_text(summary, encoding="utf-8")
    build_tables(out, [], results, assets=tmp_path / "no_assets")
    browser.set_window_size(1400, 1000)
    browser.get((results / "site" / "index.html").as_uri())
    assert errors(browser) == [] and broken_images(browser) == []
    hubble, room = lead_of(browser, "hubble"), lead_of(browser, "room")
    best = hubble.find_element("css selector", ".best").text
    assert best.startswith("Best: NVF, 23.00 dB") and "Runner-up: Random" in best
    assert "(95% interval over the 3 seeds both ran): separated from Random" in best
    assert "not separated from Random (the interval includes zero)" in room.find_element("css selector", ".best").text
    flag = room.find_element("css selector", ".flag")
    assert flag.is_displayed() and flag.text.startswith(f"Below the {PSNR_FLOOR_DB:g} dB floor")
    assert hubble.find_elements("css selector", ".flag") == []
    for box in (hubble, room):
        picture = box.find_element("css selector", "img")
        assert picture.is_displayed() and browser.execute_script("return arguments[0].naturalWidth", picture) > 300
    browser.save_screenshot(str(tmp_path / "index.png"))
    hubble.find_element("css selector", "img").click()
    assert browser.title == "hubble, smoke budget" and errors(browser) == []
    browser.get((results / "site" / "duel.html").as_uri())
    assert errors(browser) == [] and no_sideways_scroll(browser)
    scenes = browser.find_elements("css selector", "h2")
    tables = browser.find_elements("css selector", ".wide table")
    rows = table_rows(browser, ".wide table")
    lines = [line.split(",") for line in summary.splitlines()[1:]]
    first = [rival for _, rival, scene, *_ in lines if scene == lines[0][2]]  # the first scene's rivals
    assert len(tables) == len(scenes) and len(rows) == len(lines)
    labels = sorted(contender_label(rival) for rival in first)
    assert sorted(row[1] for row in rows[: len(first)]) == labels  # first scene: a row per rival it has, by its label
    browser.save_screenshot(str(tmp_path / "duel.png"))
    print(f"screenshots: {tmp_path / 'index.png'}, {tmp_path / 'duel.png'}")


@pytest.mark.skipif(
    bool(missing), reason=f"needs {' and '.join(missing)} (Debian's chromium, chromium-driver: make browser)"
)
def test_a_newcomers_method_and_scene_show_on_the_site_in_chromium(browser, tmp_path):
    """The newcomer's path ends on the site: an outside method (examples/depth_spread) and an outside scene run at
    smoke, the tables build, and in Chromium the index lists the scene with the method by its label, marked as the
    newcomer's own, and the scene's page loads with both methods' rows and pictures."""
    example = REPO / "examples" / "depth_spread"
    conf = tmp_path / "conf"
    (conf / "scene").mkdir(parents=True)
    (conf / "method").mkdir()
    (conf / "method" / "depth_spread.yaml").write_text((example / "conf" / "method" / "depth_spread.yaml").read_text())
    scene = (REPO / "conf" / "scene" / "default.yaml").read_text().replace("name: default", "name: mything", 1)
    (conf / "scene" / "mything.yaml").write_text(scene)
    env = {**os.environ, "PYTHONPATH": str(example), "OMP_NUM_THREADS": "1", "GIT_DIR": str(tmp_path / "no-git")}
    outputs, results = tmp_path / "outputs", tmp_path / "results"
    search = f"hydra.searchpath=[file://{conf}]"
    for command in (
        ["pipeline.run", "-m", "method=depth_spread,nvf", "budget=smoke", "budget.horizon=2", "scene=mything", search]
        + [f"paths.outputs={outputs}"],
        ["pipeline.tables", f"paths.outputs={outputs}", f"paths.results={results}"],
    ):
        subprocess.run(
            [sys.executable, "-m", *command], cwd=REPO, env=env, check=True, capture_output=True, timeout=1800
        )
    browser.get((results / "site" / "index.html").as_uri())
    assert errors(browser) == [] and broken_images(browser) == []
    assert sorted(row[0] for row in table_rows(browser, "table")) == ["DepthSpread", "NVF"]
    assert "a method of your own" in browser.find_element("tag name", "body").text
    lead_of(browser, "mything").find_element("link text", "mything").click()
    assert browser.title == "mything, smoke budget" and errors(browser) == []
    assert sorted(row[1] for row in table_rows(browser, ".wide table")) == ["DepthSpread§", "NVF"]
    assert len(browser.find_elements("css selector", ".run img")) == 4 and broken_images(browser) == []
    browser.save_screenshot(str(tmp_path / "newcomer.png"))
