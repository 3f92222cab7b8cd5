#pragma once
// JSON blocks of the calibration outputs, shared by RIG.json (the "calibration" summary) and the
// report's report.json (everything: every face view, photo and board photo). Internal to calib/.
#include <string>

#include "calib/calib_file.h"
#include "engine/capture/json_fields.h"
#include "calib/turntable.h"

namespace reflcap::calib::internal {

using jsonio::Json;
using jsonio::MatrixJson;
using jsonio::VectorJson;

// The summary: source, gauge, intrinsics provenance, reprojection, sigmas, cuboid pose, angle
// offsets, the baseline and the comparison with ground truth (when the file has it).
Json CalibrationJson(const CalibFile& file, const TurntableResult& result, const TurntableOptions& options,
                     const std::string& intrinsics_note, const std::string& report_path);

// The full report: the summary plus per camera / angle / face statistics, every face view, every
// photo (with the grids refused and why) and every board photo.
Json TurntableReportJson(const CalibFile& file, const TurntableResult& result, const TurntableOptions& options,
                         const std::string& intrinsics_note);

Json TruthJson(const TruthComparison& c, const CalibFile& file);

}  // namespace reflcap::calib::internal
