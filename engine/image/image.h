#pragma once
// Image: the one float image type of reflcap. Interleaved channels, row-major, row 0 at the top
// (as in photographs and OpenCV). HDR photographs are 3-channel linear RGB; masks and single
// quantities are 1-channel; per-texel parameter maps may carry many named channels (see
// exr_io.h). Pixel (x, y) channel c lives at data[(y * width + x) * channels + c].
#include <cstddef>
#include <string>
#include <vector>

#include "engine/core/check.h"
#include "engine/core/large_buffer.h"

namespace reflcap {

// Images from this size on (a million-texel atlas's parameter maps: 46-100 MB) are mapped on
// huge pages. glibc maps every block above its largest mmap threshold (32 MiB on 64-bit) fresh,
// in 4 KiB pages, so above it huge pages cost nothing that malloc would save, and each one
// faults in 512 times fewer pages: filling the million fit's three maps took 0.52 of its 1.1 s
// of maps on 2 cores, most of it page faults. Smaller images (renders, photographs: up to 12 MB
// at 1024 px with aux channels) stay on the heap, which reuses their pages.
inline constexpr size_t kHugePageImageBytes = size_t{32} << 20;
using ImageStorage = std::vector<float, LargeBufferAllocator<float, kHugePageImageBytes>>;

struct Image {
  int width = 0;
  int height = 0;
  int channels = 0;
  // Grows without zeroing (Uninitialized below); every constructor that takes a size fills.
  // Storage of kHugePageImageBytes or more is mapped on huge pages (large_buffer.h).
  ImageStorage data;

  Image() = default;
  Image(int w, int h, int c, float fill = 0.0f)
      : width(w), height(h), channels(c), data(size_t(w) * size_t(h) * size_t(c), fill) {}
  // An image whose values are not set: the caller writes every one before reading any.
  static Image Uninitialized(int w, int h, int c) {
    Image image;
    image.width = w;
    image.height = h;
    image.channels = c;
    image.data.resize(size_t(w) * size_t(h) * size_t(c));
    return image;
  }

  bool empty() const { return data.empty(); }
  size_t PixelCount() const { return size_t(width) * size_t(height); }
  float& at(int x, int y, int c = 0) {
    REFLCAP_DCHECK(x >= 0 && x < width && y >= 0 && y < height && c >= 0 && c < channels);
    return data[(size_t(y) * width + x) * channels + c];
  }
  float at(int x, int y, int c = 0) const {
    REFLCAP_DCHECK(x >= 0 && x < width && y >= 0 && y < height && c >= 0 && c < channels);
    return data[(size_t(y) * width + x) * channels + c];
  }
  float* pixel(int x, int y) { return &data[(size_t(y) * width + x) * channels]; }
  const float* pixel(int x, int y) const { return &data[(size_t(y) * width + x) * channels]; }
};

// What a file's header says, read without decoding pixels (for `reflcap info`).
struct ImageInfo {
  int width = 0;
  int height = 0;
  int channels = 0;
  std::vector<std::string> channel_names;  // EXR channel names; empty for PNG
};

}  // namespace reflcap
