#!/usr/bin/env bash
# Submits reflcap's whole flow to Slurm as job arrays with dependent merges:
#   reflcap-slurm.sh CAPTURE OUT [--shards N] [--fit-shards M] [--render-shards R] [--wait]
#                    [--sbatch "ARGS"] [--reflcap PATH] [--resample-args "ARGS"]
#                    [--fit-args "ARGS"] [--render-args "ARGS"] [--link-samples]
# resample (N tasks, a shard = a range of views) -> merge -> fit (M tasks, a shard = a range of
# chunks) -> merge (lobe transfer, albedo fill and the clusters run here, on the whole atlas) ->
# render the holdout split (R tasks) -> merge -> validate. Each stage's array starts when the
# merge before it succeeded (--dependency=afterok). OUT/samples, OUT/fit, OUT/renders and
# OUT/report are what `reflcap resample`, `fit`, `render` and `validate` write on one machine;
# the parts stay in OUT/parts. --wait blocks until the last job ends (sbatch --wait) and exits
# with its status. Prints the job IDs. A fit shard takes whole chunks of the store: M must not
# exceed its chunks (16,384 texels each unless --resample-args "--chunk-texels K"); a resample
# shard takes whole views (camera x turntable poses), a render shard whole photographs.
# --link-samples: OUT/samples is a linked store (`reflcap merge --link`) that reads the resample
# parts in OUT/parts as the fit goes, instead of a copy of their samples joined (the merge then
# writes only the maps: on the million preset 1.6 s instead of 6.0 s); keep OUT/parts with it.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
capture=${1:?CAPTURE}
out=${2:?OUT}
shift 2
shards=8 fit_shards="" render_shards="" wait_flag="" extra="" reflcap=${REFLCAP:-reflcap}
resample_args="" fit_args="" render_args="" link=""
while [ $# -gt 0 ]; do
  case "$1" in
    --shards) shards=$2; shift 2 ;;
    --fit-shards) fit_shards=$2; shift 2 ;;
    --render-shards) render_shards=$2; shift 2 ;;
    --wait) wait_flag=--wait; shift ;;
    --sbatch) extra=$2; shift 2 ;;
    --reflcap) reflcap=$2; shift 2 ;;
    --resample-args) resample_args=$2; shift 2 ;;
    --fit-args) fit_args=$2; shift 2 ;;
    --render-args) render_args=$2; shift 2 ;;
    --link-samples) link=--link; shift ;;
    *) echo "reflcap-slurm: unknown option $1" >&2; exit 1 ;;
  esac
done
fit_shards=${fit_shards:-$shards}
render_shards=${render_shards:-$shards}
reflcap=$(command -v "$reflcap" || echo "$reflcap")
export REFLCAP="$reflcap"
mkdir -p "$out/parts" "$out/logs"
out=$(cd "$out" && pwd)
capture=$(realpath "$capture")
submit() {  # sbatch with the common options; prints the job id
  # shellcheck disable=SC2086
  sbatch --parsable --export=ALL --chdir="$out" $extra "$@"
}
parts() {  # the part folders of a stage: PREFIX.0 .. PREFIX.(N-1)
  local prefix=$1 n=$2 list=""
  for ((i = 0; i < n; ++i)); do list+=" $prefix.$i"; done
  echo "$list"
}
log="$out/logs/%x-%A_%a.out"
r=$(submit --array=0-$((shards - 1)) --job-name=reflcap-resample --output="$log" \
      "$here/reflcap-shard.sbatch" resample "$capture" "$out/parts/resample" $resample_args)
rm=$(submit --dependency=afterok:$r --job-name=reflcap-merge-resample --output="$out/logs/%x-%j.out" \
      --wrap "\"$reflcap\" merge $(parts "$out/parts/resample" "$shards") --out \"$out/samples\" --overwrite $link")
f=$(submit --dependency=afterok:$rm --array=0-$((fit_shards - 1)) --job-name=reflcap-fit --output="$log" \
      "$here/reflcap-shard.sbatch" fit "$out/samples" "$out/parts/fit" $fit_args)
fm=$(submit --dependency=afterok:$f --job-name=reflcap-merge-fit --output="$out/logs/%x-%j.out" \
      --wrap "\"$reflcap\" merge $(parts "$out/parts/fit" "$fit_shards") --out \"$out/fit\" --overwrite")
g=$(submit --dependency=afterok:$fm --array=0-$((render_shards - 1)) --job-name=reflcap-render --output="$log" \
      "$here/reflcap-shard.sbatch" render "$capture" "$out/fit" "$out/parts/render" $render_args)
gm=$(submit --dependency=afterok:$g --job-name=reflcap-merge-render --output="$out/logs/%x-%j.out" \
      --wrap "\"$reflcap\" merge $(parts "$out/parts/render" "$render_shards") --out \"$out/renders\" --overwrite")
echo "jobs: resample $r, merge $rm, fit $f, merge $fm, render $g, merge $gm"
v=$(submit $wait_flag --dependency=afterok:$gm --job-name=reflcap-validate --output="$out/logs/%x-%j.out" \
      --wrap "\"$reflcap\" validate \"$capture\" \"$out/renders\" --fit \"$out/fit\" --out \"$out/report\" --overwrite")
echo "validate $v"
