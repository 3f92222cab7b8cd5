#pragma once
// What the chosen Vulkan device can do at best, measured so that the benchmarks can state their
// rates as a fraction of it: float multiply-add throughput (shaders/bench/mad_throughput.comp,
// each invocation's result checked against a double-precision model before the timing counts)
// and device-to-device copy bandwidth. Used by reflcap_gpu_bench, reflcap_fit_bench and
// `reflcap bench` (bench/suite), which record the device, its driver and these peaks.
#include <string>

#include "engine/core/status.h"
#include "engine/gpu/vk_context.h"

namespace reflcap::bench {

struct DevicePeak {
  std::string device;        // DeviceInfo::ToString(): name, type, driver, Vulkan version
  double mad_gflops = 0;     // float multiply-add throughput, GFLOP/s (an FMA counts 2)
  double copy_gbps = 0;      // vkCmdCopyBuffer between device buffers, GB/s (read + write: bytes
                             // copied per second)
  std::string timing;        // "gpu-timestamps" or "wall-clock"
  bool software = false;     // a CPU device: its peaks are CPU peaks
};

// Measures the peaks on `ctx` (a few hundred milliseconds on a GPU, a few seconds on lavapipe).
// Internal error when the multiply-add kernel computes wrong values.
StatusOr<DevicePeak> MeasureDevicePeak(gpu::VkContext& ctx);

// Opens the device `device` ("" = automatic) and measures it; Unavailable without Vulkan.
StatusOr<DevicePeak> MeasureDevicePeak(const std::string& device);

// Flops of one residual evaluation of the fitter's normal equations with P parameters, by which
// the benchmarks convert residual evaluations into FLOP/s: the multiply-adds of J^T W J (P (P +
// 1) / 2) and J^T W r (P), two flops each, plus 40 for the model (base, exp/log of the lobe,
// slopes) and the residual. A count, not a timing: the kernels run more instructions (exp and log
// are polynomial on CPU devices, a hardware unit on GPUs).
double FitFlopsPerResidualEvaluation(int num_params);

}  // namespace reflcap::bench
