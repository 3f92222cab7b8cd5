#pragma once
// Atomic output: every file reflcap writes goes to a temporary name beside its destination and is
// renamed into place only when complete, so an error or a crash never leaves half-written output.
#include <filesystem>
#include <functional>
#include <string>

#include "engine/core/status.h"

namespace reflcap {

// Calls `write(tmp_path)`; when it returns OK, renames tmp_path to `path` (replacing it),
// otherwise removes tmp_path and returns the writer's error. tmp_path sits in path's folder.
Status WriteFileAtomic(const std::filesystem::path& path,
                       const std::function<Status(const std::filesystem::path& tmp_path)>& write);

// Writes `contents` to `path` atomically.
Status WriteTextFileAtomic(const std::filesystem::path& path, const std::string& contents);

// Reads a whole file; NotFound when it does not exist.
StatusOr<std::string> ReadTextFile(const std::filesystem::path& path);

// An output folder built under a temporary name and moved into place by Commit().
// The destination must not exist, or exist empty, unless `overwrite`: then a previous folder is
// replaced only after the new one is complete. Destruction without Commit() removes the staging
// folder, so a failed run leaves nothing behind and touches nothing that was there.
class StagingDir {
 public:
  static StatusOr<StagingDir> Create(const std::filesystem::path& destination, bool overwrite);
  StagingDir(StagingDir&& other) noexcept;
  StagingDir& operator=(StagingDir&&) = delete;
  ~StagingDir();

  // Where to write now.
  const std::filesystem::path& path() const { return staging_; }
  const std::filesystem::path& destination() const { return destination_; }
  // Reports written inside the folder name the files they describe by path, which is the
  // staging path until Commit: this rewrites, in every .json and .html file under the folder,
  // each occurrence of the staging path (as written raw, JSON-escaped or HTML-escaped) to the
  // destination, so the committed reports name folders that exist. Internal on an I/O error.
  Status NameFinalPaths();
  Status Commit();

 private:
  StagingDir(std::filesystem::path destination, std::filesystem::path staging, bool overwrite)
      : destination_(std::move(destination)), staging_(std::move(staging)), overwrite_(overwrite) {}
  std::filesystem::path destination_;
  std::filesystem::path staging_;
  bool overwrite_ = false;
  bool committed_ = false;
};

}  // namespace reflcap
