#pragma once
// OpenEXR read/write (OpenEXR 3, kept out of this header). Errors name the file.
#include <filesystem>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap {

enum class ExrPixelType { kHalf, kFloat };

// Reads an RGB image: channels R,G,B (any file order; missing G,B copy R; a lone Y channel is
// replicated). Half or float pixels; data window origin must be (0,0) relative to the display
// window. A missing file is NotFound; a corrupt or truncated one is DataLoss (never a crash).
StatusOr<Image> ReadExrRgb(const std::filesystem::path& path);

// Reads every channel, named, in the file's channel order (alphabetical, as OpenEXR stores them).
// channel_names receives the names; the returned image has one channel per name.
StatusOr<Image> ReadExrChannels(const std::filesystem::path& path,
                                std::vector<std::string>* channel_names);

// Header only: size and channel names.
StatusOr<ImageInfo> ReadExrInfo(const std::filesystem::path& path);

// Writes a 1-channel (Y), 3-channel (R,G,B) or 4-channel (R,G,B,A) image, ZIP compressed,
// atomically (temporary name, then rename).
Status WriteExr(const std::filesystem::path& path, const Image& image,
                ExrPixelType type = ExrPixelType::kFloat);

// Writes image.channels named channels (names.size() == image.channels), atomically.
Status WriteExrChannels(const std::filesystem::path& path, const Image& image,
                        const std::vector<std::string>& names,
                        ExrPixelType type = ExrPixelType::kFloat);

}  // namespace reflcap
