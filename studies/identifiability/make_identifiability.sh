#!/usr/bin/env bash
# The identifiability study (issue 11): which objective, with how many drives and which variables
# free, calibrates closest to the truth? CMA-ES (a leader on every VIO problem of the committed
# sweeps) on `synthetic` in the local space, for each objective x {1, 4 drives} x {10 free,
# 7 free (fy tied to fx, the lever arm's y and z frozen at the reference)}, plus both objectives
# with 16 drives and 7 free (does the error keep shrinking as 1/sqrt(drives)?) and with 4 drives
# and 5 free (the principal point frozen too: it trades against the rotation), and with one drive in
# four noise realisations, 7 free (same world and trajectory, independent noise: does averaging the
# noise alone do what four drives do?), seeds 0-4 (the
# optimiser's seed is also the data seed: five cameras, five noise realisations); and some
# configurations again with larger budgets (suffix _<N>evals: the 4-drive, 7-free ones, the
# likelihood's 4-drive, 10-free and 16-drive ones; does CMA-ES's error at the default budget
# belong to the objective or to the optimiser?), and both objectives' 4-drive, 7-free ones at
# 1,600 evaluations with seeds 0-9 (suffix _<K>seeds: is the 5-seed median within the seeds'
# scatter of the targets, and does the likelihood's lead hold?), and those two again with the
# outlier decisions of a filter at the reference imposed on every calibration (suffix
# _refdecisions, FilterConfig.outlier_decisions: do the runs end nearer the truth when the
# objective no longer jumps with the decisions?), and the likelihood's with the reference's
# transfer-gain and baseline checks imposed too (suffix _refall, outlier_decisions=reference_all:
# the last per-filter decisions, which left jumps along dx), and the likelihood's own- and
# reference_all-decision ones and the RMSE's with seeds 0-19 (do the leads seen over ten seeds
# hold over twenty?), and (issue 33) the joint likelihood's 4-drive, 7-free one and the excited
# rig's rows (suffixes _full3d, _td), and the joint likelihood with each feature's Jacobian at its
# corrected pixels (suffix _corrected) and its 16-drive rows with and without. Then the summary table and figure
# (studies/identifiability/identifiability.py).
#   bash studies/identifiability/make_identifiability.sh [--seeds K] [evals] [configuration ...]
# With configuration names (e.g. innovation_nll_sixteendrive_7free) only those are (re-)made and the
# others kept; without, the whole study is re-made. With --seeds K, a named configuration without a
# _<K>seeds suffix has K seeds instead of 5, and one that already has records keeps them: only the
# seeds it lacks are run (their job folders i<k> beside its seed<k> ones, their sweep's multirun.yaml
# kept as multirun_seeds<first>-<last>.yaml), so a row grows from 5 to K seeds without re-running the
# first five (they are the same runs: same instance, same data and optimiser seeds).
set -euo pipefail
cd "$(dirname "$0")/../.."
want=""
if [ "${1:-}" = --seeds ]; then
  want=${2:?make_identifiability: --seeds needs a number}
  [[ $want =~ ^[1-9][0-9]*$ ]] || { echo "make_identifiability: --seeds $want: not a positive whole number" >&2; exit 2; }
  shift 2
fi
evals=${1:-400}
shift || true
out=results/identifiability
all=()
for objective in position_rmse innovation_nll; do
  for drives in one four; do
    for free in 10 7; do all+=("${objective}_${drives}drive_${free}free"); done
  done
done
all+=(position_rmse_sixteendrive_7free innovation_nll_sixteendrive_7free position_rmse_fourdrive_5free
      innovation_nll_fourdrive_5free position_rmse_onedrive_fournoise_7free innovation_nll_onedrive_fournoise_7free
      innovation_nll_fourdrive_7free_1600evals innovation_nll_fourdrive_7free_3200evals
      position_rmse_fourdrive_7free_1600evals innovation_nll_fourdrive_10free_1600evals
      innovation_nll_sixteendrive_7free_1600evals innovation_nll_fourdrive_7free_1600evals_10seeds
      position_rmse_fourdrive_7free_1600evals_10seeds innovation_nll_fourdrive_7free_refdecisions_1600evals_10seeds
      position_rmse_fourdrive_7free_refdecisions_1600evals_10seeds innovation_nll_fourdrive_7free_refall_1600evals_10seeds
      innovation_nll_fourdrive_7free_1600evals_20seeds innovation_nll_fourdrive_7free_refall_1600evals_20seeds
      position_rmse_fourdrive_7free_1600evals_20seeds innovation_nll_joint_fourdrive_7free_refall_1600evals_10seeds)
# issue 33: the excited rig (suffix _full3d: drives full3d_540m), all 10 free and with the time
# offset as an 11th (suffix _td), 1 and 4 drives, each objective (likelihoods with reference_all)
for objective in position_rmse innovation_nll innovation_nll_joint; do
  decide=""; [ "$objective" != position_rmse ] && decide=_refall
  for drives in one four; do
    for td in "" _td; do all+=("${objective}_${drives}drive_10free_full3d${td}${decide}_1600evals_10seeds"); done
  done
done
# issue 33: each feature's Jacobian at its corrected pixels (suffix _corrected, docs/model.md Eqs. 35a-b): the joint
# likelihood, 4 drives, on the flat city (7 free) and the excited rig (10 free), and 16 flat-city drives with
# and without (does removing the fy tilt show where the drives' scatter is smaller?)
all+=(innovation_nll_joint_fourdrive_7free_refall_corrected_1600evals_10seeds
      innovation_nll_joint_fourdrive_10free_full3d_refall_corrected_1600evals_10seeds
      innovation_nll_joint_sixteendrive_7free_refall_1600evals_10seeds
      innovation_nll_joint_sixteendrive_7free_refall_corrected_1600evals_10seeds)
# issue 33: the adjusted joint likelihood (innovation_nll_adjusted, docs/model.md Eq. 55b: its fy tilt at the truth
# cancelled), 4 flat-city drives, 7 free, and 4 excited-rig drives, all 10 free
all+=(innovation_nll_adjusted_fourdrive_7free_refall_1600evals_10seeds
      innovation_nll_adjusted_fourdrive_10free_full3d_refall_1600evals_10seeds)
# issue 33: the adjusted joint likelihood with each feature's Jacobian alone at its corrected pixels, its noise model
# at the measured ones (suffix _correctedjac, docs/model.md Eq. 35c: smooth, and half the cross-update excess)
all+=(innovation_nll_adjusted_fourdrive_7free_refall_correctedjac_1600evals_10seeds
      innovation_nll_adjusted_fourdrive_10free_full3d_refall_correctedjac_1600evals_10seeds
      innovation_nll_adjusted_sixteendrive_7free_refall_correctedjac_1600evals_10seeds)
# issue 33: the joint likelihood's two 16-drive rows with seeds 10-19 added (made from the _10seeds rows with
# --seeds 20: does the corrected pixels' lead at 16 drives, 7 of 10 seeds, hold over twenty?)
all+=(innovation_nll_joint_sixteendrive_7free_refall_1600evals_20seeds
      innovation_nll_joint_sixteendrive_7free_refall_corrected_1600evals_20seeds)
# --seeds 25 (the _20seeds rows' records copied in first, seeds 20-24 added): is the corrected pixels'
# undecided lead at twenty seeds (p = 0.097) decided by five more?
all+=(innovation_nll_joint_sixteendrive_7free_refall_1600evals_25seeds
      innovation_nll_joint_sixteendrive_7free_refall_corrected_1600evals_25seeds)
# the filter assuming 1.0 px where the drives have 0.7 (suffix _sigma1p0): does a likelihood that trusts each
# update less, so that fewer errors outlive P across updates, calibrate closer at 4 flat drives?
all+=(innovation_nll_joint_fourdrive_7free_refall_sigma1p0_1600evals_10seeds)
if [ $# -eq 0 ]; then rm -rf "$out"; set -- "${all[@]}"; fi
mkdir -p "$out"
for name in "$@"; do
  [[ " ${all[*]} " == *" $name "* ]] || { echo "make_identifiability: unknown configuration $name; valid: ${all[*]}" >&2; exit 2; }
  seeds=${want:-5} budget=$evals base=$name
  if [[ $base =~ _([0-9]+)seeds$ ]]; then seeds=${BASH_REMATCH[1]}; base=${base%_*seeds}; fi
  if [[ $base =~ _([0-9]+)evals$ ]]; then budget=${BASH_REMATCH[1]}; base=${base%_*evals}; fi
  # a likelihood's default decisions are reference_all (bench/problems/vio.py): a configuration without a
  # decisions suffix means the filters' own, so it says so
  # suffix _corrected: each feature's Jacobian at its corrected pixels (FilterConfig.jacobian_pixels, issue 33)
  jac=""; [[ $base == *_corrected ]] && { jac=", jacobian_pixels: corrected"; base=${base%_corrected}; }
  # suffix _correctedjac: the Jacobian alone there, the noise model at the measured pixels (Eq. 35c)
  [[ $base == *_correctedjac ]] && { jac=", jacobian_pixels: corrected_jacobian"; base=${base%_correctedjac}; }
  # suffix _sigma<a>p<b>: the filter assumes a pixel noise of a.b px (FilterConfig.pixel_sigma_px; the drives' is 0.7)
  if [[ $base =~ _sigma([0-9]+)p([0-9]+)$ ]]; then
    jac="$jac, pixel_sigma_px: ${BASH_REMATCH[1]}.${BASH_REMATCH[2]}"; base=${base%_sigma*}
  fi
  decisions=("problem.params.filter={outlier_decisions: own$jac}"); [[ $base == *_refdecisions ]] && { decisions=("problem.params.filter={outlier_decisions: reference$jac}"); base=${base%_refdecisions}; }
  [[ $base == *_refall ]] && { decisions=("problem.params.filter={outlier_decisions: reference_all$jac}"); base=${base%_refall}; }
  preset=paper_540m; timing=()
  [[ $base == *_td ]] && { timing=(problem.params.with_time_offset=true); base=${base%_td}; }
  [[ $base == *_full3d ]] && { preset=full3d_540m; base=${base%_full3d}; }
  objective=${base%_*drive_*free}
  rest=${base#"${objective}_"}
  case ${rest%%drive_*} in one) n=1 ;; four) n=4 ;; sixteen) n=16 ;; esac
  free=${base##*_}; free=${free%free}
  noise=1; [[ $rest == *_fournoise_* ]] && noise=4
  d="[$(printf "$preset,%.0s" $(seq "$n"))]"; d=${d/,]/]}
  extra=(); [ "$free" = 7 ] && extra=(problem.params.tie_focal=true 'problem.params.fixed=[dy,dz]')
  [ "$free" = 5 ] && extra=(problem.params.tie_focal=true 'problem.params.fixed=[cx,cy,dy,dz]')
  have=0 sweep="$out/$name"
  if [ -n "$want" ] && { [ -f "$out/$name/records.tar.xz" ] || [ -d "$out/$name/synthetic" ]; }; then
    # keep the configuration's finished jobs: restore them from the archive (the summary re-packs them), or
    # count those an interrupted run left unpacked
    have=$(python - "$out/$name" <<'PY'
import sys
from pathlib import Path
sys.path.insert(0, "studies/identifiability")
from identifiability import restored_seeds
print(restored_seeds(Path(sys.argv[1])))
PY
)
    if [ "$have" -ge "$seeds" ]; then echo "- $name: has $have seeds already"; continue; fi
    sweep="$out/$name/.seeds$have-$((seeds - 1))"
    rm -rf "$sweep"
  else
    rm -rf "${out:?}/$name"
  fi
  start=$(date -u +%s)
  # instance k: the camera and drives of data seed k, and CMA-ES's seed k (configurations made before
  # instances existed swept seed=range(k) with data_seed=${seed}: the same runs, folders seed<k>)
  python -m bench problem=synthetic optimizer=cmaes instance="range($have,$seeds)" budget.evals="$budget" report=false \
    problem.params.space=local problem.params.objective="$objective" "problem.params.drives=$d" \
    problem.params.noise_realisations=$noise "${extra[@]}" "${decisions[@]}" "${timing[@]}" hydra/launcher=joblib hydra.launcher.n_jobs=2 \
    hydra.sweep.dir="$sweep"
  added=""
  if [ "$sweep" != "$out/$name" ]; then
    mv "$sweep"/synthetic/cmaes/i* "$out/$name/synthetic/cmaes/"
    mv "$sweep/multirun.yaml" "$out/$name/multirun_seeds$have-$((seeds - 1)).yaml"
    [ -f "$sweep/.outcomes.jsonl" ] && cat "$sweep/.outcomes.jsonl" >> "$out/$name/.outcomes.jsonl"
    rm -rf "$sweep"
    added=" (seeds $have-$((seeds - 1)) added)"
  fi
  echo "- \`$name\`$added: $(date -u +%Y-%m-%dT%H:%MZ), commit $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- avio bench optimizers || echo '-dirty'), $(( $(date -u +%s) - start )) s" >> "$out/.provenance"
done
# the summary, then each new configuration packed into its records.tar.xz without the evaluation logs
python studies/identifiability/identifiability.py "$out" --pack
