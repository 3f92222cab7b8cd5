// Fuzz target: structured_light/1 JSON (acquire/scan: LoadScanSpec without opening the images).
// On success the angles are finite and each angle has its images.
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "acquire/scan/scan_spec.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const auto path = reflcap::fuzz::WriteScratch("scan.json", data, size);
  auto spec = reflcap::scan::LoadScanSpec(path, /*check_images=*/false);
  if (!spec.ok()) {
    reflcap::fuzz::Rejected(spec.status());
    return 0;
  }
  FUZZ_CHECK(!spec->angles.empty());
  FUZZ_CHECK(spec->camera.width > 0 && spec->camera.height > 0);
  return 0;
}
