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
#include <OpenEXR/ImfThreading.h>
#include <OpenEXR/openexr.h>

#include <cmath>
#include <cstdint>
#include <exception>
#include <fstream>
#include <limits>
#include <map>
#include <mutex>
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

// zlib level of ZIP-compressed files: 1, not OpenEXR's default 4. Measured on the million preset's
// outputs (one thread, OpenEXR 3.1): a 1024^2 RGB re-render writes in 0.046 s instead of 0.065 and
// reads in 0.043 instead of 0.061, its 5-channel aux buffers 0.094 / 0.077 instead of 0.128 /
// 0.105, a 1290^2 params.exr 0.68 / 0.44 instead of 0.88 / 0.50, for files 3-6 % larger. reflcap
// writes its renders, aux buffers and maps once and reads them back at once (validate, render):
// the time counts, the few percent of disk do not. Any reader decodes either level.
constexpr int kExrZipLevel = 1;

// Grows OpenEXR's global thread pool to `threads` (never shrinks it), for a caller that reads or
// writes one large file while nothing else runs.
void GrowGlobalPool(int threads) {
  static std::mutex pool_mutex;  // the pool is global: grown by one caller at a time
  const std::lock_guard<std::mutex> lock(pool_mutex);
  if (Imf::globalThreadCount() < threads) Imf::setGlobalThreadCount(threads);
}

// Largest finite half (0x7bff). half(x) rounds |x| >= 65520 to Inf, so values beyond this are
// clamped before conversion.
constexpr float kHalfMax = 65504.0f;

// A header claiming more samples (pixels x channels) than this is treated as corrupt: 2^32 floats
// are 16 GiB, beyond any image reflcap handles, and allocating for a damaged header would exhaust
// memory before OpenEXR noticed the damage.
constexpr uint64_t kMaxSamples = uint64_t(1) << 32;

// OpenEXR's magic number and the version-field flag of multi-part files.
constexpr int32_t kExrMagic = 20000630;
constexpr int32_t kExrMultiPartFlag = 0x1000;
// Attribute and type names are at most 255 bytes (31 without the long-names flag).
constexpr size_t kExrMaxNameBytes = 256;

// Bytes Imf 3.1 reads for the value of each fixed-size attribute type, whatever the declared
// size says (Imf::TypedAttribute<T>::readValueFrom).
int FixedAttributeBytes(const std::string& type) {
  static const std::map<std::string, int> kBytes = {
      {"box2i", 16}, {"box2f", 16}, {"chromaticities", 32}, {"compression", 1}, {"envmap", 1},
      {"lineOrder", 1}, {"deepImageState", 1}, {"double", 8}, {"float", 4}, {"int", 4},
      {"keycode", 28}, {"m33f", 36}, {"m33d", 72}, {"m44f", 64}, {"m44d", 128}, {"rational", 8},
      {"tiledesc", 9}, {"timecode", 8}, {"v2i", 8}, {"v2f", 8}, {"v2d", 16}, {"v3i", 12},
      {"v3f", 12}, {"v3d", 24}};
  auto it = kBytes.find(type);
  return it == kBytes.end() ? -1 : it->second;
}

// Checks of the header before Imf::InputFile sees the file, all for inputs found by
// tests/fuzz/exr_fuzzer. OpenEXR 3.1 (Imf and OpenEXRCore alike) allocates what a header declares
// before reading it — an attribute's size, a string's length, a preview's pixels — so a 184-byte
// file declaring a 1.6 GB attribute made it allocate 1.6 GB. And Imf reads fixed-size types and
// channel lists without regard to the declared size, so on a damaged header it parses on where
// the file holds other bytes, and finds such declarations there.
//  1. CheckAttributeSizes walks the attributes (name, type, int32 size, value) of every part as
//     Imf reads them, and refuses a declared size that runs past the end of the file or differs
//     from what Imf will read (fixed-size types, chlist, preview, stringvector);
//  2. CheckHeaderWithCore then parses the header with OpenEXRCore, and CheckPixelBytes bounds
//     the pixels it declares by the file's size.
// Anything else malformed (bad magic, overlong names, a cut) is left for OpenEXR to report.
Status CheckAttributeSizes(const fs::path& path, uint64_t file_size) {
  std::ifstream in(path, std::ios::binary);
  int32_t magic = 0, version = 0;
  if (!in.read(reinterpret_cast<char*>(&magic), 4) || magic != kExrMagic ||
      !in.read(reinterpret_cast<char*>(&version), 4)) {
    return OkStatus();
  }
  auto read_name = [&in](std::string* name) {
    name->clear();
    for (char c; in.get(c);) {
      if (c == '\0') return true;
      if (name->size() >= kExrMaxNameBytes) return false;
      *name += c;
    }
    return false;
  };
  auto read_i32 = [&in](int32_t* v) { return bool(in.read(reinterpret_cast<char*>(v), 4)); };
  const bool multi_part = (version & kExrMultiPartFlag) != 0;
  std::set<std::string> names_in_part;
  std::string name, type;
  while (read_name(&name)) {
    if (name.empty()) {  // end of a part's header; a multi-part file ends with an empty header
      if (!multi_part || names_in_part.empty()) return OkStatus();
      names_in_part.clear();
      continue;
    }
    // Imf keeps the last of repeated attributes and OpenEXRCore the first, so the two would
    // disagree on, say, the data window CheckPixelBytes bounds (a fuzzer input repeated it).
    if (!names_in_part.insert(name).second) {
      return DataLossError(path.string(), ": header attribute \"", name, "\" appears twice");
    }
    int32_t size = 0;
    if (!read_name(&type) || !read_i32(&size)) return OkStatus();
    const uint64_t at = uint64_t(in.tellg());
    auto refuse = [&](const std::string& what) {
      return DataLossError(path.string(), ": header attribute \"", name, "\" (", type, ") declares ",
                           size, " bytes, ", what);
    };
    if (size < 0 || at > file_size || uint64_t(size) > file_size - at) {
      return refuse(StrCat("past the end of the ", file_size, "-byte file"));
    }
    const int fixed = FixedAttributeBytes(type);
    if (fixed >= 0 && size != fixed) return refuse(StrCat("but a ", type, " has ", fixed));
    if (type == "chlist") {  // entries of name, 16 bytes, up to an empty name
      std::string channel;
      int64_t consumed = 0;
      while (read_name(&channel) && !channel.empty()) {
        consumed += int64_t(channel.size()) + 1 + 16;
        if (consumed >= size) break;
        in.seekg(16, std::ios::cur);
      }
      if (!in || !channel.empty() || consumed + 1 != size) {
        return refuse("unlike the channel list it holds");
      }
    } else if (type == "preview") {  // width, height, then 4 bytes per pixel
      int32_t width = 0, height = 0;
      if (!read_i32(&width) || !read_i32(&height) || width < 0 || height < 0 ||
          8 + 4 * uint64_t(width) * uint64_t(height) != uint64_t(size)) {
        return refuse("unlike the preview image it holds");
      }
      in.seekg(size - 8, std::ios::cur);
    } else if (type == "stringvector") {  // (int32 length, bytes) until the size is used up
      int64_t left = size;
      while (left > 0) {
        int32_t length = 0;
        if (left < 4 || !read_i32(&length) || length < 0 || length > left - 4) {
          return refuse("unlike the strings it holds");
        }
        in.seekg(length, std::ios::cur);
        left -= 4 + int64_t(length);
      }
    } else {
      in.seekg(size, std::ios::cur);
    }
    if (!in) return OkStatus();
  }
  return OkStatus();
}

// No codec of OpenEXR packs pixels tighter than this many raw bytes per stored byte (deflate's
// limit is about 1032:1; RLE's 128:1), with margin for DWA on flat images.
constexpr uint64_t kMaxExrCompressionRatio = 4096;

// Imf::InputFile allocates the line (or tile) buffers of a whole chunk when it opens a file, from
// the data window alone: a 300-byte file declaring a 2^27-pixel-wide window made it allocate 2 GB
// (tests/fuzz/exr_fuzzer). The pixels of a chunk, and of the whole image, are stored in the file,
// so neither can exceed kMaxExrCompressionRatio times its size; a header claiming more is damaged.
Status CheckPixelBytes(const fs::path& path, exr_context_t context, uint64_t file_size) {
  exr_attr_box2i_t window{};
  const exr_attr_chlist_t* channels = nullptr;
  exr_storage_t storage = EXR_STORAGE_SCANLINE;
  int32_t lines_per_chunk = 1;
  if (exr_get_data_window(context, 0, &window) != EXR_ERR_SUCCESS ||
      exr_get_channels(context, 0, &channels) != EXR_ERR_SUCCESS || channels == nullptr ||
      exr_get_storage(context, 0, &storage) != EXR_ERR_SUCCESS) {
    return OkStatus();  // Imf reports what is missing
  }
  uint64_t pixel_bytes = 0;  // per pixel, all channels (subsampling ignored: an upper bound)
  for (int c = 0; c < channels->num_channels; ++c) {
    pixel_bytes += channels->entries[c].pixel_type == EXR_PIXEL_HALF ? 2 : 4;
  }
  const uint64_t width = uint64_t(int64_t(window.max.x) - window.min.x + 1);
  const uint64_t height = uint64_t(int64_t(window.max.y) - window.min.y + 1);
  uint64_t chunk_pixels = 0;
  if (storage == EXR_STORAGE_TILED || storage == EXR_STORAGE_DEEP_TILED) {
    uint32_t tile_x = 0, tile_y = 0;
    exr_tile_level_mode_t level{};
    exr_tile_round_mode_t round{};
    if (exr_get_tile_descriptor(context, 0, &tile_x, &tile_y, &level, &round) != EXR_ERR_SUCCESS) {
      return OkStatus();
    }
    chunk_pixels = uint64_t(tile_x) * tile_y;
  } else {
    if (exr_get_scanlines_per_chunk(context, 0, &lines_per_chunk) != EXR_ERR_SUCCESS) return OkStatus();
    chunk_pixels = width * uint64_t(std::max(lines_per_chunk, 1));
  }
  const uint64_t limit = kMaxExrCompressionRatio * file_size;
  // Guard the products against overflow: each factor is below 2^32.
  const double chunk_bytes = double(chunk_pixels) * double(pixel_bytes);
  const double image_bytes = double(width) * double(height) * double(pixel_bytes);
  if (chunk_bytes > double(limit) || image_bytes > double(limit)) {
    return DataLossError(path.string(), ": header declares a ", width, "x", height, " image of ",
                         channels->num_channels, " channels (", image_bytes,
                         " bytes of pixels), more than a ", file_size, "-byte file can hold");
  }
  return OkStatus();
}

Status CheckHeaderWithCore(const fs::path& path, uint64_t file_size) {
  // OpenEXRCore reports through a callback; the message of this thread's check lands here.
  static thread_local std::string core_message;
  core_message.clear();
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = [](exr_const_context_t, exr_result_t, const char* message) {
    core_message = message ? message : "";
  };
  exr_context_t context = nullptr;
  const exr_result_t result = exr_start_read(&context, path.c_str(), &init);
  if (result != EXR_ERR_SUCCESS) {
    if (context) exr_finish(&context);
    return DataLossError(path.string(), ": ",
                         core_message.empty() ? exr_get_default_error_message(result) : core_message);
  }
  const Status sizes = CheckPixelBytes(path, context, file_size);
  exr_finish(&context);
  return sizes;
}

Status CheckReadable(const fs::path& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    return InvalidArgumentError(path.string(), ": is a folder, not an OpenEXR file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return NotFoundError(path.string(), ": cannot open");
  const uintmax_t file_size = fs::file_size(path, ec);
  if (ec) return OkStatus();  // not a regular file: OpenEXR reports what it finds
  REFLCAP_RETURN_IF_ERROR(CheckAttributeSizes(path, uint64_t(file_size)));
  return CheckHeaderWithCore(path, uint64_t(file_size));
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
                    ExrPixelType type, int threads = kExrThreads) {
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
      header.zipCompressionLevel() = kExrZipLevel;
      Imf::FrameBuffer frame_buffer;
      for (int c = 0; c < image.channels; ++c) {
        header.channels().insert(names[c], Imf::Channel(pixel_type));
        frame_buffer.insert(names[c],
                            Imf::Slice(pixel_type, base + value_size * c, x_stride, y_stride));
      }
      // The file is closed (line offset table written) when `file` leaves this scope, before
      // WriteFileAtomic renames it.
      Imf::OutputFile file(tmp_path.c_str(), header, threads > 1 ? threads : kExrThreads);
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

StatusOr<Image> ReadExrChannels(const fs::path& path, std::vector<std::string>* channel_names,
                                int threads) {
  REFLCAP_CHECK(channel_names != nullptr);
  if (threads > 1) GrowGlobalPool(threads);
  std::vector<std::string> names;
  StatusOr<Image> image = GuardRead<Image>(path, [&]() -> StatusOr<Image> {
    Imf::InputFile file(path.c_str(), threads > 1 ? threads : kExrThreads);
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
                        const std::vector<std::string>& names, ExrPixelType type, int threads) {
  if (threads > 1) GrowGlobalPool(threads);
  return WriteExrImpl(path, image, names, type, threads);
}

}  // namespace reflcap
