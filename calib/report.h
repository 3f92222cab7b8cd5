#pragma once
// The calibration reports: a folder with report.json (every number), index.html (self-contained:
// tables and inline SVG plots, open it in any browser) and PNG photos with the reprojection
// residuals drawn as vectors, magnified.
//   turntable: reprojection RMS/max per camera, angle and face, adjusted beside the seed's
//     averaged-poses baseline; residual histogram and scatter; sigmas; the comparison with ground
//     truth; what was refused or rejected and why; one photo per camera with its residuals.
//   intrinsics: per camera K, distortion and their sigmas; per-view reprojection; frame coverage
//     (the corners over the frame); one photo per camera with its residuals.
#include <filesystem>
#include <string>

#include "calib/calib_file.h"
#include "calib/intrinsics.h"
#include "calib/turntable.h"
#include "engine/core/status.h"

namespace reflcap::calib {

// Writes into `dir`, an existing folder (the caller's staging folder).
Status WriteTurntableReport(const CalibFile& file, const TurntableResult& result, const TurntableOptions& options,
                            const std::string& intrinsics_note, const std::filesystem::path& dir);
Status WriteIntrinsicsReport(const CalibFile& file, const IntrinsicsResult& result,
                             const IntrinsicsOptions& options, const std::filesystem::path& dir);

}  // namespace reflcap::calib
