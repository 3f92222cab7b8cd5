#pragma once
// PNG read/write (libpng, kept out of this header). Values are linear: 8-bit byte/255,
// 16-bit value/65535; no gamma curve is applied either way. Errors name the file.
#include <filesystem>

#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap {

// Grey images come back with 1 channel, grey+alpha with 2, RGB with 3, RGBA with 4; palette
// images are expanded to RGB(A), a tRNS chunk to an alpha channel, grey below 8 bits to 8 bits.
// A missing file is NotFound; corrupt or truncated files are DataLoss, never a crash.
StatusOr<Image> ReadPng(const std::filesystem::path& path);
// Header only: size and the channel count ReadPng would return (channel_names stays empty).
StatusOr<ImageInfo> ReadPngInfo(const std::filesystem::path& path);

// Writes 1..4 channels at 8 or 16 bits (else InvalidArgument), clamping to [0,1] (NaN written
// as 0, with a warning), atomically. Channels map to grey, grey+alpha, RGB, RGBA.
Status WritePng(const std::filesystem::path& path, const Image& image, int bit_depth = 8);

}  // namespace reflcap
