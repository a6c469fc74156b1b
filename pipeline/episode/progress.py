"""What an episode shows while it runs: on a terminal one status line from its first training iteration
(steps done, the training stage and its iteration, the time left in the stage and, once a step has finished
in this process, in the episode; then evaluating and planning); elsewhere (a log, a sweep's job) no bar, one
line per finished step."""

import sys
import time
from collections.abc import Sequence

from tqdm import tqdm

BAR_FORMAT = "{desc} step {n_fmt}/{total_fmt} |{bar:12}| {elapsed} elapsed, episode ETA {remaining}{postfix}"


def clock(seconds: float) -> str:
    """``seconds`` as ``m:ss`` or ``h:mm:ss``."""
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class EpisodeProgress:
    """The progress of one episode's steps ``first`` .. ``horizon - 1``, labelled ``label`` (scene/method,
    budget, seed). ``interactive`` (default: stderr is a terminal) shows the status line; otherwise
    ``step_done`` prints its line on stdout. ``stages``: the training stages a step runs, in order (after the
    last one's last iteration the step evaluates and plans). A context manager: the line closes with the loop."""

    def __init__(self, label: str, first: int, horizon: int, stages: Sequence[str], interactive: bool | None = None):
        self.label, self.last_stage = label, stages[-1]
        self.interactive = sys.stderr.isatty() if interactive is None else interactive
        self.bar = tqdm(
            total=horizon,
            initial=first,
            desc=label,
            unit="step",
            bar_format=BAR_FORMAT,
            disable=not self.interactive,
            dynamic_ncols=True,
            smoothing=0.0,  # ETA: mean step time so far
        )
        self.bar.set_postfix_str("preparing", refresh=False)
        self.stage_start = time.perf_counter()
        self.last = ""

    def __enter__(self) -> "EpisodeProgress":
        return self

    def __exit__(self, *exc) -> None:
        self.bar.close()

    def train(self, stage: str, iteration: int, total: int, loss: float) -> None:
        """A training iteration ended (``nvf.training``'s progress callback): ``iteration`` of ``total``
        (0-based) of ``stage``."""
        now = time.perf_counter()
        if iteration == 0:
            self.stage_start = now
        done = iteration + 1
        left = (total - done) * (now - self.stage_start) / done
        status = f"training {stage} {done}/{total} ({clock(left)} left, loss {loss:.3g})"
        trained = stage == self.last_stage and done == total
        status = "evaluating and planning" if trained else status
        self.bar.set_postfix_str(status + (f" | {self.last}" if self.last else ""), refresh=trained)
        self.bar.update(0)  # otherwise redraws at most every tqdm.mininterval

    def step_done(self, step: int, views: int, psnr: float, seconds: float) -> None:
        """Step ``step`` is recorded: ``views`` training views, ``psnr`` on the evaluation views."""
        self.last = f"step {step}: {views} views, PSNR {psnr:.2f} dB, {seconds:.1f} s"
        if self.interactive:
            self.bar.set_postfix_str(self.last, refresh=False)
            self.bar.update(1)
        else:
            print(f"[{self.label}] {self.last}", flush=True)
