"""The results site in a real browser (slow): a smoke sweep, its tables and site, then headless Chromium (Debian's
chromium and chromium-driver, `make browser`) opens the index and a scene page from file:// and checks that
they load without console errors, that the tables hold the expected rows, that the plot drew and that every
image loads. Screenshots stay in the test's folder (pytest's tmp_path, printed)."""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

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
    """A smoke sweep's results site (``python -m pipeline.run -m experiment=smoke``, then ``pipeline.tables``)."""
    root = tmp_path_factory.mktemp("smoke")
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
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
    from pipeline.tables.site import pilots_page

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
