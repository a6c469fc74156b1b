"""What a paper state has finished before its row is written (``pipeline.experiments.paper_states``): its trained
models and its one-step outcomes, kept under ``paths.outputs`` so that a killed state resumes after them."""

import dataclasses
import json
import pickle
import time
from pathlib import Path

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import fail
from pipeline.episode.loop import Episode
from pipeline.episode.shared_training import Trained, load_trained, save_trained
from pipeline.records.checked_files import Each, Number, read_json
from pipeline.records.files import RecordError, make_directory

PROGRESS = {
    "seconds": Number(0.0),
    "outcomes": Each({"key": Each(Number()), "psnr": Number(0.0, 100.0), "seconds": Number(0.0)}),
}


@dataclasses.dataclass
class StateProgress:
    """What a state has finished before its row, kept under ``paths.outputs`` so that a killed state resumes
    after it: its trained models (``models``: ``save_trained``) and, in ``progress.json``, the seconds spent up to
    them and each one-step outcome taken (pose key, held-out PSNR and seconds). Its folder is named by the state's
    owner and the digest of its views, so another state never resumes from it. A resumed state's ``seconds`` are
    those of one run: the earlier run's up to its models, plus this run's after them. Removed once the row is
    written; a corrupt file is one ``error:`` line naming the folder to remove."""

    folder: Path
    spent: float = 0.0  # seconds from the state's start to its saved models
    outcomes: dict[tuple, tuple[float, float]] = dataclasses.field(default_factory=dict)
    earlier: float = 0.0  # what this run's seconds add to: the earlier run's up to its models

    @property
    def models(self) -> Path:
        return self.folder / "trained.pt"

    @staticmethod
    def open(folder: Path, root: Path) -> "StateProgress":
        """The progress kept in ``folder`` (below ``root``; created), or a fresh one."""
        make_directory(root, folder)
        try:
            found = read_json(folder / "progress.json", PROGRESS)
        except RecordError as err:
            fail(f"not a state's progress ({err}); remove {folder} to measure the state from the start")
        if found is None:
            return StateProgress(folder)
        outcomes = {tuple(item["key"]): (float(item["psnr"]), float(item["seconds"])) for item in found["outcomes"]}
        return StateProgress(folder, float(found["seconds"]), outcomes)

    def load_models(self, episodes: dict[str, Episode], step: int) -> dict[str, Trained] | None:
        """The models kept for ``episodes`` (``load_trained``), or None; one ``error:`` line for a file that is not
        theirs."""
        try:
            return load_trained(self.models, episodes, step)
        except (RuntimeError, ValueError, KeyError, TypeError, EOFError, IndexError, pickle.UnpicklingError) as err:
            fail(
                f"{self.models}: not a state's models ({type(err).__name__}); remove {self.folder} to train them again"
            )

    def _write(self) -> None:
        outcomes = [{"key": list(key), "psnr": v[0], "seconds": v[1]} for key, v in self.outcomes.items()]
        text = json.dumps({"seconds": self.spent, "outcomes": outcomes}) + "\n"
        atomic_write_text(self.folder / "progress.json", text)

    def trained(self, trained: dict[str, Trained], seconds: float) -> None:
        """The state's models, trained ``seconds`` after its start, kept."""
        save_trained(trained, self.models)
        self.spent = seconds
        self._write()

    def resumed(self, replayed: float) -> None:
        """This run took its models from an earlier one, after a replay of ``replayed`` seconds (the earlier run
        replayed too): its seconds add to the earlier run's from after that replay."""
        self.earlier = self.spent - replayed

    def add_outcome(self, key: tuple, found: tuple[float, float]) -> None:
        """The held-out PSNR and seconds of the pick ``key``, kept."""
        self.outcomes[key] = found
        self._write()

    def seconds(self, start: float) -> float:
        """The state's seconds: this run's since ``start``, after an earlier run's (``resumed``)."""
        return self.earlier + time.perf_counter() - start
