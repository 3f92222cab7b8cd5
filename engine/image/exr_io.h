#pragma once
// OpenEXR read/write (OpenEXR 3, kept out of this header). Errors name the file.
#include <filesystem>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap {

enum class ExrPixelType { kHalf, kFloat };

// Reads an RGB image: channels R,G,B (any file order; missing G,B copy R; a file without R but
// with Y has Y replicated; other channels are ignored). Half, float or uint pixels, returned as
// float. The data window must equal the display window and every channel must be full
// resolution, else InvalidArgument; no R and no Y is InvalidArgument too. A missing file is
// NotFound; a corrupt or truncated one is DataLoss (never a crash or a partial image).
// Non-finite values (NaN, Inf) are returned as stored: callers that cannot use them must check.
// Decoding runs in the calling thread (no OpenEXR thread pool); read files in parallel instead.
StatusOr<Image> ReadExrRgb(const std::filesystem::path& path);

// Reads every channel, named, in the file's channel order (alphabetical, as OpenEXR stores them).
// channel_names receives the names (only on success); the returned image has one channel per
// name. Same window rules, errors and non-finite handling as ReadExrRgb. `threads` > 1 decodes on
// that many threads of OpenEXR's global pool (as WriteExrChannels): for one large file read while
// nothing else runs (a fit's maps); the pixels are the same.
StatusOr<Image> ReadExrChannels(const std::filesystem::path& path,
                                std::vector<std::string>* channel_names, int threads = 0);

// Header only: data window size and channel names (pixels are not decoded, windows not checked).
StatusOr<ImageInfo> ReadExrInfo(const std::filesystem::path& path);

// Writes a 1-channel (Y), 3-channel (R,G,B) or 4-channel (R,G,B,A) image, ZIP compressed,
// atomically (temporary name, then rename); other channel counts are InvalidArgument.
// No NaN or Inf reaches the file: NaN is written as 0, and values beyond the pixel type's finite
// range (±65504 for half, ±FLT_MAX for float) are clamped to it, with one warning per file giving
// the counts. I/O failures are Internal.
Status WriteExr(const std::filesystem::path& path, const Image& image,
                ExrPixelType type = ExrPixelType::kFloat);

// Writes image.channels named channels (names.size() == image.channels, names non-empty and
// unique, else InvalidArgument), atomically, sanitised as WriteExr. OpenEXR stores the channels
// sorted by name, which is the order ReadExrChannels returns them in. `threads` > 1 compresses
// on that many threads of OpenEXR's global pool (grown to it, never shrunk): for a large file
// written while nothing else runs (the fit's maps); the file is the same byte for byte.
Status WriteExrChannels(const std::filesystem::path& path, const Image& image,
                        const std::vector<std::string>& names,
                        ExrPixelType type = ExrPixelType::kFloat, int threads = 0);

}  // namespace reflcap
