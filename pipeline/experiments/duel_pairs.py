"""A duel's pairs, A against each rival: a pair's folder under ``${paths.results}/pilots/duel/``, its setting
(``setting.json``, checked and written under the pair's lock) and the states it has decided
(``pipeline.experiments.duel``)."""

import json
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import fail
from pipeline.experiments.decisions import DECISION, Contender, decision_key
from pipeline.experiments.duel_summary import SETTING
from pipeline.experiments.options import add_command, other_threads
from pipeline.experiments.row_files import JsonLines
from pipeline.records.checked_files import read_json, read_json_lines
from pipeline.records.files import check_directory
from pipeline.records.lock import RunLock

SETTING_LOCK = ".setting"  # a pair's setting.json and command.txt are written under this lock of its folder


@dataclass
class Pair:
    """One duel, A against B: its folder, its setting (``setting.json``) and the states it has decided (read under
    the lock of a scene and seed, ``read``)."""

    method: Contender
    rival: Contender
    folder: Path
    setting: dict
    decisions: JsonLines = field(init=False)
    done: dict[tuple[str, int, int], set[int]] = field(init=False)  # (scene, seed, step) -> its decided sets
    opened: bool = False  # whether this process has written its setting and command

    def read(self) -> None:
        """The pair's decisions as the file holds them now (another writer's of other seeds included)."""
        self.decisions = JsonLines(self.folder / "decisions.jsonl", DECISION, decision_key)
        self.done = {}
        for r in self.decisions.rows:
            self.done.setdefault((r["scene"], r["seed"], r["step"]), set()).add(r["set"])

    def missing(self, scene: str, seed: int, step: int, sets: int) -> list[int]:
        """The candidate sets of a state this pair has not decided (a state cut by a kill has some)."""
        return [index for index in range(sets) if index not in self.done.get((scene, seed, step), set())]

    def owner(self, i: int, seed: int) -> Contender:
        """Whose record the ``i``-th listed step's state comes from for ``seed``: A's and B's alternately."""
        return Pair.owner_of(self.method, self.rival, i, seed)

    @staticmethod
    def owner_of(method: Contender, rival: Contender, i: int, seed: int) -> Contender:
        return method if (i + seed) % 2 == 0 else rival

    def open(self, command: list[str]) -> None:
        """Once, before this process's first rows: under the pair's own lock, its ``setting.json`` checked again
        (another process may have written one since the call was checked) and written, and ``command`` added to
        its ``command.txt``."""
        if self.opened:
            return
        with RunLock(self.folder / SETTING_LOCK, self.folder):
            check_setting(self.folder, self.setting)
            atomic_write_text(self.folder / "setting.json", json.dumps(self.setting, indent=2) + "\n")
            add_command(self.folder, command)
        self.opened = True

    def record(self, rows: list[dict]) -> None:
        self.decisions.add(rows)
        for r in rows:
            self.done.setdefault((r["scene"], r["seed"], r["step"]), set()).add(r["set"])


def setting_problem(folder: Path, setting: dict) -> str | None:
    """Why ``folder`` takes no rows of ``setting``: it holds a duel of other overrides or states' budget, or made
    with another torch thread count (its setting's, or its rows' where the setting predates it); None when it
    takes them (or holds no setting). Reads only."""
    made = read_json(folder / "setting.json", SETTING)
    if made is None:
        return None
    if made["overrides"] != setting["overrides"] or made.get("state_budget") != setting.get("state_budget"):
        theirs, ours = (
            f"{s['overrides']}" + (f" and --state-budget {s['state_budget']}" if "state_budget" in s else "")
            for s in (made, setting)
        )
        return f"{folder} holds a duel with overrides {theirs}, not {ours}; pass paths.results=DIR for another setting"
    rows = read_json_lines(folder / "decisions.jsonl", DECISION)[0]
    counts = {made["threads"]} if "threads" in made else {r["threads"] for r in rows}
    return other_threads(folder, setting["threads"], counts)


def check_setting(folder: Path, setting: dict) -> None:
    """One ``error:`` line when ``folder`` takes no rows of ``setting`` (``setting_problem``)."""
    problem = setting_problem(folder, setting)
    if problem is not None:
        fail(problem)


def pairs_of(root: Path, method: Contender, rivals: list[Contender], setting: dict) -> list[Pair]:
    """Each pair of the call with its setting, its folder checked (``check_setting``) before anything is written."""
    pairs = []
    for rival in rivals:
        contenders = {c.name: {"method": c.method, "ablation": c.ablation} for c in (method, rival)}
        pair = Pair(method, rival, root / f"{method.name}_vs_{rival.name}", setting | {"rival": rival.name})
        pair.setting["contenders"] = contenders
        check_directory(root.parent.parent, pair.folder)
        check_setting(pair.folder, pair.setting)
        pairs.append(pair)
    return pairs
