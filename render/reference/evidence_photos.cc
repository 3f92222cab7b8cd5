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

EvidencePhotographs::EvidencePhotographs(const Capture& capture, std::vector<size_t> indices)
    : capture_(capture), indices_(std::move(indices)), reads_(indices_.size()) {
  for (size_t k = 0; k < std::min(indices_.size(), kEvidenceReadAhead); ++k) Start(k);
}

EvidencePhotographs::~EvidencePhotographs() {
  for (auto& read : reads_) {
    if (read.valid()) read.wait();
  }
}

void EvidencePhotographs::Start(size_t k) {
  if (k >= indices_.size() || reads_[k].valid()) return;
  const std::filesystem::path path = capture_.Resolve(capture_.images[indices_[k]].file);
  reads_[k] = std::async(std::launch::async, [path] { return ReadImageRgb(path); });
}

StatusOr<Image> EvidencePhotographs::Take(size_t k, Status rendered, const char* what) {
  REFLCAP_CHECK(k < indices_.size()) << "EvidencePhotographs::Take(" << k << ") of "
                                     << indices_.size();
  Start(k);
  Start(k + kEvidenceReadAhead);  // the next read takes the place of this one
  StatusOr<Image> read = reads_[k].get();
  const size_t index = indices_[k];
  const CaptureImage& image = capture_.images[index];
  const Camera& camera = capture_.cameras[image.camera];
  if (!rendered.ok()) read = rendered;
  Status problem = read.status();
  if (problem.ok() && (read->width != camera.width || read->height != camera.height)) {
    problem = InvalidArgumentError(capture_.Resolve(image.file).string(), ": ", read->width, "x",
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
