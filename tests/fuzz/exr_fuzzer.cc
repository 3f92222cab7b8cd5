// Fuzz target: OpenEXR headers and pixels (engine/image: ReadExrInfo, ReadExrChannels,
// ReadExrRgb). A successful read must hold exactly width x height x channels values and name
// each channel; the header must agree with it.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/image/exr_io.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const auto path = reflcap::fuzz::WriteScratch("image.exr", data, size);
  auto info = reflcap::ReadExrInfo(path);
  std::vector<std::string> names;
  auto image = reflcap::ReadExrChannels(path, &names);
  if (image.ok()) {
    FUZZ_CHECK(info.ok());
    FUZZ_CHECK(info->width == image->width && info->height == image->height);
    FUZZ_CHECK(names.size() == size_t(image->channels));
    FUZZ_CHECK(image->data.size() == image->PixelCount() * size_t(image->channels));
  } else {
    reflcap::fuzz::Rejected(image.status());
  }
  auto rgb = reflcap::ReadExrRgb(path);
  if (rgb.ok()) {
    FUZZ_CHECK(rgb->channels == 3);
    FUZZ_CHECK(rgb->data.size() == rgb->PixelCount() * 3);
  }
  return 0;
}
