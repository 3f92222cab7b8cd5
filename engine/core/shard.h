#pragma once
// Shards and checkpoint folders: how a stage runs as N independent jobs (a Slurm job array, a
// Kubernetes indexed job) and where it keeps what a killed run needs to continue.
#include <cstdint>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "engine/core/status.h"

namespace reflcap {

// Shard `index` of `count` (0 <= index < count): `--shard I/N`.
struct Shard {
  int index = 0;
  int count = 1;
};
// Job arrays larger than this are not a batch system's (Slurm's MaxArraySize defaults to 1001).
constexpr int kMaxShards = 100000;
// "3/8" -> {3, 8}; "" (no --shard) -> {0, 1}, the whole work. InvalidArgument (naming --shard)
// unless 0 <= I < N <= kMaxShards.
StatusOr<Shard> ParseShard(const std::string& text);

// Items [begin, end) of shard `shard` among `items` in order: floor(I n / N) .. floor((I+1) n / N)
// — contiguous, every item in exactly one shard, shard sizes differing by at most one.
// InvalidArgument naming `what` ("chunks", "views") when N > items (a shard would be empty).
struct ItemRange {
  uint32_t begin = 0;
  uint32_t end = 0;
};
StatusOr<ItemRange> ShardRange(Shard shard, uint32_t items, const std::string& what);

// Which part holds each shard 0..count-1, given the shard index of every part (each in [0,
// count)) and the part files named in messages: the answer's entry s is the index into `files`.
// FailedPrecondition naming both files when a shard is given twice, or the first missing shard
// ("merge: K parts given for a WHAT of N shards (shard s is missing)").
StatusOr<std::vector<int>> PartOfEachShard(const std::vector<int>& shard_of_part, int count,
                                           const std::vector<std::string>& files,
                                           const std::string& what);

// The checkpoint folder of an output: OUT.checkpoint beside OUT.
std::filesystem::path CheckpointDir(const std::filesystem::path& out);

// Removes a checkpoint folder on scope exit unless Keep() was called or it then holds a file
// named `marker` (work that --resume can continue): a run that fails before it saved anything
// leaves no folder that would make the next run ask for --resume.
class CheckpointCleanup {
 public:
  CheckpointCleanup(std::filesystem::path dir, std::string marker_extension)
      : dir_(std::move(dir)), marker_(std::move(marker_extension)) {}
  ~CheckpointCleanup();
  CheckpointCleanup(const CheckpointCleanup&) = delete;
  CheckpointCleanup& operator=(const CheckpointCleanup&) = delete;

 private:
  std::filesystem::path dir_;
  std::string marker_;  // a file name or an extension (".rcf")
};

}  // namespace reflcap
