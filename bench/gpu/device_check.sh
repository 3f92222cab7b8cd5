#!/usr/bin/env bash
# device_check.sh: one call's worth of GPU checks for issue 14, run on a lent GPU machine after
# bench/gpu/pack.sh (../shared/tools/gpu-bundle.sh less the scanner; carry .gl and .gpu; the command is
#   . .gpu/run-prologue.sh && bash bench/gpu/device_check.sh
# ). Writes its logs and the million run's reports under $OUT (at most 8 files come back) and
# prints a summary. 156 s on an H200 host at 01841b1 (tests 60 s, synth 21 s, run 35 s, fits
# 11 s, benchmarks 23 s); 207 s at 7447d4e, with the fit at 4 and 8 threads beside 16 and 64 MiB
# transfers over 4-32 MiB staging pieces; since then also the photographs' read and decode rates
# (~10 s), and the render variants (183-213 s in all at bb5f5f6-b7f27cc; 197 s at ae2cc8d);
# since the sixteenth session also five render runs over flights and batch sizes (not yet timed
# on a device: ~5 s each expected) and the clusters' k-fold batches in the fit table.
# BM_FitTexelsVulkanStaged runs beside BM_FitTexelsVulkan: the fit's records through the staging
# ring against mapped device memory. Record every number with the device line it prints.
set -u
: "${BUILD:?source .gpu/run-prologue.sh first}" "${OUT:?run through the device tool (OUT unset)}"
R=$BUILD/bin/reflcap
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 | tee "$OUT/device.txt"
{ nproc; lscpu 2>/dev/null | grep -E "Model name|Thread|Core|Socket|MHz"; } | tee -a "$OUT/device.txt"
# Transparent huge pages: the sample store's chunks are advised MADV_HUGEPAGE (core/large_buffer.h),
# which only "always" or "madvise" honours.
echo "THP: $(cat /sys/kernel/mm/transparent_hugepage/enabled 2>/dev/null)" | tee -a "$OUT/device.txt"

# 1. Every test, one process each (a teardown crash shows here), plus the masks' figures.
# (The scanner's tests are left out with its binaries: pack.sh.)
timeout 240 ctest --test-dir "$BUILD" -j16 --timeout 150 --output-on-failure \
  -E "layering|^Scan(Decode|Pipeline|SharedData|Spec|Triangulate|Cli)\.|^UvAtlas\.|^BadInputCorpus\.Scan$" \
  > "$OUT/ctest.log" 2>&1
grep -E "tests passed|\*\*\*Failed|SEGFAULT|Timeout|Not Run" "$OUT/ctest.log" | head -20
"$BUILD"/tests/acquire/resample/acquire_resample_test --gtest_filter='VulkanMasksTest.*' 2>&1 |
  grep -E "max relative|agreeing|FAILED" | head -12
stamp "tests done"

# 2. The million preset end to end on the GPU, and the fit alone on both backends.
{ time "$R" synth --preset million --out /tmp/mil --quiet ; } 2>&1 | grep real
stamp "synth done"
{ time "$R" run /tmp/mil --out /tmp/mil_run --backend vulkan ; } > "$OUT/run.log" 2>&1
grep -E "reflcap run:|^real" "$OUT/run.log"
python3 - "$OUT" <<'PY'
import json, sys, shutil
out = sys.argv[1]
reports = {"resample": "/tmp/mil_run/samples/resample_report.json",
           "render": "/tmp/mil_run/renders/render_report.json",
           "metrics": "/tmp/mil_run/report/metrics.json",
           "fit": "/tmp/mil_run/fit/fit_report.json"}
merged = {}
for name, path in reports.items():
    try:
        d = json.load(open(path))
    except OSError as e:
        merged[name] = str(e)
        continue
    merged[name] = {k: d[k] for k in ("timings", "timings_s", "vulkan", "pixel_model", "indirect",
                                      "backend", "read_ahead") if k in d}
json.dump(merged, open(out + "/reports.json", "w"), indent=1)
print(json.dumps({k: v.get("timings", v.get("timings_s")) if isinstance(v, dict) else v
                  for k, v in merged.items()})[:2000])
PY
stamp "run done"
# The resample waited 4.5-5.1 s for photographs at 8482aff / 7447d4e: from the disk, or decoding?
{ time cat /tmp/mil/images/*.exr > /dev/null ; } 2>&1 | grep real | sed 's/^/read 288 photographs: /'
REFLCAP_BENCH_PHOTOGRAPH=/tmp/mil/images/0000.exr timeout 60 \
  "$BUILD"/bench/acquire/reflcap_resample_bench --benchmark_filter='BM_ReadPhotograph' 2>&1 |
  grep -E "^BM_" | awk '{print $1, $2, $3, $NF}'
for b in vulkan cpu; do
  { time "$R" fit /tmp/mil_run/samples --out /tmp/fit_$b --backend $b --quiet ; } 2>&1 | grep real
done
# How the fit's stages scale with the host's threads (serial parts show as stages that do not
# shrink from 4 to 16 threads).
for th in 4 8; do
  "$R" fit /tmp/mil_run/samples --out /tmp/fit_t$th --backend vulkan --threads $th --quiet > /dev/null 2>&1
done
# One chunk at a time (the default on a GPU is two in flight, each on its own fitter).
"$R" fit /tmp/mil_run/samples --out /tmp/fit_seq --backend vulkan --vulkan-chunks-in-flight 1 \
  --quiet > /dev/null 2>&1
# Stages at 4, 8 and 16 threads (vulkan), one chunk in flight at 16, and the CPU backend's at
# 16: a stage that does not shrink with threads is serial; setup is the fitter's creation (a
# Vulkan device).
python3 - "$OUT" <<'PY' | tee "$OUT/fit_threads.txt"
import json, sys
cols = (("4", "/tmp/fit_t4"), ("8", "/tmp/fit_t8"), ("16", "/tmp/fit_vulkan"),
        ("seq16", "/tmp/fit_seq"), ("cpu16", "/tmp/fit_cpu"))
rows = {}
for name, d in cols:
    try:
        report = json.load(open(d + "/fit_report.json"))
        rows[name] = dict(report["timings_s"])
        # Batches of the clusters' k-fold refits (a count, not seconds).
        rows[name]["kfold_batches"] = report["clusters"].get("kfold_batches", float("nan"))
    except OSError:
        rows[name] = {}
print(f"{'stage':26s}" + "".join(f" {n:>8s}" for n, _ in cols))
for k in rows["16"]:
    print(f"{k:26s}" + "".join(f" {rows[n].get(k, float('nan')):8.3f}" for n, _ in cols))
# Where the Vulkan fit pass's time went (seconds summed over chunks; two chunks in flight overlap).
for name, d in cols[:4]:
    try:
        v = json.load(open(d + "/fit_report.json")).get("vulkan", {})
    except OSError:
        continue
    print(f"vulkan {name}: " + ", ".join(f"{k} {v[k]:.3f}" for k in
          ("device_s", "prepare_s", "prepare_texel_thread_s", "prepare_layout_thread_s", "finish_s")
          if k in v))
PY
stamp "fits done"

# 3. Micro-benchmarks: fits/s over 10^6 texels, render batches, transfers.
timeout 120 "$BUILD"/bench/engine/reflcap_fit_bench --benchmark_filter='BM_FitTexels.*/1000000' 2>&1 |
  grep -E "^BM_|device_" | tee "$OUT/fit_bench.txt"
# The host's per-texel work on one thread of this host (PrepareTexel 5 us, FinishProblem 0.47 us
# a problem on the 2-core VM): what sets prepare_s and finish_s above.
timeout 60 "$BUILD"/bench/engine/reflcap_fit_bench --benchmark_filter='BM_PrepareTexel|BM_FinishProblem' 2>&1 |
  grep -E "^BM_" | tee -a "$OUT/fit_bench.txt"
# The batched renderer with one cost taken away at a time (aux read-back, host shadow edges,
# shadow-map drawing), against the rasterised paths, with device timestamps: what limits it.
# Then 1024 px.
REFLCAP_BENCH_RENDER_SIZES=512 REFLCAP_BENCH_RENDER_VARIANTS=1 timeout 90 \
  "$BUILD"/bench/render/reflcap_render_bench --benchmark_filter='BM_RenderBatch/vulkan/512/64' 2>&1 |
  grep -E "^BM_" | tee "$OUT/render_bench.txt"
# Submissions in flight and images per submission (defaults 3 and 16). At ae2cc8d the host
# waited 0.12 ms an image on fences and the device idled ~0.14 ms an image (0.58 ms an image
# against 0.44 of device time): do more flights, or other batch sizes, overlap them better?
while read -r flights images; do
  REFLCAP_BENCH_RENDER_SIZES=512 REFLCAP_BENCH_RENDER_IN_FLIGHT=$flights \
    REFLCAP_BENCH_RENDER_BATCH_IMAGES=$images timeout 30 \
    "$BUILD"/bench/render/reflcap_render_bench --benchmark_filter='BM_RenderBatch/vulkan/512/64/real_time$' 2>&1 |
    grep -E "^BM_" | sed "s/^/in_flight $flights, batch $images: /" | tee -a "$OUT/render_bench.txt"
done <<'CFG'
2 16
4 16
6 16
3 8
3 32
CFG
REFLCAP_BENCH_RENDER_SIZES=1024 timeout 60 \
  "$BUILD"/bench/render/reflcap_render_bench --benchmark_filter='BM_RenderBatch/vulkan/1024/64' 2>&1 |
  grep -E "^BM_" | tee -a "$OUT/render_bench.txt"
timeout 60 "$BUILD"/bench/gpu/reflcap_gpu_bench --benchmark_filter='BM_(Upload|Download)Staged/64|BM_Mad' 2>&1 |
  grep -E "^BM_" | tee "$OUT/gpu_bench.txt"
stamp "all done"
