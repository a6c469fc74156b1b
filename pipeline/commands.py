"""``nvf-bench COMMAND [args]``: every command of the benchmark under one name, and ``nvf-bench study NAME [args]``:
the studies that ask questions of it (the paper states, the transfer table, the visibility study, ...). Each is the
module it names, run as ``python -m <module> [args]`` runs it (imported only when it is asked for; the same
arguments, the same ``--help``, the same ``error:`` line and exit status 2 for bad input); ``nvf-bench --help`` and
``nvf-bench study --help`` list them."""

import runpy
import sys

# command -> (module, what it does): the benchmark itself
COMMANDS = {
    "run": ("pipeline.run", "one episode, or a Hydra sweep with -m (records, pictures, a table)"),
    "tables": ("pipeline.tables", "every table, figure and the results site from the run records"),
    "duel": ("pipeline.experiments.duel", "paired one-step decisions of two methods on recorded states"),
    "duel-summary": ("pipeline.experiments.duel_summary", "the duel's tables, beside the episodes'"),
    "scenes": ("pipeline.scenes", "a scene's picture (scenes show SCENE), or a scene of your own (scenes new)"),
    "bench": ("pipeline.bench", "benchmarks and diagnostics (bench --help lists them)"),
}
STUDY = "study"  # nvf-bench study NAME: the studies that ask questions of the benchmark
STUDIES = {
    "paper-states": ("pipeline.experiments.paper_states", "decisions at recorded states trained at the paper's budget"),
    "paper-states-summary": ("pipeline.experiments.paper_states_summary", "the paper-size states' tables"),
    "transfer": ("pipeline.experiments.transfer", "which cpu verdicts hold at the paper's scale"),
    "visibility": ("pipeline.experiments.visibility_study", "does the visibility field change a decision, and help?"),
    "visibility-summary": ("pipeline.experiments.visibility_summary", "the visibility study's tables"),
    "discriminate": ("pipeline.experiments.discriminate", "does a budget tell the methods apart? (paired intervals)"),
    "budget-curve": ("pipeline.experiments.budget_curve", "the discrimination experiments' leads against their cost"),
    "uncertainty": ("pipeline.experiments.uncertainty", "the stand-alone uncertainty experiment (PROTOCOL 4.4)"),
    "fan-out": ("pipeline.experiments.fan_out", "a study's scene-and-seed units through Hydra's launchers (-m)"),
}


def listing(entries: dict[str, tuple[str, str]], prefix: str = "") -> list[str]:
    width = max(len(prefix + name) for name in entries)
    return [f"  {prefix + name:<{width}}  {text}   [python -m {module}]" for name, (module, text) in entries.items()]


def help_page() -> str:
    lines = ["usage: nvf-bench COMMAND [args]   (nvf-bench COMMAND --help: a command's own help)", "", "commands:"]
    lines += listing(COMMANDS)
    lines += [f"  {STUDY} NAME  a study of the benchmark (nvf-bench {STUDY} --help lists them)"]
    return "\n".join(lines)


def study_page() -> str:
    lines = [f"usage: nvf-bench {STUDY} NAME [args]   (nvf-bench {STUDY} NAME --help: a study's own help)", ""]
    return "\n".join([*lines, "studies:", *listing(STUDIES)])


def dispatch(entries: dict[str, tuple[str, str]], name: str, argv: list[str], page: str, prog: str) -> None:
    """Run the module of ``entries[name]`` as ``python -m`` runs it; one ``error:`` line for an unknown name."""
    if name not in entries:
        print(f"error: unknown {page} '{name}'; choose one of: {', '.join(entries)} ({prog} --help)", file=sys.stderr)
        raise SystemExit(2)
    sys.argv = [f"{prog} {name}", *argv]
    runpy.run_module(entries[name][0], run_name="__main__", alter_sys=True)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(help_page())
        raise SystemExit(0 if argv else 2)
    if argv[0] == STUDY:
        if len(argv) == 1 or argv[1] in ("-h", "--help"):
            print(study_page())
            raise SystemExit(0 if len(argv) > 1 else 2)
        dispatch(STUDIES, argv[1], argv[2:], "study", f"nvf-bench {STUDY}")
        return
    dispatch(COMMANDS, argv[0], argv[1:], "command", "nvf-bench")


if __name__ == "__main__":
    main()
