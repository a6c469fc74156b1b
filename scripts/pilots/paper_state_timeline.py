"""One whole paper-size state of ``pipeline.experiments.paper_states`` (``measure_state``, the command's own code)
with the process's resident memory printed every 20 s and each stage's entry (``>``) and exit (``<``) marked.

Run from the repository root with one torch thread:
``OMP_NUM_THREADS=1 python scripts/pilots/paper_state_timeline.py SCENE STEP [overrides] > LOG``
(``default 2 render.backend=pyrender`` made ``default_step2_pyrender.log``). The state is NVF's cpu record of
seed 100 before step STEP, trained at ``budget=paper``; the one-step outcome against w/o Vis. is measured where
their picks differ. Its last line is the state's row as the command writes it."""

import functools
import sys
import threading
import time
from pathlib import Path

import torch

from pipeline.config.catalog import conf_dirs
from pipeline.config.validation import compose_run
from pipeline.episode.loop import Episode
from pipeline.experiments import paper_states
from pipeline.experiments.decisions import contender, recorded_steps
from pipeline.experiments.paper_states_summary import STATE, state_key
from pipeline.experiments.provenance import checkout
from pipeline.experiments.row_files import JsonLines
from pipeline.metrics.image import LpipsMetric
from pipeline.scenes.blender import blender_python
from pipeline.scenes.loading import load_scene

START = time.time()
STAGES = ("train_models", "candidate_set", "picks_of", "visibility_agreement", "heldout_psnr")  # the study's steps


def log(message: str) -> None:
    """Minutes since start, resident memory (GB) and ``message``."""
    status = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
    rss = int(status["VmRSS"].split()[0]) / 1e6
    print(f"{(time.time() - START) / 60:7.1f} min rss {rss:6.2f} GB  {message}", flush=True)


def marked(function):
    """``function`` logging its entry and exit."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        log(f"> {function.__name__}")
        out = function(*args, **kwargs)
        log(f"< {function.__name__}")
        return out

    return wrapper


def poll() -> None:
    while True:
        time.sleep(20)
        log("")


def main() -> None:
    scene_name, step, overrides = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    torch.set_num_threads(1)
    threading.Thread(target=poll, daemon=True).start()
    for name in STAGES:  # each step of the state logs its entry and exit (the row has each training stage's seconds)
        setattr(paper_states, name, marked(getattr(paper_states, name)))
    cfg = compose_run([f"scene={scene_name}", "budget=paper", *overrides])
    scene = load_scene(cfg.scene, Path(cfg.paths.assets), blender_python(cfg.paths.blender_python))
    owner = contender("nvf")
    recorded = recorded_steps(Path("results/runs"), scene_name, owner, 100, "cpu", step, scene)
    state = paper_states.State(scene, 100, step, owner, recorded.source, recorded.rows)
    settings = paper_states.settings_of(scene, owner, 100, "paper", overrides)
    episode = Episode(settings, scene, torch.device("cpu"), LpipsMetric())
    call = paper_states.Call(
        folder=Path("outputs/paper_state_timeline"),
        overrides=overrides,
        state_budget="cpu",
        records=Path("results/runs"),
        contenders=["nvf", "wo_vis"],
        outcomes=["wo_vis"],
        vis_points=4096,
        threads=1,
        states=JsonLines(Path("outputs/paper_state_timeline/states.jsonl"), STATE, state_key),
        saved=Path("outputs/paper_state_timeline/saved"),
        git=checkout(),
        dirs=conf_dirs([]),
    )
    row = paper_states.measure_state(call, state, episode, None)
    log("done")
    print(row)


main()
