// Fuzz target: PNG headers and pixels (engine/image: ReadPngInfo, ReadPng). When both succeed
// they must agree on size and channels, and every value must be in [0, 1].
#include <cstddef>
#include <cstdint>

#include "engine/image/png_io.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const auto path = reflcap::fuzz::WriteScratch("image.png", data, size);
  auto info = reflcap::ReadPngInfo(path);
  auto image = reflcap::ReadPng(path);
  if (!image.ok()) {
    reflcap::fuzz::Rejected(image.status());
    return 0;
  }
  FUZZ_CHECK(info.ok());
  FUZZ_CHECK(info->width == image->width && info->height == image->height);
  FUZZ_CHECK(info->channels == image->channels);
  FUZZ_CHECK(image->data.size() == image->PixelCount() * size_t(image->channels));
  for (float v : image->data) FUZZ_CHECK(v >= 0.0f && v <= 1.0f);
  return 0;
}
