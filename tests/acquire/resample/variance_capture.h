#pragma once
// AddVarianceImages: gives an existing capture per-pixel variance images (images[].variance), as
// `reflcap hdr` writes them, for the tests of the resampler's variance path. The photographs stay
// where they are; the variance images go to `dir`/<folder>/<index>.exr (float RGB) and the
// capture is written again under a new name beside the original, so a test holds the same capture
// with and without variance (relative paths only: nothing is written outside `dir`).
#include <filesystem>
#include <functional>
#include <string>

#include "engine/capture/capture.h"
#include "engine/core/check.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"

namespace reflcap::testing {

// var(pixels, x, y, c): the variance of channel c of pixel (x, y) of `pixels`, the photograph.
using VarianceOf = std::function<float(const Image& pixels, int x, int y, int c)>;

// Reads `dir`/capture.json, writes a variance image for every image i with with(i) true (all when
// `with` is empty) and writes the capture with images[].variance set as `dir`/`json_name`.
// Returns that path. Aborts (REFLCAP_CHECK) on any I/O failure: test setup.
inline std::filesystem::path AddVarianceImages(const std::filesystem::path& dir,
                                               const std::string& json_name,
                                               const std::string& folder, const VarianceOf& var,
                                               const std::function<bool(size_t)>& with = {}) {
  Capture capture = ReadCapture(dir / "capture.json").value();
  std::filesystem::create_directories(dir / folder);
  for (size_t i = 0; i < capture.images.size(); ++i) {
    if (with && !with(i)) continue;
    const Image pixels = ReadImageRgb(capture.Resolve(capture.images[i].file)).value();
    Image variance(pixels.width, pixels.height, 3);
    for (int y = 0; y < pixels.height; ++y) {
      for (int x = 0; x < pixels.width; ++x) {
        for (int c = 0; c < 3; ++c) variance.at(x, y, c) = var(pixels, x, y, c);
      }
    }
    const std::string name = folder + "/" + std::to_string(i) + ".exr";
    const Status s = WriteExr(dir / name, variance, ExrPixelType::kFloat);
    REFLCAP_CHECK(s.ok()) << s.ToString();
    capture.images[i].variance = name;
  }
  const std::filesystem::path json = dir / json_name;
  capture.json_path = json;
  const Status s = WriteCapture(capture, json);
  REFLCAP_CHECK(s.ok()) << s.ToString();
  return json;
}

}  // namespace reflcap::testing
