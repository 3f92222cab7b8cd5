// Reading the train photographs for the render's automatic decisions (see evidence_photos.h).
#include "render/reference/evidence_photos.h"

#include <algorithm>
#include <cmath>

#include "engine/core/log.h"
#include "engine/image/image_io.h"

namespace reflcap::render {

std::vector<size_t> EvidenceImages(const Capture& capture, int count) {
  std::vector<size_t> pool;
  for (size_t i = 0; i < capture.images.size(); ++i) {
    if (capture.images[i].split == Split::kTrain) pool.push_back(i);
  }
  const size_t take = std::min(pool.size(), size_t(count));
  std::vector<size_t> out;
  for (size_t j = 0; j < take; ++j) out.push_back(pool[j * pool.size() / take]);
  return out;
}

StatusOr<Image> ReadEvidencePhotograph(const Capture& capture, size_t index, Status rendered,
                                       const char* what) {
  const CaptureImage& image = capture.images[index];
  const Camera& camera = capture.cameras[image.camera];
  StatusOr<Image> read =
      rendered.ok() ? ReadImageRgb(capture.Resolve(image.file)) : StatusOr<Image>(rendered);
  Status problem = read.status();
  if (problem.ok() && (read->width != camera.width || read->height != camera.height)) {
    problem = InvalidArgumentError(capture.Resolve(image.file).string(), ": ", read->width, "x",
                                   read->height, " pixels, but camera \"", camera.id, "\" is ",
                                   camera.width, "x", camera.height);
  }
  if (!problem.ok()) {
    REFLCAP_LOG(kWarning) << "render: " << what << " leaves out images[" << index
                          << "]: " << problem.message();
    return problem;
  }
  return read;
}

bool UsablePixel(const float* p, const CaptureImage& image) {
  for (int c = 0; c < 3; ++c) {
    if (!std::isfinite(p[c]) || (image.saturation > 0 && double(p[c]) >= image.saturation)) {
      return false;
    }
  }
  return true;
}

}  // namespace reflcap::render
