"""pipeline/cli.py: the convention every command follows, through ``run_command``: bad input is one ``error:`` line
and exit status 2, a failed run one line and status 1, a bug keeps its traceback."""

import ast
import os
import subprocess
import sys

import pytest

from pipeline.cli import BAD_INPUT, FAILED, BadInput, Failed, run_command
from pipeline.repo import REPO

COMMANDS = (
    "pipeline/run.py",
    "pipeline/tables/__main__.py",
    "pipeline/experiments/discriminate.py",
    "pipeline/experiments/uncertainty.py",
    "pipeline/experiments/visibility_study.py",
    "pipeline/experiments/visibility_summary.py",
    "pipeline/experiments/budget_curve.py",
    "pipeline/experiments/duel.py",
    "pipeline/experiments/duel_summary.py",
    "pipeline/scenes/__main__.py",
    "pipeline/bench/__main__.py",
)


def _command(*args: str) -> tuple[int, list[str]]:
    """``python -m <args>`` from the checkout: its exit status and its stderr's non-empty lines."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop("NVF_UNSET_VARIABLE", None)
    proc = subprocess.run([sys.executable, "-m", *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    return proc.returncode, [line for line in proc.stderr.splitlines() if line.strip()]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("pipeline.run", "budget=smoke", "paths.outputs=/proc/nvf-bench"), "error: /proc/nvf-bench: No such file"),
        (
            ("pipeline.run", "budget=smoke", "paths.outputs=${oc.env:NVF_UNSET_VARIABLE}"),
            "error: paths.outputs: KeyError raised while resolving interpolation",
        ),
        (
            ("pipeline.run", "budget=smoke", "paths.outputs=${paths.outputs}"),
            "error: paths.outputs: Recursive interpolation detected",
        ),
        (("pipeline.tables", "paths.results=${"), "error: paths.results: no viable alternative at input '${'"),
    ],
    ids=["outputs_in_proc", "unset_environment_variable", "self_reference", "tables_unclosed_interpolation"],
)
def test_a_path_that_cannot_be_used_or_resolved_is_one_line(args, needle):
    """``paths.outputs=/proc/x``, ``${oc.env:UNSET}``, a self-referencing interpolation and a tables
    ``paths.results=${`` were tracebacks (exit 1). Now each is one ``error:`` line naming the key, exit 2."""
    status, err = _command(*args)
    assert status == BAD_INPUT and len(err) == 1 and err[0].startswith(needle), err


def test_every_command_runs_through_run_command():
    """Each command's ``if __name__ == "__main__":`` block is one call of ``run_command``."""
    for path in COMMANDS:
        tree = ast.parse((REPO / path).read_text(encoding="utf-8"))
        blocks = [node for node in tree.body if isinstance(node, ast.If) and "__main__" in ast.unparse(node.test)]
        assert len(blocks) == 1 and ast.unparse(blocks[0].body[0]).startswith("run_command("), path


def _bad() -> None:
    raise BadInput("paths.results=x is a file; pass paths.results=DIR")


def _failed() -> None:
    raise Failed("run r failed: step 0: training diverged")


def _bug() -> None:
    raise KeyError("a bug")


def test_run_command_maps_bad_input_to_2_a_failed_run_to_1_and_keeps_a_bugs_traceback(capsys):
    for main, status, line in ((_bad, BAD_INPUT, "error: paths.results=x"), (_failed, FAILED, "error: run r failed")):
        with pytest.raises(SystemExit) as exit_info:
            run_command(main)
        err = capsys.readouterr().err.splitlines()
        assert exit_info.value.code == status and len(err) == 1 and err[0].startswith(line)
    with pytest.raises(KeyError):
        run_command(_bug)
    with pytest.raises(SystemExit) as exit_info:
        run_command(lambda argv: 3 if argv == ["x"] else 0, ["x"])
    assert exit_info.value.code == 3
