#!/usr/bin/env bash
# Builds the libFuzzer targets (clang, -fsanitize=fuzzer,address,undefined) into build-fuzz/ and
# runs each for MINUTES minutes (default 10), then prints per target the executions, the coverage
# (libFuzzer's cov = edges, ft = features) and the findings. README.md, "Hardening".
#
#   tests/fuzz/run.sh [MINUTES] [TARGET...]     e.g. tests/fuzz/run.sh 2 capture obj
#   tests/fuzz/run.sh --check-seeds             run every seed once, printing the readers' verdicts
#
# Needs clang and libclang-rt-14-dev (Debian 12: apt-get install clang libclang-rt-14-dev), plus
# the packages of .ci/install-deps. Environment: BUILD_DIR (default build-fuzz), JOBS (ninja -j,
# default 2). The seeds in tests/fuzz/corpus/<target>/ stay untouched: each run grows a copy in
# BUILD_DIR/fuzz/work/<target>/; crashes, leaks, timeouts and OOMs land in
# BUILD_DIR/fuzz/artifacts/<target>/ (a fixed one goes back into the seeds as a regression case).
set -euo pipefail
cd "$(dirname "$0")/../.."

ALL=(capture calib intrinsics brackets scan_spec obj gltf png exr sample_chunk sample_store brdf_maps)
BUILD_DIR=${BUILD_DIR:-build-fuzz}
JOBS=${JOBS:-2}
# Per-input limits: an input that takes longer than this is a finding (a hang); so is one that
# makes the process exceed the RSS limit or asks for one allocation beyond the malloc limit (a
# reader must refuse an absurd header before allocating for it).
TIMEOUT_S=10
RSS_LIMIT_MB=2048
MALLOC_LIMIT_MB=1024

check_seeds=0
minutes=10
if [ "${1:-}" = "--check-seeds" ]; then check_seeds=1; shift
elif [[ "${1:-}" =~ ^[0-9]+(\.[0-9]+)?$ ]]; then minutes=$1; shift; fi
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=("${ALL[@]}")

command -v clang++ >/dev/null || { echo "run.sh: clang++ not found (apt-get install clang libclang-rt-14-dev)" >&2; exit 1; }
if [ ! -f "$BUILD_DIR/build.ninja" ]; then
  CC=clang CXX=clang++ cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DREFLCAP_FUZZ=ON -DREFLCAP_BUILD_TESTS=OFF -DREFLCAP_BUILD_BENCH=OFF -DREFLCAP_ENABLE_VULKAN=OFF
fi
ninja -C "$BUILD_DIR" -j"$JOBS" "${targets[@]/%/_fuzzer}"

export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
if [ $check_seeds -eq 1 ]; then
  for t in "${targets[@]}"; do
    for seed in tests/fuzz/corpus/"$t"/*; do
      verdict=$(REFLCAP_FUZZ_VERBOSE=1 "$BUILD_DIR/fuzz/${t}_fuzzer" "$seed" 2>&1 | grep -m1 '^rejected:' || true)
      echo "$t $(basename "$seed"): ${verdict:-accepted}"
    done
  done
  exit 0
fi

seconds=$(awk -v m="$minutes" 'BEGIN { printf "%d", m * 60 }')
summary=()
status=0
for t in "${targets[@]}"; do
  work="$BUILD_DIR/fuzz/work/$t"
  artifacts="$BUILD_DIR/fuzz/artifacts/$t"
  log="$BUILD_DIR/fuzz/$t.log"
  mkdir -p "$work" "$artifacts"
  echo "== $t: ${minutes} min (log: $log)"
  set +e
  "$BUILD_DIR/fuzz/${t}_fuzzer" "$work" "tests/fuzz/corpus/$t" -max_total_time="$seconds" \
    -timeout="$TIMEOUT_S" -rss_limit_mb="$RSS_LIMIT_MB" -malloc_limit_mb="$MALLOC_LIMIT_MB" \
    -artifact_prefix="$artifacts/" -print_final_stats=1 > "$log" 2>&1
  rc=$?
  set -e
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  line=$(grep -E '^#[0-9]+' "$log" | grep -E 'cov: ' | tail -1)
  cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$line")
  ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$line")
  corpus=$(sed -n 's/.* corp: \([0-9]*\/[0-9a-zA-Z]*\).*/\1/p' <<<"$line")
  found=$(find "$artifacts" -type f | wc -l)
  [ "$rc" -ne 0 ] && status=1
  summary+=("$(printf '%-14s %12s %8s %8s %12s %9s %4s' "$t" "${execs:-?}" "${cov:-?}" "${ft:-?}" "${corpus:-?}" "$found" "$rc")")
done
echo
printf '%-14s %12s %8s %8s %12s %9s %4s\n' target executions cov ft corpus artifacts rc
printf '%s\n' "${summary[@]}"
exit $status
