#!/usr/bin/env bash
# Builds the whole suite with sanitizers and runs it (README.md, "Hardening").
#
#   tests/sanitize.sh address [CTEST_ARGS...]   ASan + UBSan, every test      -> build-asan/
#   tests/sanitize.sh thread  [CTEST_ARGS...]   TSan, the multithreaded paths -> build-tsan/
#                                               (resample's reorder buffers, the fitter's
#                                               workers, the worker pool, the Vulkan submissions)
#
# g++ (the compiler of the regular build) with REFLCAP_SANITIZE=address,undefined or thread, Debug
# assertions off (RelWithDebInfo: -O2 -g, so the reports have lines). Any report fails its test:
# UBSan halts on the first error, ASan and TSan abort. Known reports from uninstrumented system
# libraries (lavapipe/LLVM, TBB, OpenMP in Open3D) are suppressed by the files in tests/sanitize/,
# each entry with its reason. Environment: JOBS (build and ctest parallelism, default 2);
# TARGETS (space-separated test binaries, e.g. "engine_image_test engine_mesh_test"): build and
# run only those (the suites of the binaries not built are left out); CMAKE_ARGS (more -D
# options, e.g. -DREFLCAP_ENABLE_VULKAN=OFF).
# Needs only the packages of .ci/install-deps (g++ ships libasan, libubsan and libtsan).
set -euo pipefail
cd "$(dirname "$0")/.."

mode=${1:-address}
shift || true
JOBS=${JOBS:-2}
supp=$PWD/tests/sanitize
case "$mode" in
  address)
    dir=build-asan
    flags=(-DREFLCAP_SANITIZE=address,undefined)
    export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:detect_stack_use_after_return=0}
    export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$supp/lsan.supp:print_suppressions=0}
    export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1:suppressions=$supp/ubsan.supp}
    filter=()
    ;;
  thread)
    dir=build-tsan
    flags=(-DREFLCAP_SANITIZE=thread)
    export TSAN_OPTIONS=${TSAN_OPTIONS:-halt_on_error=1:second_deadlock_stack=1:suppressions=$supp/tsan.supp}
    # The suites that drive the multithreaded paths.
    TARGETS=${TARGETS:-engine_core_test engine_fit_test acquire_resample_test engine_fit_vulkan_test}
    filter=()
    ;;
  *)
    echo "usage: tests/sanitize.sh address|thread [CTEST_ARGS...]" >&2
    exit 1
    ;;
esac

start=$(date +%s)
cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DREFLCAP_BUILD_BENCH=OFF "${flags[@]}" \
  ${CMAKE_ARGS:-}
if [ -n "${TARGETS:-}" ]; then
  # shellcheck disable=SC2086
  cmake --build "$dir" -j"$JOBS" --target $TARGETS
  filter+=(-E '_NOT_BUILT$')
else
  cmake --build "$dir" -j"$JOBS"
fi
built=$(date +%s)
set +e
if [ "$mode" = address ]; then
  # The suites through OpenCV's ColorChecker detection run with the slow unwinder: OpenCV has no
  # frame pointers, and only then does the suppression of its one-time Lab tables
  # (tests/sanitize/lsan.supp) see their frame. Everything else keeps the fast one (the slow one
  # does not finish the lavapipe tests).
  slow='DetectChart|CalibrateColour|Hdr'
  # The suites that render or build masks on lavapipe run without leak checking: allocations made
  # by lavapipe's JIT-compiled shader code have no module in their stacks (nothing a suppression
  # can match; the slow unwinder does not finish them), and LSan reports ~112 bytes of them in
  # every such test. ASan and UBSan still check every memory access of these tests.
  lavapipe='VulkanRendererScenes|VulkanCapture|VulkanCli|VulkanBatch|VulkanMasksTest'
  skip="$slow|$lavapipe"
  [ -n "${TARGETS:-}" ] && skip="$skip|_NOT_BUILT\$"
  ctest --test-dir "$dir" --output-on-failure -j"$JOBS" --timeout 1800 -E "$skip" "$@"
  rc=$?
  ASAN_OPTIONS="$ASAN_OPTIONS:fast_unwind_on_malloc=0" \
    ctest --test-dir "$dir" --output-on-failure -j"$JOBS" --timeout 1800 -R "$slow" "${filter[@]}" "$@"
  rc_slow=$?
  ASAN_OPTIONS="$ASAN_OPTIONS:detect_leaks=0" \
    ctest --test-dir "$dir" --output-on-failure -j"$JOBS" --timeout 1800 -R "$lavapipe" "${filter[@]}" "$@"
  rc_lavapipe=$?
  [ $rc -eq 0 ] && rc=$rc_slow
  [ $rc -eq 0 ] && rc=$rc_lavapipe
else
  ctest --test-dir "$dir" --output-on-failure -j"$JOBS" --timeout 1800 "${filter[@]}" "$@"
  rc=$?
fi
set -e
done_at=$(date +%s)
echo "sanitize.sh $mode: build $((built - start)) s, tests $((done_at - built)) s, ctest exit $rc"
exit $rc
