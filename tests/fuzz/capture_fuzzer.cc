// Fuzz target: capture/1 JSON (engine/capture: ParseCapture, the whole field validation). On a
// successful parse every index must be in range, every number finite, and the document written
// back (CaptureToJson) must parse again.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include "engine/capture/capture.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto capture = reflcap::ParseCapture(text, "fuzz/capture.json");
  if (!capture.ok()) {
    reflcap::fuzz::Rejected(capture.status());
    return 0;
  }
  for (const auto& camera : capture->cameras) {
    FUZZ_CHECK(camera.width > 0 && camera.height > 0);
    FUZZ_CHECK(camera.K.allFinite());
  }
  for (const auto& image : capture->images) {
    FUZZ_CHECK(image.camera >= 0 && size_t(image.camera) < capture->cameras.size());
    FUZZ_CHECK(image.light >= 0 && size_t(image.light) < capture->lights.size());
    FUZZ_CHECK(std::isfinite(image.exposure_s) && image.exposure_s > 0);
    FUZZ_CHECK(std::isfinite(image.turntable_deg));
  }
  auto again = reflcap::ParseCapture(reflcap::CaptureToJson(*capture), "fuzz/capture.json");
  if (!again.ok()) {
    std::fprintf(stderr, "round trip failed: %s\n", again.status().ToString().c_str());
    std::abort();
  }
  FUZZ_CHECK(again->images.size() == capture->images.size());
  return 0;
}
