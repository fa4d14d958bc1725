#!/usr/bin/env bash
# The identifiability study (issue 11): which objective, with how many drives and which variables
# free, calibrates closest to the truth? CMA-ES (a leader on every VIO problem of the committed
# sweeps) on `synthetic` in the local space, for each objective x {1, 4 drives} x {10 free,
# 7 free (fy tied to fx, the lever arm's y and z frozen at the reference)}, seeds 0-4 (the
# optimiser's seed is also the data seed: five cameras, five noise realisations). Then the
# summary table and figure (scripts/identifiability.py).
#   bash scripts/make_identifiability.sh [evals]
set -euo pipefail
cd "$(dirname "$0")/.."
evals=${1:-400}
out=results/identifiability
rm -rf "$out"
four='[paper_540m,paper_540m,paper_540m,paper_540m]'
for objective in position_rmse innovation_nll; do
  for drives in one four; do
    for free in 10 7; do
      name="${objective}_${drives}drive_${free}free"
      d='[paper_540m]'; [ "$drives" = four ] && d=$four
      extra=(); [ "$free" = 7 ] && extra=(problem.params.tie_focal=true 'problem.params.fixed=[dy,dz]')
      start=$(date -u +%s)
      python -m bench problem=synthetic optimizer=cmaes seed='range(5)' budget.evals="$evals" report=false \
        problem.params.space=local problem.params.objective="$objective" "problem.params.drives=$d" \
        'problem.params.data_seed=${seed}' "${extra[@]}" hydra/launcher=joblib hydra.launcher.n_jobs=2 \
        hydra.sweep.dir="$out/$name"
      echo "- \`$name\`: $(date -u +%Y-%m-%dT%H:%MZ), commit $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- avio bench optimizers || echo '-dirty'), $(( $(date -u +%s) - start )) s" >> "$out/.provenance"
    done
  done
done
python scripts/identifiability.py "$out"
