#!/usr/bin/env bash
# scripts/device_check.sh [--dry] [--force] --out DIR: what one lent GPU can show in at most 8 minutes, as JSON files
# in DIR (flat, at most 8): device.json (nvidia-smi and torch's device facts), cuda_tests.json (the `cuda`
# tests: each kernel on CUDA against the CPU, and a smoke episode), paper_shape.json and paper_shape_room.json
# (budget=paper at the paper's sizes with counts cut, `python -m pipeline.bench paper_shape`; Room only where
# NVF_ASSETS is set), field.json, train.json and plan.json (the field, training and planning benches), and
# summary.json (each step's command, exit status and seconds, and the end of its output where it failed).
# Every step has its own time limit, so the whole stays under 8 minutes; a step that fails or runs out of
# time is recorded and the next one runs. Exit status: 0 when every step passed, 1 otherwise, 2 on bad input.
# A folder that already holds reports (*.json) is refused unless --force (they are then replaced). Room is
# measured where NVF_ASSETS is set; where its asset is a .blend and Blender's Python is missing, the step is
# recorded as skipped with the reason (the .blend is read by Blender).
# --dry runs the same steps on this machine's CPU at smoke sizes (budget=smoke, a few iterations; each limit
# x 3), in a few minutes: the check CI keeps from rotting. Python: $NVF_PYTHON, else .venv/bin/python, else
# python3.
set -uo pipefail

usage="usage: scripts/device_check.sh [--dry] [--force] --out DIR"
dry=0
force=0
out=""
while [ $# -gt 0 ]; do
    case "$1" in
        --dry) dry=1 ;;
        --force) force=1 ;;
        --out) out="${2:-}"; shift ;;
        -h | --help) sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "error: unknown argument '$1'; $usage" >&2; exit 2 ;;
    esac
    shift
done
if [ -z "$out" ]; then
    echo "error: --out DIR is missing: name the folder the JSON files go to; $usage" >&2
    exit 2
fi
if ! mkdir -p "$out" || [ ! -w "$out" ]; then
    echo "error: --out $out is not a folder this user can write in; name another" >&2
    exit 2
fi
out="$(cd "$out" && pwd)"
held="$(find "$out" -maxdepth 1 -name '*.json' -printf '%f ' 2>/dev/null | sed 's/ $//')"
if [ -n "$held" ] && [ "$force" -eq 0 ]; then
    echo "error: --out $out already holds reports ($held); pass --force to replace them, or name an empty folder" >&2
    exit 2
fi
cd "$(dirname "$0")/.." || exit 2
python="${NVF_PYTHON:-.venv/bin/python}"
[ -x "$python" ] || python="$(command -v python3)"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
logs="$(mktemp -d)"
trap 'rm -rf "$logs"' EXIT
steps="$logs/steps.tsv"
: > "$steps"

# step NAME LIMIT_SECONDS COMMAND...: run it under its limit, its output in $logs/NAME.log, a row in $steps.
step() {
    local name="$1" limit=$(($2 * slack))
    shift 2
    local start end rc
    echo "device_check: $name (at most $limit s): $*"
    start="$(date +%s.%N)"
    timeout --kill-after=10 "$limit" "$@" > "$logs/$name.log" 2>&1
    rc=$?
    end="$(date +%s.%N)"
    printf '%s\t%s\t%s\t%s\t%s\n' "$name" "$rc" "$start" "$end" "$*" >> "$steps"
    [ "$rc" -eq 0 ] || { echo "device_check: $name failed (exit status $rc); its output ends:"; tail -n 5 "$logs/$name.log"; }
}

# skip NAME REASON: a step that cannot run here, recorded with its reason (not a failure).
skip() {
    echo "device_check: $1 skipped: $2"
    printf '%s\t%s\t%s\t%s\t%s\n' "$1" "skipped" "0" "0" "$2" >> "$steps"
}

if [ "$dry" -eq 1 ]; then
    slack=3  # the CPU is slower than a GPU: each limit x 3, a few minutes in all
    sizes=(--budget smoke)
    field=(--iters 1 --rays 64 --samples-per-ray 8 --only "hash2^15-torch")
    train=(budget=smoke --precisions fp32 --repeats 1 --windows 1)
    plan=(budget=smoke planner.num_candidates=8 --precisions fp32 --blocks 1)
else
    slack=1
    sizes=()
    field=(--iters 3 --only "hash2^19-torch" "hash2^15-torch")
    train=(budget=cpu --repeats 2 --windows 2)
    plan=(budget=cpu --blocks 2)
fi

step device 30 "$python" -m pipeline.bench device --out "$out/device.json"
step cuda_tests 120 "$python" -m pytest -m cuda tests/test_cuda.py tests/test_episode.py -q -n 0 -p no:cacheprovider \
    --junitxml="$logs/cuda_tests.xml"
step paper_shape 120 "$python" -m pipeline.bench paper_shape "${sizes[@]}" --scenes default render.backend=pyrender \
    --out "$out/paper_shape.json"
blender="${NVF_BLENDER_PYTHON:-.venv-blender/bin/python}"
if [ -n "${NVF_ASSETS:-}" ] && [ -f "$NVF_ASSETS/room/room.blend" ] && [ ! -x "$blender" ]; then
    skip paper_shape_room "Room's asset is room.blend, which Blender reads, and Blender's Python ($blender) is missing: make blender"
elif [ -n "${NVF_ASSETS:-}" ]; then
    step paper_shape_room 90 "$python" -m pipeline.bench paper_shape "${sizes[@]}" --scenes room \
        render.backend=pyrender --out "$out/paper_shape_room.json"
fi
step field 30 "$python" -m pipeline.bench field --threads "$(nproc)" "${field[@]}" --out "$out/field.json"
step train 50 "$python" -m pipeline.bench train "${train[@]}" --out "$out/train.json"
step plan 50 "$python" -m pipeline.bench plan "${plan[@]}" --out "$out/plan.json"

"$python" - "$out" "$logs" "$dry" <<'EOF'
"""summary.json (each step's row) and cuda_tests.json (pytest's JUnit report as JSON), written atomically."""
import datetime
import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

out, logs, dry = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3] == "1"


def write(name: str, data: dict) -> None:
    tmp = out / f".{name}.tmp"
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(out / name)


junit = logs / "cuda_tests.xml"
if junit.is_file():
    tests = []
    for case in ET.parse(junit).getroot().iter("testcase"):
        outcome = next((child.tag for child in case if child.tag in ("failure", "error", "skipped")), "passed")
        reason = next((child.get("message", "") for child in case if child.tag != "system-out"), "")
        tests.append({"test": f"{case.get('classname')}::{case.get('name')}", "outcome": outcome,
                      "seconds": float(case.get("time", 0.0)), "reason": reason[:300]})
    counts = {k: sum(t["outcome"] == k for t in tests) for k in ("passed", "failure", "error", "skipped")}
    write("cuda_tests.json", {"counts": counts, "tests": tests})
rows = []
for line in (logs / "steps.tsv").read_text().splitlines():
    name, rc, start, end, command = line.split("\t", 4)
    if rc == "skipped":
        rows.append({"step": name, "exit_status": 0, "seconds": 0.0, "skipped": command})
        continue
    row = {"step": name, "exit_status": int(rc), "seconds": round(float(end) - float(start), 2), "command": command}
    if int(rc) != 0:
        row["output_tail"] = (logs / f"{name}.log").read_text(errors="replace").splitlines()[-20:]
    rows.append(row)
write("summary.json", {
    "mode": "dry: CPU, smoke sizes" if dry else "device",
    "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    "seconds": round(sum(r["seconds"] for r in rows), 2),
    "passed": all(r["exit_status"] == 0 for r in rows),
    "steps": rows,
})
EOF
"$python" -c "import json, sys; s = json.load(open(sys.argv[1])); print(f\"device_check: {'passed' if s['passed'] else 'FAILED'} in {s['seconds']:.0f} s; reports in {sys.argv[2]}\"); sys.exit(0 if s['passed'] else 1)" \
    "$out/summary.json" "$out"
