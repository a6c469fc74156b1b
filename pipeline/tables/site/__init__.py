"""The results site, ``${paths.results}/site/``: static pages that open from ``file://`` with no server and no
network. ``index.html`` leads with who wins where: per scene and budget the best method by final PSNR, its paired
interval against the runner-up, a small picture of PSNR over the steps (``scenes/psnr_<scene>_<budget>.png``) and
a flag where no method reaches ``PSNR_FLOOR_DB``; then a methods x scenes table of the final PSNR. One page per
scene and budget holds
its table (paired intervals as in ``tables/all_runs``), its PSNR-over-steps curves per method (mean and 95%
Student-t band over seeds, the paper's final value marked where it has one) and every run's pictures;
``pilots.html`` shows the pilots under ``${paths.results}/pilots``: their Markdown notes as text (raw HTML in a
note is shown escaped, never passed through; links only to http(s), mailto and the files beside the note; a note
that is a symbolic link, or lies behind one leaving the pilots, is not read). The interactive plots are plotly's, its
JavaScript written once beside the pages (``plotly.min.js``); pictures are linked where they lie (beside the
run records, in ``pilots/``, or drawn into ``site/runs/`` for records that lack them, and carried from one build
of the site to the next), not copied, so the site works while it stays beside them.
"""

import os
from collections.abc import Mapping
from pathlib import Path

from plotly.offline import get_plotlyjs

from pipeline.atomic_write import atomic_write_bytes, atomic_write_text
from pipeline.records.checked_files import read_csv
from pipeline.records.experiment_columns import DUEL_SUMMARY_COLUMNS, TRANSFER_COLUMNS, TRANSFER_TABLE
from pipeline.tables.load import Runs
from pipeline.tables.site.duel_page import duel_page
from pipeline.tables.site.index_page import index_page, psnr_picture, scene_lead
from pipeline.tables.site.page_frame import PLOTLY_JS, RunPictures
from pipeline.tables.site.pilot_notes import note_html, pilots_page
from pipeline.tables.site.scene_pages import scene_page, scene_page_name, scene_picture_name

DUEL_SUMMARY = Path("pilots", "duel", "summary.csv")  # pipeline.experiments.duel_summary's table


PAPER_STATES_NOTE = Path("pilots", "paper_states", "README.md")  # the duel page's closing note


DUEL_COLUMNS = DUEL_SUMMARY_COLUMNS  # the duel summary's columns as its writer declares them, read back checked


def write_site(runs: Runs, pictures: Mapping[str, RunPictures], results: Path, site: Path) -> list[Path]:
    """Write the site of ``results`` into the folder ``site`` (beside ``results / "site"``, which it replaces:
    ``pipeline.tables.build``) from the runs and each run's pictures (by run directory); the pilots and the duel's
    summary are read from ``results``. Returns the files written."""
    done = runs.final[runs.final["status"] == "done"]
    pages_text: dict[Path, str] = {site / PLOTLY_JS: get_plotlyjs()}  # plotly.js, its MIT licence in its first lines
    pngs: dict[Path, bytes] = {}
    pages, curves = {}, {}
    for (budget, scene), frame in done.groupby(["budget", "scene"]):
        path = site / scene_page_name(scene, budget)
        pages[(budget, scene)] = path
        pages_text[path] = scene_page(runs, frame, pictures, scene, budget, path)
        lead = scene_lead(runs, frame)
        if lead is not None:
            curves[(budget, scene)] = site / scene_picture_name(scene, budget)
            pngs[curves[(budget, scene)]] = psnr_picture(runs, scene, budget, lead)
    duels = read_csv(Path(results) / DUEL_SUMMARY, DUEL_COLUMNS)
    transfer = read_csv(Path(results) / TRANSFER_TABLE, TRANSFER_COLUMNS)
    if duels is not None:
        paper_note = Path(results) / PAPER_STATES_NOTE
        at_paper_scale = note_html(paper_note, site / "duel.html") if os.path.lexists(paper_note) else None
        pages_text[site / "duel.html"] = duel_page(duels, at_paper_scale, transfer)
    index = site / "index.html"
    pages_text[index] = index_page(runs, done, pages, index, duels is not None, curves, transfer)
    pilots = site / "pilots.html"
    pages_text[pilots] = pilots_page(Path(results) / "pilots", pilots)
    for png_path, png in pngs.items():
        atomic_write_bytes(png_path, png)
    for path, text in pages_text.items():
        atomic_write_text(path, text)
    return [*pngs, *pages_text]
