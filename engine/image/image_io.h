#pragma once
// Dispatch on file extension: .exr -> OpenEXR, .png -> PNG.
#include <filesystem>

#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap {

// RGB float image from .exr or .png (grey PNGs are replicated to RGB, alpha dropped).
StatusOr<Image> ReadImageRgb(const std::filesystem::path& path);
// Header only.
StatusOr<ImageInfo> ReadImageInfo(const std::filesystem::path& path);

}  // namespace reflcap
