// Fuzz target: brackets/1 JSON (acquire/radiometry: ParseBrackets, rig included). On success
// every photo names a known camera and light and has >= 2 strictly increasing exposures.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include "acquire/radiometry/brackets.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto set = reflcap::radiometry::ParseBrackets(text, "fuzz/brackets.json");
  if (!set.ok()) {
    reflcap::fuzz::Rejected(set.status());
    return 0;
  }
  for (const auto& photo : set->photos) {
    FUZZ_CHECK(photo.camera >= 0 && size_t(photo.camera) < set->rig.cameras.size());
    FUZZ_CHECK(photo.exposures.size() >= 2);
    for (size_t e = 0; e < photo.exposures.size(); ++e) {
      FUZZ_CHECK(std::isfinite(photo.exposures[e].exposure_s) && photo.exposures[e].exposure_s > 0);
      if (e > 0) FUZZ_CHECK(photo.exposures[e].exposure_s > photo.exposures[e - 1].exposure_s);
    }
  }
  return 0;
}
