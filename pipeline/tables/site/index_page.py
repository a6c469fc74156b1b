"""The site's first page, ``index.html``: per scene and budget who wins (the best method by final PSNR, its paired
interval against the runner-up, a picture of PSNR over the steps, a flag below ``PSNR_FLOOR_DB``), the methods x
scenes table, and which of the duel's cpu verdicts hold at the paper's scale."""

import html
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from PIL import Image

from pipeline.tables.aggregate import mean_std_valid, seed_samples
from pipeline.tables.escape import plot_text
from pipeline.tables.figures import integer_steps
from pipeline.tables.load import Runs
from pipeline.tables.site.page_frame import LEAD_STYLE, STYLE, bold_interval, link, page_html
from pipeline.tables.site.scene_pages import COLORS, psnr_bands
from pipeline.tables.stats import LEVEL, Interval, paired

PSNR_FLOOR_DB = 15.0  # an RMS error of 18% of the intensity range: a blur of about the right colours, not a scene


PICTURE_SIZE = (3.8, 2.3)  # inches at PICTURE_DPI: the index's PSNR picture of a scene, shown 380 px wide


PICTURE_DPI = 150


PICTURE_COLORS = 64  # its palette (few colours: lines on white)


OTHER_ROWS = "#b0b0b0"  # the picture's rows other than the best and the runner-up


FLOOR_LABEL = f"floor, {PSNR_FLOOR_DB:g} dB"


@dataclass(frozen=True)
class SceneLead:
    """Who wins a scene at one budget: its rows (methods, their -OPT variants, NVF's ablations) by mean final PSNR
    over seeds, best first, as (label, mean, seeds); ``versus``: the best's PSNR minus the runner-up's, paired by
    seed (``stats.paired``, as the tables' ΔPSNR vs NVF), with no mean when there is no runner-up."""

    ranked: tuple[tuple[str, float, int], ...]
    versus: Interval

    @property
    def below_floor(self) -> bool:
        """No row's mean final PSNR reaches ``PSNR_FLOOR_DB``."""
        return self.ranked[0][1] < PSNR_FLOOR_DB


def scene_lead(runs: Runs, frame: pd.DataFrame) -> SceneLead | None:
    """The ``SceneLead`` of one scene's finished runs at one budget (``frame``); None when no run has a final PSNR.
    Rows with the same mean keep the tables' order."""
    samples = seed_samples(frame)
    stats = {key: mean_std_valid(values["psnr"].to_numpy(float)) for key, values in samples.items()}
    keys = sorted(
        (key for key, (mean, _, _) in stats.items() if math.isfinite(mean)),
        key=lambda key: (-stats[key][0], runs.row(*key[2:]).order),
    )
    if not keys:
        return None
    ranked = tuple((runs.row(*key[2:]).label, stats[key][0], stats[key][2]) for key in keys)
    versus = paired(samples[keys[0]]["psnr"], samples[keys[1]]["psnr"]) if len(keys) > 1 else Interval.of(np.array([]))
    return SceneLead(ranked, versus)


def lead_text(lead: SceneLead) -> str:
    """The lead line of a scene (plain text): the best row and its paired difference to the runner-up, saying
    plainly whether the 95% interval separates them."""
    best, mean, seeds = lead.ranked[0]
    text = f"Best: {best}, {mean:.2f} dB (mean final PSNR over {seeds} seed{'' if seeds == 1 else 's'})."
    if len(lead.ranked) == 1:
        return f"{text} The only method run here."
    runner, runner_mean, _ = lead.ranked[1]
    versus, n = lead.versus, lead.versus.n
    text += f" Runner-up: {runner}, {runner_mean:.2f} dB."
    pairs = f"{n} seed{'' if n == 1 else 's'} both ran"
    if n < 2:
        return f"{text} Paired difference {versus.text()} dB over {pairs}: too few pairs for an interval."
    if versus.mean == versus.low == versus.high == 0.0:
        return (
            f"{text} Identical final PSNR on each of the {pairs}: not separated from {runner} (a difference of zero)."
        )
    verdict = (
        f"separated from {runner} (the interval excludes zero)"
        if versus.excludes_zero
        else f"not separated from {runner} (the interval includes zero)"
    )
    return f"{text} Paired difference {versus.text()} dB ({LEVEL:.0%} interval over the {pairs}): {verdict}."


def floor_text(lead: SceneLead) -> str:
    """The flag of a scene below ``PSNR_FLOOR_DB`` (plain text)."""
    return (
        f"Below the {PSNR_FLOOR_DB:g} dB floor: no method's mean final PSNR reaches it (the best: "
        f"{lead.ranked[0][1]:.2f} dB). The model barely learns this scene at this budget; read its ranking with care."
    )


def psnr_picture(runs: Runs, scene: str, budget: str, lead: SceneLead) -> bytes:
    """A small PNG of a scene's PSNR over the steps, the mean over seeds per row (``psnr_bands``): the best and the
    runner-up in colour and named, the others grey; the floor dashed where it is in range or not reached."""
    best = lead.ranked[0][0]
    runner = lead.ranked[1][0] if len(lead.ranked) > 1 else None
    fig = Figure(figsize=PICTURE_SIZE, dpi=PICTURE_DPI, layout="constrained")
    ax = fig.subplots()
    drawn = []
    for label, frame in reversed(psnr_bands(runs, scene, budget)):  # the paper's first rows drawn last, on top
        if frame.empty or not frame["mean"].notna().any():
            continue
        steps, means = frame["step"].to_numpy(int), frame["mean"].to_numpy(float)
        drawn.append(means[np.isfinite(means)])
        if label == best:
            ax.plot(steps, means, color=COLORS[0], linewidth=2.2, zorder=4, label=plot_text(f"best: {label}"))
        elif label == runner:
            ax.plot(steps, means, color=COLORS[1], linewidth=1.6, zorder=3, label=plot_text(f"runner-up: {label}"))
        else:
            ax.plot(steps, means, color=OTHER_ROWS, linewidth=0.8, zorder=2)
    values = np.concatenate(drawn) if drawn else np.array([PSNR_FLOOR_DB])
    if lead.below_floor or values.min() <= PSNR_FLOOR_DB <= values.max():
        ax.axhline(PSNR_FLOOR_DB, color="#b35900", linestyle="--", linewidth=0.9, zorder=1, label=FLOOR_LABEL)
    handles, labels = ax.get_legend_handles_labels()
    order = sorted(range(len(labels)), key=lambda i: (labels[i] == FLOOR_LABEL, not labels[i].startswith("best")))
    if handles:
        ax.legend([handles[i] for i in order], [labels[i] for i in order], fontsize=6.5, frameon=False, loc="best")
    ax.set_xlabel("step", fontsize=7)
    ax.set_ylabel("PSNR (dB)", fontsize=7)
    ax.tick_params(labelsize=6.5)
    integer_steps(ax)
    ax.grid(alpha=0.3)
    png = io.BytesIO()
    fig.savefig(png, format="png")
    with Image.open(io.BytesIO(png.getvalue())) as image:
        png = io.BytesIO()
        image.convert("RGB").quantize(PICTURE_COLORS).save(png, format="PNG", optimize=True)
    return png.getvalue()


def picture_alt(scene: str, budget: str, lead: SceneLead) -> str:
    """The picture's text alternative (plain text)."""
    runner = f", the runner-up {lead.ranked[1][0]} in orange" if len(lead.ranked) > 1 else ""
    return (
        f"{scene}, {budget} budget: mean PSNR over the steps per method, the best {lead.ranked[0][0]} in blue"
        f"{runner}, the others grey"
    )


def leads_html(
    runs: Runs,
    frame: pd.DataFrame,
    budget: str,
    pages: Mapping[tuple[str, str], Path],
    curves: Mapping[tuple[str, str], Path],
    page: Path,
) -> str:
    """One budget's scenes, each a box: its name and picture linking its page, its lead line, its flag."""
    boxes = []
    for scene in sorted(set(frame["scene"]), key=lambda scene: runs.scene(scene).order):
        lead = scene_lead(runs, frame[frame["scene"] == scene])
        target = link(pages[(budget, scene)], page)
        box = [f'<div class="lead"><h3><a href="{target}">{html.escape(scene)}</a></h3>']
        if lead is None:
            boxes.append(f"{''.join(box)}<p>No run has a final PSNR.</p></div>")
            continue
        picture = curves.get((budget, scene))
        if picture is not None:
            alt = html.escape(picture_alt(scene, budget, lead))
            width, height = (round(inches * 100) for inches in PICTURE_SIZE)
            source = link(picture, page)
            box.append(f'<a href="{target}"><img src="{source}" alt="{alt}" width="{width}" height="{height}"></a>')
        box.append(f'<p class="best">{html.escape(lead_text(lead))}</p>')
        if lead.below_floor:
            box.append(f'<p class="flag" role="note">{html.escape(floor_text(lead))}</p>')
        boxes.append("".join(box) + "</div>")
    return f'<div class="leads">{"".join(boxes)}</div>'


def index_page(
    runs: Runs,
    done: pd.DataFrame,
    pages: Mapping[tuple[str, str], Path],
    page: Path,
    duel: bool = False,
    curves: Mapping[tuple[str, str], Path] | None = None,
    transfer: pd.DataFrame | None = None,
) -> str:
    """Per budget, who wins where (``leads_html``: per scene the best row and its paired interval against the
    runner-up, the PSNR picture of ``curves`` by (budget, scene), the floor's flag), then methods x scenes: final
    PSNR mean ± population std over seeds, each scene linking to its page; ``duel``: link the duel's page;
    ``transfer``: which of the duel's cpu verdicts hold at the paper's scale (``transfer_html``)."""
    parts = []
    if done.empty:
        parts.append(
            "<p>No finished runs yet: run <code>python -m pipeline.run</code>, then "
            "<code>python -m pipeline.tables</code>.</p>"
        )
    else:
        parts.append(
            "<p>Who wins where: per scene and budget, the best method by mean final PSNR over seeds (every row of "
            "the tables: the methods, their -OPT variants and NVF's ablations) and its paired difference to the "
            "runner-up, the best's final PSNR minus the runner-up's on the seeds both ran: mean "
            f"[{LEVEL:.0%} Student-t interval], as the tables' ΔPSNR vs NVF. Where that interval includes zero, "
            "the best is not separated from the runner-up. The picture: mean PSNR over the steps per method, the "
            "best in blue, the runner-up in orange, the others grey; it opens the scene's page.</p>"
            f'<p class="note">Floor: a scene is flagged where no method\'s mean final PSNR reaches '
            f"{PSNR_FLOOR_DB:g} dB. That is a root-mean-square error of {10 ** (-PSNR_FLOOR_DB / 20):.0%} of the "
            "intensity range, a blur of about the right colours: the model barely learns the scene at this budget, "
            "and its ranking says more about the seeds than about the chosen views.</p>"
        )
    for budget, frame in done.groupby("budget"):
        parts.append(f"<h2>{html.escape(budget)} budget</h2>")
        parts.append(leads_html(runs, frame, budget, pages, curves or {}, page))
        frame = frame.assign(row=list(zip(frame["method"], frame["planner"], frame["ablation"], strict=True)))
        groups = sorted(set(frame["row"]), key=lambda key: runs.row(*key).order)
        scenes = sorted(set(frame["scene"]), key=lambda scene: runs.scene(scene).order)
        head = "".join(f'<th><a href="{link(pages[(budget, s)], page)}">{html.escape(s)}</a></th>' for s in scenes)
        lines = []
        for key in groups:
            cells = []
            for scene in scenes:
                psnr = frame.loc[(frame["scene"] == scene) & (frame["row"] == key), "psnr"].to_numpy(float)
                psnr = psnr[np.isfinite(psnr)]
                spread = f" ± {psnr.std():.2f}" if len(psnr) > 1 else ""  # one seed: the mean alone, as the tables
                text = f"{psnr.mean():.2f}{spread}" if len(psnr) else "-"
                cells.append(f'<td title="{len(psnr)} seeds">{text}</td>')
            lines.append(f'<tr><td class="label">{html.escape(runs.row(*key).label)}</td>{"".join(cells)}</tr>')
        parts.append(
            f'<h3>Every method, {html.escape(budget)} budget</h3><div class="wide"><table><thead><tr><th>method</th>'
            f"{head}</tr></thead><tbody>{''.join(lines)}</tbody></table></div>"
        )
        own = [runs.row(*key).label for key in groups if not runs.row(*key).in_repository]
        if own:
            parts.append(
                f'<p class="note">{html.escape(", ".join(own))}: a method of your own (declared outside this '
                "repository), not the benchmark's.</p>"
            )
    parts.append(
        '<p class="note">Tables: final PSNR (dB) on the evaluation views, mean ± population std over seeds (hover a '
        "cell for the number of seeds). A scene's page has every metric with paired 95% intervals, the curves over "
        "the steps and each run's pictures. Proxies and the procedural default scene are stand-ins, not the paper's "
        "assets.</p>"
    )
    if duel:
        parts.append(
            '<p><a href="duel.html">Duels</a>: which method\'s next view is better from the same state, paired '
            "one-step decisions beside the episodes' final PSNR.</p>"
        )
    if transfer is not None:
        parts.append(transfer_html(transfer))
    return page_html("nvf-bench results", "".join(parts), style=STYLE + LEAD_STYLE)


def transfer_html(transfer: pd.DataFrame) -> str:
    """Per rival of NVF, its one-step verdict at the cpu budget beside the same states trained at the paper's scale
    (``pilots/paper_states/transfer.csv``) and whether it holds at both, flips or is unknown at one."""
    head = "".join(
        f"<th>{html.escape(name)}</th>"
        for name in ("rival", "states", "NVF's gain, cpu (dB)", "NVF's gain, paper (dB)", "verdict at both scales")
    )
    rows = "".join(
        f'<tr><td class="label">{html.escape(str(r["label"]))}</td><td>{int(r["states"])}</td>'
        f"<td>{bold_interval(Interval(r['cpu_gain'], r['cpu_low'], r['cpu_high'], int(r['states'])))}</td>"
        f"<td>{bold_interval(Interval(r['paper_gain'], r['paper_low'], r['paper_high'], int(r['states'])))}</td>"
        f"<td>{html.escape(str(r['verdict']))}</td></tr>"
        for _, r in transfer.iterrows()
    )
    return (
        "<h2>Do the verdicts hold at the paper's scale?</h2><p>The same states trained at the cpu budget and at the "
        "paper's (its 512-px images, iterations and table size): NVF's pick's one-step held-out PSNR minus the "
        "rival's, 0 where both pick one view, mean [95% interval] over the states "
        '(<a href="../pilots/paper_states/transfer.md">transfer.md</a>).</p>'
        f'<div class="wide"><table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table></div>'
    )
