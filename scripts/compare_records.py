"""``python scripts/compare_records.py A B``: are two trees of run records the same runs with the same results?

For every ``steps.jsonl`` under ``A``, the record at the same path under ``B``: its rows and its run.json's
config, with what legitimately differs between two executions left out (seconds, threads, the commit, the
digest). Prints one line per record and ``IDENTICAL`` or ``DIFFERENT``; exit status 0 or 1. Used to show that
a refactor leaves behaviour unchanged (a smoke sweep and a cpu step 0 before and after).
"""

import json
import sys
from pathlib import Path
from typing import Any

VARYING = {"seconds", "torch_threads", "git", "started", "finished", "record_digest", "timings", "versions"}


def comparable(value: Any) -> Any:
    """``value`` without the keys that differ between two executions of the same run."""
    if isinstance(value, dict):
        return {k: comparable(v) for k, v in value.items() if k not in VARYING and not k.endswith("_seconds")}
    if isinstance(value, list):
        return [comparable(v) for v in value]
    return value


def record(steps: Path) -> tuple[list, Any]:
    rows = [comparable(json.loads(line)) for line in steps.read_text().splitlines()]
    return rows, comparable(json.loads((steps.parent / "run.json").read_text()).get("config"))


def main(a: Path, b: Path) -> int:
    same = True
    for steps in sorted(a.rglob("steps.jsonl")):
        relative = steps.relative_to(a)
        other = b / relative
        if not other.is_file():
            print(f"{relative}: missing under {b}")
            same = False
            continue
        (rows_a, config_a), (rows_b, config_b) = record(steps), record(other)
        print(f"{relative}: rows {'identical' if rows_a == rows_b else 'DIFFER'}, "
              f"config {'identical' if config_a == config_b else 'DIFFERS'}")  # fmt: skip
        same &= rows_a == rows_b and config_a == config_b
    print("IDENTICAL" if same else "DIFFERENT")
    return 0 if same else 1


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print("error: usage: python scripts/compare_records.py A B (two directories of run records)", file=sys.stderr)
        sys.exit(2)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
