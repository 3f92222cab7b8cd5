#include "engine/gpu/vk_timestamps.h"

#include <utility>

#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {

const char* TimingSourceName(TimingSource source) {
  switch (source) {
    case TimingSource::kGpuTimestamps:
      return "GPU timestamps";
    case TimingSource::kWallClock:
      return "wall clock (submit + fence wait)";
  }
  return "unknown";
}

StatusOr<TimestampQueryPool> TimestampQueryPool::Create(VkContext& ctx, uint32_t count) {
  const DeviceInfo& d = ctx.info();
  if (d.timestamp_valid_bits == 0) {
    return UnavailableError("the compute queue of ", d.name, " has no timestamps");
  }
  if (count == 0) return InvalidArgumentError("TimestampQueryPool: count is 0");
  TimestampQueryPool p;
  p.device_ = ctx.device();
  p.count_ = count;
  p.mask_ =
      d.timestamp_valid_bits >= 64 ? ~uint64_t{0} : (uint64_t{1} << d.timestamp_valid_bits) - 1;
  p.period_ns_ = d.timestamp_period_ns;
  VkQueryPoolCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO;
  info.queryType = VK_QUERY_TYPE_TIMESTAMP;
  info.queryCount = count;
  VK_RETURN_IF_ERROR(vkCreateQueryPool(p.device_, &info, nullptr, &p.pool_));
  return p;
}

TimestampQueryPool::~TimestampQueryPool() { Release(); }

TimestampQueryPool::TimestampQueryPool(TimestampQueryPool&& other) noexcept {
  *this = std::move(other);
}

TimestampQueryPool& TimestampQueryPool::operator=(TimestampQueryPool&& other) noexcept {
  if (this != &other) {
    Release();
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    pool_ = std::exchange(other.pool_, VK_NULL_HANDLE);
    count_ = std::exchange(other.count_, 0);
    mask_ = other.mask_;
    period_ns_ = other.period_ns_;
  }
  return *this;
}

void TimestampQueryPool::Release() {
  if (device_ != VK_NULL_HANDLE && pool_ != VK_NULL_HANDLE) {
    vkDestroyQueryPool(device_, pool_, nullptr);
  }
  device_ = VK_NULL_HANDLE;
  pool_ = VK_NULL_HANDLE;
}

Status TimestampQueryPool::Reset(CommandBuffer& cmd) {
  if (pool_ == VK_NULL_HANDLE) return FailedPreconditionError("TimestampQueryPool: empty");
  if (!cmd.recording()) return FailedPreconditionError("TimestampQueryPool::Reset: not recording");
  vkCmdResetQueryPool(cmd.handle(), pool_, 0, count_);
  return OkStatus();
}

Status TimestampQueryPool::Write(CommandBuffer& cmd, uint32_t index) {
  if (pool_ == VK_NULL_HANDLE) return FailedPreconditionError("TimestampQueryPool: empty");
  if (!cmd.recording()) return FailedPreconditionError("TimestampQueryPool::Write: not recording");
  if (index >= count_) {
    return InvalidArgumentError("TimestampQueryPool::Write: query ", index, " of ", count_);
  }
  vkCmdWriteTimestamp(cmd.handle(), VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, pool_, index);
  return OkStatus();
}

StatusOr<double> TimestampQueryPool::ElapsedSeconds(uint32_t begin, uint32_t end) const {
  if (pool_ == VK_NULL_HANDLE) return FailedPreconditionError("TimestampQueryPool: empty");
  if (begin >= count_ || end >= count_) {
    return InvalidArgumentError("TimestampQueryPool::ElapsedSeconds: queries ", begin, ", ", end,
                                " of ", count_);
  }
  uint64_t ticks[2] = {0, 0};
  const uint32_t queries[2] = {begin, end};
  for (int i = 0; i < 2; ++i) {
    VK_RETURN_IF_ERROR(vkGetQueryPoolResults(device_, pool_, queries[i], 1, sizeof(uint64_t),
                                             &ticks[i], sizeof(uint64_t),
                                             VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
  }
  const uint64_t delta = (ticks[1] - ticks[0]) & mask_;  // wraps within the valid bits
  return static_cast<double>(delta) * period_ns_ * 1e-9;
}

StatusOr<GpuTimer> GpuTimer::Create(VkContext& ctx) {
  GpuTimer timer;
  if (ctx.info().timestamp_valid_bits > 0) {
    REFLCAP_ASSIGN_OR_RETURN(timer.pool_, TimestampQueryPool::Create(ctx, 2));
    timer.has_timestamps_ = true;
  }
  return timer;
}

StatusOr<Timing> GpuTimer::Run(CommandBuffer& cmd,
                               const std::function<Status(CommandBuffer&)>& record) {
  REFLCAP_RETURN_IF_ERROR(cmd.Begin());
  if (has_timestamps_) {
    REFLCAP_RETURN_IF_ERROR(pool_.Reset(cmd));
    // The first timestamp is written once all earlier work has completed; with no earlier work
    // in this command buffer, that is when this submission starts executing.
    REFLCAP_RETURN_IF_ERROR(pool_.Write(cmd, 0));
  }
  REFLCAP_RETURN_IF_ERROR(record(cmd));
  if (has_timestamps_) REFLCAP_RETURN_IF_ERROR(pool_.Write(cmd, 1));
  REFLCAP_RETURN_IF_ERROR(cmd.SubmitAndWait());
  Timing timing;
  timing.wall_seconds = cmd.last_submit_wall_s();
  if (has_timestamps_) {
    REFLCAP_ASSIGN_OR_RETURN(timing.seconds, pool_.ElapsedSeconds(0, 1));
    timing.source = TimingSource::kGpuTimestamps;
  } else {
    timing.seconds = timing.wall_seconds;
    timing.source = TimingSource::kWallClock;
  }
  return timing;
}

}  // namespace reflcap::gpu
