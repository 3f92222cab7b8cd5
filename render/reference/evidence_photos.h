#pragma once
// The train photographs that the render's automatic decisions read (pixel model, interreflection,
// stray light): which ones, how each is read, and which of its pixels count.
#include <cstddef>
#include <future>
#include <vector>

#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap::render {

// Up to `count` train photographs of `capture`, evenly spaced over the split (capture order).
std::vector<size_t> EvidenceImages(const Capture& capture, int count);

// The photographs an evidence reads (capture image indices), decoded ahead of their use: up to
// kEvidenceReadAhead at once, each on its own thread, while the caller renders. The renders of a
// GPU take a few milliseconds an image, and decoding each photograph only once its renders were
// done was a large part of the evidence's time (million preset, H200: 2.1 s for 12 photographs
// of interreflection evidence, 0.85 s for 8 of pixel-model evidence).
class EvidencePhotographs {
 public:
  // Photographs read at once at most: a few overlap the renders; more would hold more decoded
  // photographs (a 50-megapixel float photograph is 600 MB) without finishing sooner.
  static constexpr size_t kEvidenceReadAhead = 4;

  // Starts reading the first photographs of `indices` (in the order they will be taken).
  // `capture` must outlive the object.
  EvidencePhotographs(const Capture& capture, std::vector<size_t> indices);
  // Waits for the reads still running.
  ~EvidencePhotographs();
  EvidencePhotographs(const EvidencePhotographs&) = delete;
  EvidencePhotographs& operator=(const EvidencePhotographs&) = delete;

  size_t size() const { return indices_.size(); }
  size_t index(size_t k) const { return indices_[k]; }  // the k-th photograph's capture index

  // The k-th photograph (k = 0, 1, ... in order), once its renders went well (`rendered`): an
  // evidence is advice on photographs that are not rendered, so one that cannot be rendered or
  // read, or whose size is not its camera's, is left out with a warning naming it (`what` names
  // the evidence) — a selected photograph reports its own error.
  StatusOr<Image> Take(size_t k, Status rendered, const char* what);

 private:
  void Start(size_t k);
  const Capture& capture_;
  std::vector<size_t> indices_;
  std::vector<std::future<StatusOr<Image>>> reads_;
};

// An evidence reads a photograph pixel only when every channel is finite and below the image's
// saturation (a clipped value says nothing of the radiance).
bool UsablePixel(const float* p, const CaptureImage& image);

}  // namespace reflcap::render
