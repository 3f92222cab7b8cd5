// Fuzz target: an INTRINSICS.json as `reflcap calibrate turntable --intrinsics` reads it
// (calib/intrinsics: ReadIntrinsicsFile). On success every camera has a positive size and finite
// parameters.
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "calib/intrinsics.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const auto path = reflcap::fuzz::WriteScratch("intrinsics.json", data, size);
  auto cameras = reflcap::calib::ReadIntrinsicsFile(path);
  if (!cameras.ok()) {
    reflcap::fuzz::Rejected(cameras.status());
    return 0;
  }
  for (const auto& camera : *cameras) {
    FUZZ_CHECK(camera.width > 0 && camera.height > 0);
    for (double p : camera.params) FUZZ_CHECK(std::isfinite(p));
  }
  return 0;
}
