"""pipeline/commands.py: ``nvf-bench COMMAND`` runs the module ``python -m`` runs, and lists every command."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline import commands

REPO = Path(__file__).resolve().parents[1]


def test_every_command_names_a_module_and_every_command_module_is_listed():
    modules = {module for module, _ in (commands.COMMANDS | commands.STUDIES).values()}
    assert all(importlib.util.find_spec(module) is not None for module in modules)
    runnable = {
        f"pipeline.experiments.{path.stem}"
        for path in (REPO / "pipeline" / "experiments").glob("*.py")
        if 'if __name__ == "__main__":' in path.read_text()
    }
    assert runnable <= modules
    assert {"pipeline.run", "pipeline.tables", "pipeline.bench", "pipeline.scenes"} <= modules


def test_help_lists_every_command_and_an_unknown_one_is_one_line(capsys):
    with pytest.raises(SystemExit) as exit_:
        commands.main(["--help"])
    out = capsys.readouterr().out
    assert exit_.value.code == 0 and all(f"  {name} " in out for name in commands.COMMANDS) and "  study NAME " in out
    with pytest.raises(SystemExit) as exit_:
        commands.main(["nosuch"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("error: unknown command 'nosuch'") and err.count("\n") == 1
    with pytest.raises(SystemExit) as exit_:
        commands.main(["study", "--help"])
    out = capsys.readouterr().out
    assert exit_.value.code == 0 and all(f"  {name} " in out for name in commands.STUDIES)
    with pytest.raises(SystemExit) as exit_:
        commands.main(["study", "nosuch"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("error: unknown study 'nosuch'") and err.count("\n") == 1


def test_a_command_is_its_module_run_as_python_m():
    """``nvf-bench bench --help`` prints what ``python -m pipeline.bench --help`` prints; bad input to a command is
    that command's one ``error:`` line and exit 2."""
    ours = subprocess.run(
        [sys.executable, "-m", "pipeline.commands", "bench", "--help"], capture_output=True, text=True, cwd=REPO
    )
    theirs = subprocess.run(
        [sys.executable, "-m", "pipeline.bench", "--help"], capture_output=True, text=True, cwd=REPO
    )
    assert ours.returncode == theirs.returncode == 0 and ours.stdout == theirs.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "pipeline.commands", "bench", "nosuch"], capture_output=True, text=True, cwd=REPO
    )
    assert bad.returncode == 2 and bad.stderr.startswith("error: unknown benchmark 'nosuch'")


@pytest.mark.slow
@pytest.mark.parametrize(
    "words", [[name] for name in commands.COMMANDS] + [["study", name] for name in commands.STUDIES]
)
def test_every_command_and_its_python_m_form_print_the_same_help(words):
    """Each command's and study's ``--help`` through the console script ``nvf-bench`` (the installed entry point) and
    as ``python -m <module>``: both exit 0 and print the same page (its first line names the program)."""
    module = (commands.STUDIES if words[0] == commands.STUDY else commands.COMMANDS)[words[-1]][0]
    script = Path(sys.executable).with_name("nvf-bench")
    as_script = subprocess.run([script, *words, "--help"], capture_output=True, text=True, cwd=REPO)
    as_module = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True, cwd=REPO)
    assert as_script.returncode == 0, as_script.stderr
    assert as_module.returncode == 0, as_module.stderr
    assert as_script.stdout.splitlines()[1:] == as_module.stdout.splitlines()[1:]
    assert len(as_module.stdout.splitlines()) > 1
