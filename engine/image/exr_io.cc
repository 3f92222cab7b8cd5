// OpenEXR reading and writing behind reflcap's Image and Status types. OpenEXR reports every
// failure by throwing (Iex::BaseExc and std::exception); each public function here catches
// everything at its boundary and returns a Status whose message starts with the file path. Files
// are read through Imf::InputFile into float slices (OpenEXR converts half and uint to float), and
// written scanline by scanline, ZIP compressed, to a temporary name that WriteFileAtomic renames
// into place. Writing never lets NaN or Inf into a file: NaN becomes 0 and out-of-range values are
// clamped to the largest finite value of the pixel type, with one warning per file.
#include "engine/image/exr_io.h"

#include <Imath/ImathBox.h>
#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfCompression.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfPixelType.h>

#include <cmath>
#include <cstdint>
#include <exception>
#include <fstream>
#include <limits>
#include <set>
#include <system_error>
#include <utility>

#include "engine/core/atomic_file.h"
#include "engine/core/log.h"

namespace reflcap {
namespace fs = std::filesystem;

namespace {

// OpenEXR decodes and encodes in the calling thread: reflcap parallelises over files and texels
// (ParallelFor), so a per-file thread pool would only oversubscribe the cores.
constexpr int kExrThreads = 0;

// Largest finite half (0x7bff). half(x) rounds |x| >= 65520 to Inf, so values beyond this are
// clamped before conversion.
constexpr float kHalfMax = 65504.0f;

// A header claiming more samples (pixels x channels) than this is treated as corrupt: 2^32 floats
// are 16 GiB, beyond any image reflcap handles, and allocating for a damaged header would exhaust
// memory before OpenEXR noticed the damage.
constexpr uint64_t kMaxSamples = uint64_t(1) << 32;

Status CheckReadable(const fs::path& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    return InvalidArgumentError(path.string(), ": is a folder, not an OpenEXR file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return NotFoundError(path.string(), ": cannot open");
  return OkStatus();
}

std::string BoxToString(const Imath::Box2i& box) {
  return StrCat("(", box.min.x, ",", box.min.y, ")-(", box.max.x, ",", box.max.y, ")");
}

// Runs `body`, which may throw anything OpenEXR throws, and turns exceptions into DataLoss.
template <typename T, typename Body>
StatusOr<T> GuardRead(const fs::path& path, Body&& body) {
  REFLCAP_RETURN_IF_ERROR(CheckReadable(path));
  try {
    return body();
  } catch (const std::exception& e) {
    return DataLossError(path.string(), ": ", e.what());
  } catch (...) {
    return DataLossError(path.string(), ": unknown error while reading the OpenEXR file");
  }
}

// The file's size in pixels, checked to be one full frame of a sane size, every channel at full
// resolution.
StatusOr<Imath::Box2i> FullFrameWindow(const fs::path& path, const Imf::Header& header) {
  const Imath::Box2i& data_window = header.dataWindow();
  if (data_window != header.displayWindow()) {
    return InvalidArgumentError(
        path.string(), ": data window ", BoxToString(data_window), " differs from display window ",
        BoxToString(header.displayWindow()), "; only full-frame images are supported");
  }
  const int64_t width = int64_t(data_window.max.x) - data_window.min.x + 1;
  const int64_t height = int64_t(data_window.max.y) - data_window.min.y + 1;
  int64_t channels = 0;
  for (auto it = header.channels().begin(); it != header.channels().end(); ++it) {
    if (it.channel().xSampling != 1 || it.channel().ySampling != 1) {
      return InvalidArgumentError(path.string(), ": channel ", it.name(),
                                  " is subsampled; only full-resolution channels are supported");
    }
    ++channels;
  }
  constexpr int64_t kMaxSide = std::numeric_limits<int>::max();  // Image stores sizes as int
  if (width <= 0 || height <= 0 || width > kMaxSide || height > kMaxSide ||
      uint64_t(width) * uint64_t(height) > kMaxSamples ||
      uint64_t(width) * uint64_t(height) * uint64_t(channels) > kMaxSamples) {
    return DataLossError(path.string(), ": implausible image size ", width, "x", height, "x",
                         channels);
  }
  return data_window;
}

// Reads channels `names[i]` (all present in the file) into channel i of a new interleaved image
// with names.size() channels.
StatusOr<Image> ReadSlices(const fs::path& path, Imf::InputFile& file, const Imath::Box2i& window,
                           const std::vector<std::string>& names) {
  if (!file.isComplete()) {
    return DataLossError(path.string(), ": file is incomplete (truncated?)");
  }
  const int width = window.max.x - window.min.x + 1;
  const int height = window.max.y - window.min.y + 1;
  const int channels = int(names.size());
  Image image(width, height, channels);
  const size_t x_stride = sizeof(float) * size_t(channels);
  const size_t y_stride = x_stride * size_t(width);
  Imf::FrameBuffer frame_buffer;
  for (int c = 0; c < channels; ++c) {
    frame_buffer.insert(
        names[c], Imf::Slice::Make(Imf::FLOAT, image.data.data() + c, window, x_stride, y_stride));
  }
  file.setFrameBuffer(frame_buffer);
  file.readPixels(window.min.y, window.max.y);
  return image;
}

std::vector<std::string> ChannelNames(const Imf::Header& header) {
  std::vector<std::string> names;
  for (auto it = header.channels().begin(); it != header.channels().end(); ++it) {
    names.emplace_back(it.name());
  }
  return names;
}

std::string JoinNames(const std::vector<std::string>& names) {
  std::string joined;
  for (const std::string& name : names) joined += (joined.empty() ? "" : ",") + name;
  return joined;
}

// Makes a value safe for a file of the given pixel type: NaN -> 0 and |x| beyond the type's
// largest finite value (Inf included) -> that value, counting both.
struct Sanitizer {
  float max_finite;
  int64_t nan_count = 0;
  int64_t clamp_count = 0;

  float operator()(float x) {
    if (std::isnan(x)) {
      ++nan_count;
      return 0.0f;
    }
    if (x > max_finite) {
      ++clamp_count;
      return max_finite;
    }
    if (x < -max_finite) {
      ++clamp_count;
      return -max_finite;
    }
    return x;
  }
};

Status WriteExrImpl(const fs::path& path, const Image& image, const std::vector<std::string>& names,
                    ExrPixelType type) {
  if (image.width <= 0 || image.height <= 0 || image.channels <= 0) {
    return InvalidArgumentError(path.string(), ": cannot write an empty image (", image.width, "x",
                                image.height, "x", image.channels, ")");
  }
  if (image.data.size() != image.PixelCount() * size_t(image.channels)) {
    return InvalidArgumentError(path.string(), ": image data holds ", image.data.size(),
                                " values, expected ", image.width, "x", image.height, "x",
                                image.channels);
  }
  if (names.size() != size_t(image.channels)) {
    return InvalidArgumentError(path.string(), ": ", names.size(), " channel names for ",
                                image.channels, " channels");
  }
  std::set<std::string> unique_names;
  for (const std::string& name : names) {
    if (name.empty()) return InvalidArgumentError(path.string(), ": empty channel name");
    if (!unique_names.insert(name).second) {
      return InvalidArgumentError(path.string(), ": duplicate channel name ", name);
    }
  }

  const bool half = type == ExrPixelType::kHalf;
  Sanitizer sanitize{half ? kHalfMax : std::numeric_limits<float>::max()};
  std::vector<Imath::half> half_data;
  std::vector<float> float_data;
  if (half) {
    half_data.resize(image.data.size());
    for (size_t i = 0; i < image.data.size(); ++i) half_data[i] = sanitize(image.data[i]);
  } else {
    // Float output copies only when some value needs sanitising: a full-atlas map is written
    // straight from the caller's image, so writing it does not double its memory.
    bool clean = true;
    for (size_t i = 0; i < image.data.size() && clean; ++i) {
      const float x = image.data[i];
      clean = !std::isnan(x) && x <= sanitize.max_finite && x >= -sanitize.max_finite;
    }
    if (!clean) {
      float_data.resize(image.data.size());
      for (size_t i = 0; i < image.data.size(); ++i) float_data[i] = sanitize(image.data[i]);
    }
  }
  if (sanitize.nan_count > 0 || sanitize.clamp_count > 0) {
    std::string message = path.string() + ":";
    if (sanitize.nan_count > 0) {
      message += StrCat(" wrote ", sanitize.nan_count, " NaN values as 0");
      if (sanitize.clamp_count > 0) message += ";";
    }
    if (sanitize.clamp_count > 0) {
      message += StrCat(" clamped ", sanitize.clamp_count, " values beyond the ",
                        half ? "half" : "float", " range to +/-", sanitize.max_finite);
    }
    REFLCAP_LOG(kWarning) << message;
  }

  const Imf::PixelType pixel_type = half ? Imf::HALF : Imf::FLOAT;
  const size_t value_size = half ? sizeof(Imath::half) : sizeof(float);
  // OpenEXR's Slice takes a char* for reading and writing alike; the output file only reads it.
  char* base = half ? reinterpret_cast<char*>(half_data.data())
               : float_data.empty()
                   ? reinterpret_cast<char*>(const_cast<float*>(image.data.data()))
                   : reinterpret_cast<char*>(float_data.data());
  const size_t x_stride = value_size * size_t(image.channels);
  const size_t y_stride = x_stride * size_t(image.width);

  return WriteFileAtomic(path, [&](const fs::path& tmp_path) -> Status {
    try {
      Imf::Header header(image.width, image.height);
      header.compression() = Imf::ZIP_COMPRESSION;
      Imf::FrameBuffer frame_buffer;
      for (int c = 0; c < image.channels; ++c) {
        header.channels().insert(names[c], Imf::Channel(pixel_type));
        frame_buffer.insert(names[c],
                            Imf::Slice(pixel_type, base + value_size * c, x_stride, y_stride));
      }
      // The file is closed (line offset table written) when `file` leaves this scope, before
      // WriteFileAtomic renames it.
      Imf::OutputFile file(tmp_path.c_str(), header, kExrThreads);
      file.setFrameBuffer(frame_buffer);
      file.writePixels(image.height);
    } catch (const std::exception& e) {
      return InternalError(path.string(), ": cannot write OpenEXR file: ", e.what());
    } catch (...) {
      return InternalError(path.string(), ": cannot write OpenEXR file: unknown error");
    }
    return OkStatus();
  });
}

}  // namespace

StatusOr<Image> ReadExrRgb(const fs::path& path) {
  return GuardRead<Image>(path, [&]() -> StatusOr<Image> {
    Imf::InputFile file(path.c_str(), kExrThreads);
    REFLCAP_ASSIGN_OR_RETURN(Imath::Box2i window, FullFrameWindow(path, file.header()));
    const Imf::ChannelList& channels = file.header().channels();
    const bool has_r = channels.findChannel("R") != nullptr;
    const bool has_g = channels.findChannel("G") != nullptr;
    const bool has_b = channels.findChannel("B") != nullptr;
    if (!has_r && channels.findChannel("Y") == nullptr) {
      return InvalidArgumentError(path.string(), ": no R or Y channel (channels: ",
                                  JoinNames(ChannelNames(file.header())), ")");
    }
    if (!has_r) {
      // Luminance only: read Y into channel 0, then replicate it.
      REFLCAP_ASSIGN_OR_RETURN(Image grey, ReadSlices(path, file, window, {"Y"}));
      Image rgb(grey.width, grey.height, 3);
      for (size_t i = 0; i < grey.PixelCount(); ++i) {
        rgb.data[3 * i] = rgb.data[3 * i + 1] = rgb.data[3 * i + 2] = grey.data[i];
      }
      return rgb;
    }
    // Read the channels present; an absent G or B copies R.
    std::vector<std::string> present = {"R"};
    if (has_g) present.push_back("G");
    if (has_b) present.push_back("B");
    REFLCAP_ASSIGN_OR_RETURN(Image read, ReadSlices(path, file, window, present));
    if (present.size() == 3) return read;
    Image rgb(read.width, read.height, 3);
    for (size_t i = 0; i < read.PixelCount(); ++i) {
      const float* in = &read.data[i * present.size()];
      const float r = in[0];
      size_t next = 1;
      rgb.data[3 * i] = r;
      rgb.data[3 * i + 1] = has_g ? in[next++] : r;
      rgb.data[3 * i + 2] = has_b ? in[next++] : r;
    }
    return rgb;
  });
}

StatusOr<Image> ReadExrChannels(const fs::path& path, std::vector<std::string>* channel_names) {
  REFLCAP_CHECK(channel_names != nullptr);
  std::vector<std::string> names;
  StatusOr<Image> image = GuardRead<Image>(path, [&]() -> StatusOr<Image> {
    Imf::InputFile file(path.c_str(), kExrThreads);
    REFLCAP_ASSIGN_OR_RETURN(Imath::Box2i window, FullFrameWindow(path, file.header()));
    names = ChannelNames(file.header());
    if (names.empty()) return DataLossError(path.string(), ": file has no channels");
    return ReadSlices(path, file, window, names);
  });
  if (image.ok()) *channel_names = std::move(names);
  return image;
}

StatusOr<ImageInfo> ReadExrInfo(const fs::path& path) {
  return GuardRead<ImageInfo>(path, [&]() -> StatusOr<ImageInfo> {
    Imf::InputFile file(path.c_str(), kExrThreads);
    const Imath::Box2i& window = file.header().dataWindow();
    ImageInfo info;
    info.width = window.max.x - window.min.x + 1;
    info.height = window.max.y - window.min.y + 1;
    info.channel_names = ChannelNames(file.header());
    info.channels = int(info.channel_names.size());
    return info;
  });
}

Status WriteExr(const fs::path& path, const Image& image, ExrPixelType type) {
  switch (image.channels) {
    case 1:
      return WriteExrImpl(path, image, {"Y"}, type);
    case 3:
      return WriteExrImpl(path, image, {"R", "G", "B"}, type);
    case 4:
      return WriteExrImpl(path, image, {"R", "G", "B", "A"}, type);
    default:
      return InvalidArgumentError(path.string(), ": WriteExr takes 1, 3 or 4 channels, not ",
                                  image.channels, "; use WriteExrChannels to name them");
  }
}

Status WriteExrChannels(const fs::path& path, const Image& image,
                        const std::vector<std::string>& names, ExrPixelType type) {
  return WriteExrImpl(path, image, names, type);
}

}  // namespace reflcap
