#!/usr/bin/env bash
# Rebuilds the committed results/: one sweep per problem (its report, Tables 1-3 and figures are
# built by the sweep itself, into results/<problem>/report/), then results/README.md's provenance.
#   bash scripts/make_results.sh [synthetic|kitti00|kitti00_tracks ...]
set -euo pipefail
cd "$(dirname "$0")/.."
problems=("${@:-synthetic kitti00 kitti00_tracks}")
common=(optimizer=psoga,pso,ga,cmaes,tpe,random hydra/launcher=joblib hydra.launcher.n_jobs=2)
for problem in ${problems[@]}; do
  case "$problem" in
    synthetic|kitti00) args=(seed='range(5)' budget.evals=600) ;;
    kitti00_tracks)    args=(seed='range(3)' budget.evals=300) ;;
    *) echo "unknown problem $problem" >&2; exit 2 ;;
  esac
  rm -rf "results/$problem"
  start=$(date -u +%s)
  python -m bench problem="$problem" "${common[@]}" "${args[@]}" hydra.sweep.dir="results/$problem"
  end=$(date -u +%s)
  {
    echo "- \`$problem\`: \`python -m bench problem=$problem ${common[*]} $(printf '%q ' "${args[@]}")hydra.sweep.dir=results/$problem\`"
    echo "  — $(date -u +%Y-%m-%dT%H:%MZ), commit $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- avio bench optimizers || echo '-dirty'), $((end - start)) s"
  } >> results/.provenance
done
