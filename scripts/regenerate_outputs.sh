#!/usr/bin/env bash
# Regenerate every committed output that is computed from committed data, in place, then list what changed.
#
#   bash scripts/regenerate_outputs.sh [--check]
#
# The tables, figures and results site (from results/runs), the duel's, the visibility study's and the paper
# states' summaries, the transfer table, README.md's findings and the coverage pilot's figures. With --check,
# exit 1 when any tracked file differs afterwards (git diff): a refactor that changes no output leaves the
# checkout clean. The command writes into the checkout; run it from a clean one (git stash or a worktree) to see
# only its own changes.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
check=false
case "${1:-}" in
  --check) check=true ;;
  "") ;;
  *) echo "error: unknown argument '$1': the only option is --check" >&2; exit 2 ;;
esac

$PY -m pipeline.tables paths.results=results paths.outputs=results/runs
$PY -m pipeline.experiments.duel_summary paths.results=results
$PY -m pipeline.experiments.visibility_summary paths.results=results
$PY -m pipeline.experiments.paper_states_summary paths.results=results --pool results/pilots/paper_states_pyrender
pyrender=$(mktemp -d)  # the pyrender folder's own summary: the command reads <paths.results>/pilots/paper_states
trap 'rm -rf "$pyrender"' EXIT
mkdir "$pyrender/pilots" && ln -s "$PWD/results/pilots/paper_states_pyrender" "$pyrender/pilots/paper_states"
$PY -m pipeline.experiments.paper_states_summary paths.results="$pyrender"
$PY -m pipeline.experiments.transfer paths.results=results --pool results/pilots/paper_states_pyrender
$PY scripts/readme_findings.py
$PY scripts/pilots/uncertainty_vs_coverage.py

git status --short -- results README.md
if $check; then
  git diff --quiet -- results README.md || { echo "error: regenerated outputs differ from the committed ones (git diff -- results README.md)" >&2; exit 1; }
  echo "IDENTICAL: every regenerated output is byte-identical to the committed one"
fi
