"""``nvf-bench COMMAND [args]``: every command of the benchmark under one name. Each command is the module it
names, run as ``python -m <module> [args]`` runs it (imported only when it is asked for; the same arguments, the
same ``--help``, the same ``error:`` line and exit status 2 for bad input); ``nvf-bench --help`` lists them."""

import runpy
import sys

# command -> (module, what it does)
COMMANDS = {
    "run": ("pipeline.run", "one episode, or a Hydra sweep with -m (records, pictures, a table)"),
    "tables": ("pipeline.tables", "every table, figure and the results site from the run records"),
    "bench": ("pipeline.bench", "benchmarks and diagnostics (bench --help lists them)"),
    "scenes": ("pipeline.scenes", "a picture of a scene's views and boxes (scenes show SCENE)"),
    "duel": ("pipeline.experiments.duel", "paired one-step decisions of two methods on recorded states"),
    "duel-summary": ("pipeline.experiments.duel_summary", "the duel's tables, beside the episodes'"),
    "paper-states": ("pipeline.experiments.paper_states", "decisions at recorded states trained at the paper's budget"),
    "paper-states-summary": ("pipeline.experiments.paper_states_summary", "the paper-size states' tables"),
    "transfer": ("pipeline.experiments.transfer", "which cpu verdicts hold at the paper's scale"),
    "study": (
        "pipeline.experiments.visibility_study",
        "does the visibility field change a decision, and does it help?",
    ),
    "study-summary": ("pipeline.experiments.visibility_summary", "the visibility study's tables"),
    "discriminate": ("pipeline.experiments.discriminate", "does a budget tell the methods apart? (paired intervals)"),
    "budget-curve": ("pipeline.experiments.budget_curve", "the discrimination experiments' leads against their cost"),
    "uncertainty": ("pipeline.experiments.uncertainty", "the stand-alone uncertainty experiment (PROTOCOL 4.4)"),
}


def help_page() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: nvf-bench COMMAND [args]   (nvf-bench COMMAND --help: a command's own help)", "", "commands:"]
    lines += [f"  {name:<{width}}  {text}   [python -m {module}]" for name, (module, text) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(help_page())
        raise SystemExit(0 if argv else 2)
    if argv[0] not in COMMANDS:
        print(
            f"error: unknown command '{argv[0]}'; choose one of: {', '.join(COMMANDS)} (nvf-bench --help)",
            file=sys.stderr,
        )
        raise SystemExit(2)
    module = COMMANDS[argv[0]][0]
    sys.argv = [f"nvf-bench {argv[0]}", *argv[1:]]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
