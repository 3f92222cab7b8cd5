#!/usr/bin/env bash
# The overhead of sharding (issue 19): resample and fit as one run each, then as N shards run one
# after the other + their merges, on the same capture; wall seconds per process (/usr/bin/time),
# sums, the overhead in %, and a byte comparison of the outputs.
#
#   bench/shard_overhead.sh CAPTURE WORKDIR [N] [REFLCAP]
#   FIT_SHARDS=M (default N): fit shards, at most the store's chunks (16,384 texels each)
#
# CAPTURE: e.g. `reflcap synth --preset million --out CAPTURE`. WORKDIR is emptied of the folders
# this script writes (single_samples, part.*, linked, single_fit, fit_part.*, merged_fit); the
# times go to WORKDIR/times.log. Resample shards run without checkpoints (as the single run) and
# are joined with `merge --link`; fit shards read the linked store. Run it on a quiet machine: a
# sum of small processes is sensitive to other load. Results: bench/RESULTS.md, *Shards*.
set -euo pipefail
capture=$(realpath "${1:?CAPTURE}")
work=${2:?WORKDIR}
n=${3:-8}
m=${FIT_SHARDS:-$n}
reflcap=${4:-$(cd "$(dirname "$0")/.." && pwd)/build/bin/reflcap}
mkdir -p "$work"
cd "$work"
log=times.log
rm -rf single_samples part.* linked single_fit fit_part.* merged_fit "$log"
T() { local name=$1; shift; /usr/bin/time -f "$name %e s %M KB" -a -o "$log" "$@" > /dev/null; }
parts() { local prefix=$1 count=$2 list=""; for ((i = 0; i < count; ++i)); do list+=" $prefix.$i"; done; echo "$list"; }
T resample_single "$reflcap" resample "$capture" --out single_samples --quiet --no-checkpoint
for ((i = 0; i < n; ++i)); do
  T resample_shard_$i "$reflcap" resample "$capture" --out part.$i --quiet --shard $i/$n --no-checkpoint
done
# shellcheck disable=SC2046
T resample_merge "$reflcap" merge $(parts part "$n") --out linked --link
T fit_single "$reflcap" fit single_samples --out single_fit --quiet
for ((i = 0; i < m; ++i)); do
  T fit_shard_$i "$reflcap" fit linked --out fit_part.$i --quiet --shard $i/$m
done
# shellcheck disable=SC2046
T fit_merge "$reflcap" merge $(parts fit_part "$m") --out merged_fit
for f in atlas.bin coverage.exr coverage.png domain.exr; do
  cmp -s single_samples/$f linked/$f || echo "DIFFERS: samples $f" | tee -a "$log"
done
for f in params.exr sigma.exr status.exr; do
  cmp -s single_fit/$f merged_fit/$f || echo "DIFFERS: fit $f" | tee -a "$log"
done
awk '/resample_single/{rs=$2} /resample_shard/{rsh+=$2} /resample_merge/{rm=$2}
     /fit_single/{fs=$2} /fit_shard/{fsh+=$2} /fit_merge/{fm=$2}
     END{printf "resample %.2f s vs %.2f + %.2f = %.2f s (%+.1f %%)\n", rs, rsh, rm, rsh+rm, 100*(rsh+rm-rs)/rs;
         printf "fit      %.2f s vs %.2f + %.2f = %.2f s (%+.1f %%)\n", fs, fsh, fm, fsh+fm, 100*(fsh+fm-fs)/fs;
         printf "both     %.2f s vs %.2f s (%+.1f %%)\n", rs+fs, rsh+rm+fsh+fm, 100*(rsh+rm+fsh+fm-rs-fs)/(rs+fs)}' "$log" | tee -a "$log"
