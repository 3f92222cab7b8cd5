#pragma once
// Dispatch on file extension: .exr -> OpenEXR, .png -> PNG.
#include <filesystem>

#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap {

// RGB float image from .exr or .png (grey PNGs are replicated to RGB, alpha dropped). The
// extension is matched case-insensitively; any other is InvalidArgument "unsupported image type".
StatusOr<Image> ReadImageRgb(const std::filesystem::path& path);
// Header only, as the file stores it (a grey PNG reports 1 channel).
StatusOr<ImageInfo> ReadImageInfo(const std::filesystem::path& path);

}  // namespace reflcap
