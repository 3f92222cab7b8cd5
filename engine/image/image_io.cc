// Format dispatch for callers that take "an image file": the lower-cased extension picks the
// reader (.exr -> exr_io, .png -> png_io); anything else is refused with InvalidArgument.
// ReadImageRgb normalises to 3 channels: grey (and grey+alpha) PNGs are replicated, alpha dropped.
#include "engine/image/image_io.h"

#include <algorithm>
#include <cctype>
#include <string>

#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"

namespace reflcap {
namespace fs = std::filesystem;

namespace {

enum class ImageFormat { kExr, kPng };

StatusOr<ImageFormat> FormatOf(const fs::path& path) {
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  if (extension == ".exr") return ImageFormat::kExr;
  if (extension == ".png") return ImageFormat::kPng;
  return InvalidArgumentError(path.string(), ": unsupported image type \"", extension,
                              "\" (expected .exr or .png)");
}

// 1 (grey), 2 (grey+alpha) or 4 (RGBA) channels -> RGB.
Image ToRgb(const Image& image) {
  Image rgb(image.width, image.height, 3);
  const bool grey = image.channels <= 2;
  for (size_t i = 0; i < image.PixelCount(); ++i) {
    const float* in = &image.data[i * size_t(image.channels)];
    for (int c = 0; c < 3; ++c) rgb.data[3 * i + size_t(c)] = grey ? in[0] : in[c];
  }
  return rgb;
}

}  // namespace

StatusOr<Image> ReadImageRgb(const fs::path& path) {
  REFLCAP_ASSIGN_OR_RETURN(ImageFormat format, FormatOf(path));
  if (format == ImageFormat::kExr) return ReadExrRgb(path);
  REFLCAP_ASSIGN_OR_RETURN(Image image, ReadPng(path));
  if (image.channels == 3) return image;
  return ToRgb(image);
}

StatusOr<ImageInfo> ReadImageInfo(const fs::path& path) {
  REFLCAP_ASSIGN_OR_RETURN(ImageFormat format, FormatOf(path));
  if (format == ImageFormat::kExr) return ReadExrInfo(path);
  return ReadPngInfo(path);
}

}  // namespace reflcap
