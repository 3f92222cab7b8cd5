// Tracing a FIT back to its capture, mesh and atlas (fit_source.h).
#include "render/export/fit_source.h"

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"

namespace reflcap::render {
namespace fs = std::filesystem;
namespace {

bool IsFile(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

// A string field of a JSON file, or "" when the file or field is absent or unreadable.
std::string JsonString(const fs::path& file, const char* field) {
  auto text = ReadTextFile(file);
  if (!text.ok()) return "";
  const nlohmann::json json = nlohmann::json::parse(*text, nullptr, /*allow_exceptions=*/false);
  if (!json.is_object() || !json.contains(field) || !json[field].is_string()) return "";
  return json[field].get<std::string>();
}

}  // namespace

StatusOr<fs::path> FindFitCapture(const fs::path& fit, const fs::path& capture_override) {
  if (!capture_override.empty()) {
    fs::path p = capture_override;
    std::error_code ec;
    if (fs::is_directory(p, ec)) p /= "capture.json";
    if (!IsFile(p)) return NotFoundError(p.string(), ": missing (--capture)");
    return p;
  }
  std::error_code ec;
  const fs::path dir = fs::is_directory(fit, ec) ? fit : fit.parent_path();
  const fs::path absolute = fs::absolute(dir, ec).lexically_normal();
  const fs::path parent = absolute.parent_path();
  std::string tried;
  // 1. The sample store the fit was made from.
  const fs::path report = dir / "fit_report.json";
  if (IsFile(report)) {
    fs::path samples = JsonString(report, "samples");
    if (samples.empty() || !IsFile(samples / "store.json")) samples = parent / "samples";
    if (IsFile(samples / "store.json")) {
      const fs::path capture = JsonString(samples / "store.json", "capture");
      if (!capture.empty() && IsFile(capture)) return capture;
      tried += (samples / "store.json").string() + " (capture: \"" + capture.string() + "\"), ";
    } else {
      tried += report.string() + " (samples), ";
    }
    const fs::path run_layout = parent.parent_path() / "capture" / "capture.json";
    if (IsFile(run_layout)) return run_layout;
    tried += run_layout.string() + ", ";
  }
  // 2. A capture's gt/ folder.
  if (IsFile(parent / "capture.json")) return parent / "capture.json";
  tried += (parent / "capture.json").string();
  return NotFoundError(dir.string(), ": cannot find the capture this fit belongs to (tried ",
                       tried, "); pass --capture CAPTURE");
}

StatusOr<LoadedFit> LoadFitWithMesh(const fs::path& fit, const fs::path& capture_override,
                                    const std::string& purpose) {
  LoadedFit out;
  out.params = fit;
  std::error_code ec;
  if (fs::is_directory(out.params, ec)) out.params /= "params.exr";
  if (!IsFile(out.params)) {
    return NotFoundError(out.params.string(), ": missing (FIT must hold params.exr)");
  }
  REFLCAP_ASSIGN_OR_RETURN(out.capture_json, FindFitCapture(fit, capture_override));
  REFLCAP_ASSIGN_OR_RETURN(Capture capture, ReadCapture(out.capture_json));
  if (capture.normal_map || capture.mesh.empty()) {
    return FailedPreconditionError(
        out.capture_json.string(), ": normal_map: this fit is of a normal-map capture, which has "
        "no mesh: ", purpose, " needs a mesh capture");
  }
  out.capture = std::make_unique<Capture>(std::move(capture));
  REFLCAP_ASSIGN_OR_RETURN(out.fitted, LoadFittedCapture(*out.capture, out.params,
                                                         /*height_field=*/false));
  return out;
}

}  // namespace reflcap::render
