// Fuzz target: calib/1 JSON (calib/calib_file: ParseCalibFile and the session checks the
// calibrate verbs run before opening any photo). On success every image names a known camera.
#include <cstddef>
#include <cstdint>
#include <string>

#include "calib/calib_file.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto file = reflcap::calib::ParseCalibFile(text, "fuzz/calib.json");
  if (!file.ok()) {
    reflcap::fuzz::Rejected(file.status());
    return 0;
  }
  for (const auto& camera : file->cameras) FUZZ_CHECK(camera.width > 0 && camera.height > 0);
  (void)reflcap::calib::CheckCuboidSession(*file);
  (void)reflcap::calib::CheckBoardSession(*file);
  return 0;
}
