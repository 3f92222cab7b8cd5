#pragma once
// The train photographs that the render's automatic decisions read (pixel model, interreflection,
// stray light): which ones, how each is read, and which of its pixels count.
#include <cstddef>
#include <vector>

#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap::render {

// Up to `count` train photographs of `capture`, evenly spaced over the split (capture order).
std::vector<size_t> EvidenceImages(const Capture& capture, int count);

// Photograph `index` for an evidence, once its renders went well (`rendered`): an evidence is
// advice on photographs that are not rendered, so one that cannot be rendered or read, or whose
// size is not its camera's, is left out with a warning naming it (`what` names the evidence) —
// a selected photograph reports its own error.
StatusOr<Image> ReadEvidencePhotograph(const Capture& capture, size_t index, Status rendered,
                                       const char* what);

// An evidence reads a photograph pixel only when every channel is finite and below the image's
// saturation (a clipped value says nothing of the radiance).
bool UsablePixel(const float* p, const CaptureImage& image);

}  // namespace reflcap::render
