#include "engine/core/atomic_file.h"

#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <system_error>
#include <utility>
#include <vector>

#include "engine/core/html.h"

namespace reflcap {
namespace fs = std::filesystem;

namespace {
// A name unique within this process and across concurrent processes.
std::string TempSuffix() {
  static std::atomic<int> counter{0};
  return StrCat(".tmp-", ::getpid(), "-", counter++);
}
}  // namespace

Status WriteFileAtomic(const fs::path& path,
                       const std::function<Status(const fs::path& tmp_path)>& write) {
  fs::path dir = path.parent_path();
  std::error_code ec;
  if (!dir.empty() && !fs::exists(dir, ec)) {
    return NotFoundError(path.string(), ": output folder does not exist");
  }
  fs::path tmp = dir / ("." + path.filename().string() + TempSuffix());
  Status status = write(tmp);
  if (!status.ok()) {
    fs::remove(tmp, ec);
    return status;
  }
  fs::rename(tmp, path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    return InternalError(path.string(), ": cannot rename temporary file into place: ", ec.message());
  }
  return OkStatus();
}

Status WriteTextFileAtomic(const fs::path& path, const std::string& contents) {
  return WriteFileAtomic(path, [&](const fs::path& tmp) -> Status {
    std::ofstream out(tmp, std::ios::binary);
    out << contents;
    out.close();
    if (!out) return InternalError(path.string(), ": write failed");
    return OkStatus();
  });
}

StatusOr<std::string> ReadTextFile(const fs::path& path) {
  // Read in blocks straight into the string (a stringstream copy took ~12 ms for a 4 MB
  // atlas.bin, read by every fit shard for each part of a linked store); the size is a hint
  // only, so a file that grows or a pipe still reads whole.
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return NotFoundError(path.string(), ": cannot open file");
  std::error_code ec;
  const uintmax_t hint = fs::file_size(path, ec);
  std::string bytes;
  if (!ec) bytes.reserve(size_t(hint));
  char block[1 << 16];
  size_t got;
  while ((got = std::fread(block, 1, sizeof block, f.get())) > 0) bytes.append(block, got);
  if (std::ferror(f.get())) return DataLossError(path.string(), ": read failed");
  return bytes;
}

StatusOr<StagingDir> StagingDir::Create(const fs::path& destination, bool overwrite) {
  std::error_code ec;
  fs::path dest = fs::absolute(destination, ec);
  if (fs::exists(dest, ec)) {
    if (!fs::is_directory(dest, ec)) {
      return FailedPreconditionError(destination.string(), ": exists and is not a folder");
    }
    if (!overwrite && !fs::is_empty(dest, ec)) {
      return FailedPreconditionError(destination.string(),
                                     ": folder exists and is not empty (pass --overwrite to "
                                     "replace it, or choose another --out)");
    }
  }
  // An output folder that cannot be made where the user asked is bad input (exit 2), named as
  // given, not by the staging folder the user never named.
  fs::path parent = dest.parent_path();
  fs::create_directories(parent, ec);
  if (ec) {
    return FailedPreconditionError(destination.string(), ": cannot create folder ",
                                   parent.string(), ": ", ec.message());
  }
  fs::path staging = parent / ("." + dest.filename().string() + TempSuffix());
  fs::create_directories(staging, ec);
  if (ec) {
    return FailedPreconditionError(destination.string(), ": cannot create folder (its staging "
                                   "folder ", staging.filename().string(), " in ", parent.string(),
                                   "): ", ec.message());
  }
  return StagingDir(dest, staging, overwrite);
}

StagingDir::StagingDir(StagingDir&& other) noexcept
    : destination_(std::move(other.destination_)),
      staging_(std::move(other.staging_)),
      overwrite_(other.overwrite_),
      committed_(other.committed_) {
  other.committed_ = true;  // the moved-from object owns nothing
}

StagingDir::~StagingDir() {
  if (committed_) return;
  std::error_code ec;
  fs::remove_all(staging_, ec);
}

Status StagingDir::NameFinalPaths() {
  const std::string from = staging_.string(), to = destination_.string();
  // The forms a path takes in the files reflcap writes: raw, inside a JSON string (nlohmann's
  // escapes: backslash, quote, control characters; UTF-8 as is), in HTML.
  auto json_escaped = [](const std::string& text) {
    std::string out;
    for (const char c : text) {
      if (c == '"' || c == '\\') {
        out += '\\';
        out += c;
      } else if (static_cast<unsigned char>(c) < 0x20) {
        char buf[8];
        std::snprintf(buf, sizeof buf, "\\u%04x", unsigned(static_cast<unsigned char>(c)));
        out += buf;
      } else {
        out += c;
      }
    }
    return out;
  };
  const std::vector<std::pair<std::string, std::string>> forms = {
      {from, to}, {json_escaped(from), json_escaped(to)}, {HtmlEscape(from), HtmlEscape(to)}};
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(staging_, ec);
       !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const fs::path& p = it->path();
    if (!it->is_regular_file(ec) || (p.extension() != ".json" && p.extension() != ".html")) continue;
    REFLCAP_ASSIGN_OR_RETURN(std::string text, ReadTextFile(p));
    bool changed = false;
    for (const auto& [a, b] : forms) {
      if (a == b || a.empty()) continue;
      for (size_t at = text.find(a); at != std::string::npos; at = text.find(a, at + b.size())) {
        text.replace(at, a.size(), b);
        changed = true;
      }
    }
    if (changed) REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(p, text));
  }
  if (ec) return InternalError(staging_.string(), ": cannot list the folder: ", ec.message());
  return OkStatus();
}

Status StagingDir::Commit() {
  REFLCAP_CHECK(!committed_) << "StagingDir committed twice";
  std::error_code ec;
  fs::path old;
  if (fs::exists(destination_, ec)) {
    // Move the previous folder aside first so the swap is two renames; delete it afterwards.
    old = destination_.parent_path() / ("." + destination_.filename().string() + ".old" +
                                         TempSuffix());
    fs::rename(destination_, old, ec);
    if (ec) return InternalError(destination_.string(), ": cannot replace folder: ", ec.message());
  }
  fs::rename(staging_, destination_, ec);
  if (ec) {
    if (!old.empty()) fs::rename(old, destination_, ec);
    return InternalError(destination_.string(), ": cannot move output into place: ", ec.message());
  }
  committed_ = true;
  if (!old.empty()) fs::remove_all(old, ec);
  return OkStatus();
}

}  // namespace reflcap
