#pragma once
// Timing GPU work: timestamp queries where the queue supports them (timestampValidBits > 0),
// else the host's wall clock around submit + fence wait; every result says which it is.
// After uVkCompute's vulkan/timestamp_query_pool.h.
//
// GPU timestamps measure only the device's execution between the two timestamps; wall-clock
// times also include submission, scheduling and the fence wake-up (tens of microseconds on a
// GPU, more on lavapipe, whose "GPU" is the same CPU: its numbers are CPU numbers).
#include <vulkan/vulkan.h>

#include <cstdint>
#include <functional>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_context.h"

namespace reflcap::gpu {

enum class TimingSource { kGpuTimestamps, kWallClock };
// "GPU timestamps" / "wall clock (submit + fence wait)".
const char* TimingSourceName(TimingSource source);

// A pool of `count` timestamp queries on the context's queue.
class TimestampQueryPool {
 public:
  // Unavailable when the queue has no timestamps (timestampValidBits == 0).
  static StatusOr<TimestampQueryPool> Create(VkContext& ctx, uint32_t count);

  TimestampQueryPool() = default;
  ~TimestampQueryPool();
  TimestampQueryPool(TimestampQueryPool&& other) noexcept;
  TimestampQueryPool& operator=(TimestampQueryPool&& other) noexcept;
  TimestampQueryPool(const TimestampQueryPool&) = delete;
  TimestampQueryPool& operator=(const TimestampQueryPool&) = delete;

  // Records a reset of all queries (needed before writing them again) into `cmd`.
  Status Reset(CommandBuffer& cmd);
  // Records writing query `index` once all earlier commands have completed.
  Status Write(CommandBuffer& cmd, uint32_t index);
  // Seconds between queries `begin` and `end` after the submission has finished, with the
  // counter's valid bits and wrap-around taken into account.
  StatusOr<double> ElapsedSeconds(uint32_t begin, uint32_t end) const;
  uint32_t count() const { return count_; }

 private:
  void Release();

  VkDevice device_ = VK_NULL_HANDLE;
  VkQueryPool pool_ = VK_NULL_HANDLE;
  uint32_t count_ = 0;
  uint64_t mask_ = 0;     // valid bits
  double period_ns_ = 0;  // nanoseconds per tick
};

struct Timing {
  double seconds = 0;  // GPU time between the timestamps, or wall_seconds without them
  TimingSource source = TimingSource::kWallClock;
  double wall_seconds = 0;  // host time from vkQueueSubmit to the fence wait's return
};

// Times recorded work: Run begins `cmd`, writes a timestamp, lets `record` record into it, writes
// a second timestamp, submits, waits and returns the elapsed time, from the timestamps when the
// queue has them (source kGpuTimestamps) else from the wall clock (kWallClock). `record` failing
// fails Run with its Status.
class GpuTimer {
 public:
  // Never fails for lack of timestamps: it falls back to the wall clock.
  static StatusOr<GpuTimer> Create(VkContext& ctx);
  StatusOr<Timing> Run(CommandBuffer& cmd, const std::function<Status(CommandBuffer&)>& record);
  TimingSource source() const {
    return has_timestamps_ ? TimingSource::kGpuTimestamps : TimingSource::kWallClock;
  }

 private:
  bool has_timestamps_ = false;
  TimestampQueryPool pool_;
};

}  // namespace reflcap::gpu
