// Shards and checkpoint folders (see shard.h).
#include "engine/core/shard.h"

#include <cstdio>

namespace reflcap {

StatusOr<Shard> ParseShard(const std::string& text) {
  if (text.empty()) return Shard{};
  int index = -1, count = -1;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%d/%d%c", &index, &count, &tail) != 2 || count < 1 ||
      count > kMaxShards || index < 0 || index >= count) {
    return InvalidArgumentError("--shard \"", text, "\": expected I/N with 0 <= I < N <= ",
                                kMaxShards, " (e.g. 0/8 for the first of 8 shards)");
  }
  return Shard{index, count};
}

StatusOr<ItemRange> ShardRange(Shard shard, uint32_t items, const std::string& what) {
  if (uint32_t(shard.count) > items) {
    return InvalidArgumentError("--shard ", shard.index, "/", shard.count, ": there are ", items,
                                " ", what, ", so at most that many shards (each shard takes whole ",
                                what, ")");
  }
  const uint64_t n = items;
  return ItemRange{uint32_t(shard.index * n / shard.count), uint32_t((shard.index + 1) * n / shard.count)};
}

StatusOr<std::vector<int>> PartOfEachShard(const std::vector<int>& shard_of_part, int count,
                                           const std::vector<std::string>& files,
                                           const std::string& what) {
  std::vector<int> part(size_t(count), -1);
  for (size_t i = 0; i < shard_of_part.size(); ++i) {
    int& slot = part[size_t(shard_of_part[i])];
    if (slot >= 0) {
      return FailedPreconditionError(files[i], ": shard ", shard_of_part[i], " is also ",
                                     files[size_t(slot)]);
    }
    slot = int(i);
  }
  for (int s = 0; s < count; ++s) {
    if (part[size_t(s)] < 0) {
      return FailedPreconditionError("merge: ", shard_of_part.size(), " parts given for a ", what,
                                     " of ", count, " shards (shard ", s, " is missing)");
    }
  }
  return part;
}

std::filesystem::path CheckpointDir(const std::filesystem::path& out) {
  std::filesystem::path dir = out;
  if (!dir.has_filename()) dir = dir.parent_path();  // "FIT/" -> "FIT"
  return dir.parent_path() / (dir.filename().string() + ".checkpoint");
}

CheckpointCleanup::~CheckpointCleanup() {
  std::error_code ec;
  if (dir_.empty() || !std::filesystem::exists(dir_, ec)) return;
  for (const auto& entry : std::filesystem::directory_iterator(dir_, ec)) {
    const std::filesystem::path& p = entry.path();
    if (p.filename() == marker_ || p.extension() == marker_) return;  // saved work: kept
  }
  std::filesystem::remove_all(dir_, ec);
}

}  // namespace reflcap
