// Tests for engine/image/exr_io.cc: round trips at float and half precision, channel naming and
// order, header-only reads, and that missing, truncated and garbage files come back as errors
// naming the file, never as crashes or partial images. Images are generated in the test.
#include "engine/image/exr_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "tests/support/test_support.h"

namespace reflcap {
namespace {

namespace fs = std::filesystem;
using testing::ScratchDir;

// Half has 10 explicit significand bits, so rounding a normal value (|x| >= 2^-14) to the nearest
// half changes it by at most half a unit in the last place: a relative error of 2^-11.
constexpr float kHalfRelativeTolerance = 1.0f / 2048.0f;
// Largest finite half; the writer clamps to it instead of producing Inf.
constexpr float kHalfMax = 65504.0f;

// A deterministic, poorly compressible pattern of signed values spanning several decades, all
// within the normal half range so the half tolerance applies.
Image PatternImage(int width, int height, int channels) {
  Image image(width, height, channels);
  uint32_t state = 12345u;
  for (float& value : image.data) {
    state = state * 1664525u + 1013904223u;                        // LCG (Numerical Recipes)
    const float unit = float(state >> 8) / float(1u << 24);        // [0, 1)
    const float magnitude = std::pow(10.0f, -3.0f + 6.0f * unit);  // [1e-3, 1e3)
    value = ((state >> 4) & 1u) ? magnitude : -magnitude;
  }
  return image;
}

std::string ReadBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void WriteBytes(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), std::streamsize(bytes.size()));
  ASSERT_TRUE(bool(out)) << path;
}

bool StartsWith(const std::string& text, const std::string& prefix) {
  return text.compare(0, prefix.size(), prefix) == 0;
}

TEST(ExrIo, FloatRoundTripIsExact) {
  ScratchDir dir;
  const fs::path path = dir / "float.exr";
  const Image image = PatternImage(17, 11, 3);
  ASSERT_TRUE(WriteExr(path, image, ExrPixelType::kFloat).ok());
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->width, 17);
  EXPECT_EQ(read->height, 11);
  EXPECT_EQ(read->channels, 3);
  EXPECT_EQ(read->data, image.data);
}

TEST(ExrIo, HalfRoundTripWithinHalfPrecision) {
  ScratchDir dir;
  const fs::path path = dir / "half.exr";
  const Image image = PatternImage(13, 7, 3);
  ASSERT_TRUE(WriteExr(path, image, ExrPixelType::kHalf).ok());
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->data.size(), image.data.size());
  for (size_t i = 0; i < image.data.size(); ++i) {
    EXPECT_NEAR(read->data[i], image.data[i], kHalfRelativeTolerance * std::abs(image.data[i]))
        << "sample " << i;
  }
}

TEST(ExrIo, ReadsRgbByNameWhateverTheFileOrder) {
  ScratchDir dir;
  const fs::path path = dir / "order.exr";
  // Image channel 0 is written as "B", 1 as "G", 2 as "R".
  Image image(2, 2, 3);
  for (size_t i = 0; i < image.PixelCount(); ++i) {
    image.data[3 * i + 0] = 0.75f;  // B
    image.data[3 * i + 1] = 0.5f;   // G
    image.data[3 * i + 2] = 0.25f;  // R
  }
  ASSERT_TRUE(WriteExrChannels(path, image, {"B", "G", "R"}).ok());
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  for (int y = 0; y < 2; ++y) {
    for (int x = 0; x < 2; ++x) {
      EXPECT_EQ(read->at(x, y, 0), 0.25f);
      EXPECT_EQ(read->at(x, y, 1), 0.5f);
      EXPECT_EQ(read->at(x, y, 2), 0.75f);
    }
  }
}

TEST(ExrIo, LuminanceOnlyIsReplicatedToRgb) {
  ScratchDir dir;
  const fs::path path = dir / "grey.exr";
  const Image grey = PatternImage(5, 4, 1);
  ASSERT_TRUE(WriteExr(path, grey).ok());
  StatusOr<ImageInfo> info = ReadExrInfo(path);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->channel_names, std::vector<std::string>{"Y"});
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->channels, 3);
  for (int y = 0; y < 4; ++y) {
    for (int x = 0; x < 5; ++x) {
      for (int c = 0; c < 3; ++c) EXPECT_EQ(read->at(x, y, c), grey.at(x, y));
    }
  }
}

TEST(ExrIo, MissingGreenAndBlueCopyRed) {
  ScratchDir dir;
  const fs::path path = dir / "red.exr";
  const Image red = PatternImage(3, 3, 1);
  ASSERT_TRUE(WriteExrChannels(path, red, {"R"}).ok());
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  for (size_t i = 0; i < red.PixelCount(); ++i) {
    for (int c = 0; c < 3; ++c) EXPECT_EQ(read->data[3 * i + size_t(c)], red.data[i]);
  }
}

TEST(ExrIo, NoColourChannelIsInvalidArgument) {
  ScratchDir dir;
  const fs::path path = dir / "depth.exr";
  ASSERT_TRUE(WriteExrChannels(path, Image(2, 2, 1, 1.0f), {"Z"}).ok());
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(StartsWith(read.status().message(), path.string())) << read.status().message();
}

TEST(ExrIo, DataWindowUnlikeDisplayWindowIsInvalidArgument) {
  ScratchDir dir;
  const fs::path whole = dir / "whole.exr";
  ASSERT_TRUE(WriteExr(whole, PatternImage(8, 4, 3)).ok());
  // Patch the header's dataWindow attribute (name, type, int32 size, then xMin yMin xMax yMax as
  // little-endian int32) so that xMin = 1: the data window no longer covers the display window.
  std::string bytes = ReadBytes(whole);
  const std::string attribute("dataWindow\0box2i\0", 17);
  const size_t at = bytes.find(attribute);
  ASSERT_NE(at, std::string::npos);
  bytes[at + attribute.size() + 4] = 1;
  const fs::path path = dir / "cropped.exr";
  WriteBytes(path, bytes);
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), StatusCode::kInvalidArgument) << read.status().ToString();
  EXPECT_TRUE(StartsWith(read.status().message(), path.string())) << read.status().message();
  std::vector<std::string> names;
  EXPECT_EQ(ReadExrChannels(path, &names).status().code(), StatusCode::kInvalidArgument);
}

TEST(ExrIo, NamedChannelsRoundTripInAlphabeticalOrder) {
  ScratchDir dir;
  const fs::path path = dir / "params.exr";
  const std::vector<std::string> names = {"rho_d.R", "lobe0.Cx.R", "lobe0.n"};
  const Image image = PatternImage(6, 5, 3);
  ASSERT_TRUE(WriteExrChannels(path, image, names).ok());
  std::vector<std::string> read_names;
  StatusOr<Image> read = ReadExrChannels(path, &read_names);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  const std::vector<std::string> sorted = {"lobe0.Cx.R", "lobe0.n", "rho_d.R"};
  ASSERT_EQ(read_names, sorted);
  ASSERT_EQ(read->channels, 3);
  // Written channel w lands at the read position of its name.
  const int read_index_of_written[] = {2, 0, 1};
  for (size_t i = 0; i < image.PixelCount(); ++i) {
    for (int w = 0; w < 3; ++w) {
      EXPECT_EQ(read->data[3 * i + size_t(read_index_of_written[w])],
                image.data[3 * i + size_t(w)]);
    }
  }
}

TEST(ExrIo, CompressingOnThreadsWritesTheSameBytes) {
  // The fit's maps are compressed on the pool's threads: the file must be the one a single
  // thread writes (ZIP blocks of 16 scanlines each, written in order), at sizes with a partial
  // last block.
  ScratchDir dir;
  const std::vector<std::string> names = {"a", "b", "c", "d", "e"};
  const Image image = PatternImage(97, 203, 5);
  ASSERT_TRUE(WriteExrChannels(dir / "one.exr", image, names).ok());
  ASSERT_TRUE(WriteExrChannels(dir / "four.exr", image, names, ExrPixelType::kFloat, 4).ok());
  const std::string one = ReadBytes(dir / "one.exr");
  EXPECT_GT(one.size(), 97u * 203u * 5u);  // little compresses: the blocks are not trivial
  EXPECT_EQ(one, ReadBytes(dir / "four.exr"));
}

TEST(ExrIo, RgbaWritesFourNamedChannels) {
  ScratchDir dir;
  const fs::path path = dir / "rgba.exr";
  const Image image = PatternImage(4, 3, 4);
  ASSERT_TRUE(WriteExr(path, image).ok());
  std::vector<std::string> names;
  StatusOr<Image> read = ReadExrChannels(path, &names);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(names, (std::vector<std::string>{"A", "B", "G", "R"}));
  StatusOr<Image> rgb = ReadExrRgb(path);
  ASSERT_TRUE(rgb.ok()) << rgb.status().ToString();
  for (size_t i = 0; i < image.PixelCount(); ++i) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(rgb->data[3 * i + size_t(c)], image.data[4 * i + size_t(c)]);
    }
  }
}

TEST(ExrIo, InfoMatchesWrittenImage) {
  ScratchDir dir;
  const fs::path path = dir / "info.exr";
  ASSERT_TRUE(WriteExr(path, PatternImage(9, 4, 3), ExrPixelType::kHalf).ok());
  StatusOr<ImageInfo> info = ReadExrInfo(path);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->width, 9);
  EXPECT_EQ(info->height, 4);
  EXPECT_EQ(info->channels, 3);
  EXPECT_EQ(info->channel_names, (std::vector<std::string>{"B", "G", "R"}));
}

TEST(ExrIo, WriteLeavesOnlyTheFinalFile) {
  ScratchDir dir;
  ASSERT_TRUE(WriteExr(dir / "out.exr", PatternImage(3, 2, 3)).ok());
  ASSERT_TRUE(WriteExr(dir / "out.exr", PatternImage(3, 2, 3)).ok());  // replaces
  std::vector<std::string> entries;
  for (const auto& entry : fs::directory_iterator(dir.path())) {
    entries.push_back(entry.path().filename().string());
  }
  EXPECT_EQ(entries, std::vector<std::string>{"out.exr"});
}

TEST(ExrIo, BadWriteArgumentsAreInvalidArgument) {
  ScratchDir dir;
  const fs::path path = dir / "bad.exr";
  EXPECT_EQ(WriteExr(path, Image(2, 2, 2)).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(WriteExr(path, Image()).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(WriteExrChannels(path, Image(2, 2, 2), {"a"}).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(WriteExrChannels(path, Image(2, 2, 2), {"a", "a"}).code(),
            StatusCode::kInvalidArgument);
  EXPECT_FALSE(fs::exists(path));
}

TEST(ExrIo, MissingFileIsNotFound) {
  ScratchDir dir;
  const fs::path path = dir / "absent.exr";
  StatusOr<Image> read = ReadExrRgb(path);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), StatusCode::kNotFound);
  EXPECT_EQ(read.status().message(), path.string() + ": cannot open");
  EXPECT_EQ(ReadExrInfo(path).status().code(), StatusCode::kNotFound);
  std::vector<std::string> names;
  EXPECT_EQ(ReadExrChannels(path, &names).status().code(), StatusCode::kNotFound);
}

TEST(ExrIo, TruncatedFileIsDataLoss) {
  ScratchDir dir;
  const fs::path whole = dir / "whole.exr";
  ASSERT_TRUE(WriteExr(whole, PatternImage(64, 48, 3)).ok());
  const std::string bytes = ReadBytes(whole);
  ASSERT_GT(bytes.size(), 1000u);
  // Half the file (the case named in the contract), then cuts inside the header, inside the
  // offset table and one byte short of the end (every chunk offset still valid).
  for (size_t keep : {bytes.size() / 2, size_t(8), size_t(400), bytes.size() - 1}) {
    const fs::path cut = dir / ("cut" + std::to_string(keep) + ".exr");
    WriteBytes(cut, bytes.substr(0, keep));
    StatusOr<Image> rgb = ReadExrRgb(cut);
    ASSERT_FALSE(rgb.ok()) << "kept " << keep << " of " << bytes.size() << " bytes";
    EXPECT_EQ(rgb.status().code(), StatusCode::kDataLoss) << rgb.status().ToString();
    EXPECT_TRUE(StartsWith(rgb.status().message(), cut.string())) << rgb.status().message();
    std::vector<std::string> names;
    EXPECT_EQ(ReadExrChannels(cut, &names).status().code(), StatusCode::kDataLoss);
    EXPECT_TRUE(names.empty());
  }
}

TEST(ExrIo, GarbageFileIsDataLoss) {
  ScratchDir dir;
  std::string garbage(4096, '\0');
  uint32_t state = 7u;
  for (char& c : garbage) {
    state = state * 1664525u + 1013904223u;
    c = char(state >> 24);
  }
  const fs::path plain = dir / "garbage.exr";
  WriteBytes(plain, garbage);
  // The OpenEXR magic number and version, then garbage: gets past the first check.
  const fs::path magic = dir / "magic.exr";
  WriteBytes(magic, std::string("\x76\x2f\x31\x01\x02\x00\x00\x00", 8) + garbage);
  for (const fs::path& path : {plain, magic}) {
    StatusOr<Image> read = ReadExrRgb(path);
    ASSERT_FALSE(read.ok());
    EXPECT_EQ(read.status().code(), StatusCode::kDataLoss) << read.status().ToString();
    EXPECT_TRUE(StartsWith(read.status().message(), path.string())) << read.status().message();
    EXPECT_EQ(ReadExrInfo(path).status().code(), StatusCode::kDataLoss);
  }
}

// Regression (tests/fuzz/exr_fuzzer): OpenEXR allocates a header attribute's declared size
// before reading it, so a tiny file declaring a 1.6 GB attribute used to make it allocate
// 1.6 GB. The reader now refuses sizes that run past the end of the file, before OpenEXR.
TEST(ExrIo, AttributeSizePastTheEndOfTheFileIsDataLoss) {
  ScratchDir dir;
  const fs::path whole = dir / "whole.exr";
  ASSERT_TRUE(WriteExr(whole, PatternImage(4, 3, 3)).ok());
  const std::string bytes = ReadBytes(whole);
  const int32_t declared = 1600000000;
  const std::string attribute = std::string("reflcapHuge\0opaqueType\0", 23) +
                                std::string(reinterpret_cast<const char*>(&declared), 4) + "xyz";
  const fs::path huge = dir / "huge_attribute.exr";
  WriteBytes(huge, bytes.substr(0, 8) + attribute + bytes.substr(8));
  for (const Status& status : {ReadExrInfo(huge).status(), ReadExrRgb(huge).status()}) {
    EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.ToString();
    EXPECT_TRUE(StartsWith(status.message(), huge.string())) << status.message();
    EXPECT_NE(status.message().find("reflcapHuge"), std::string::npos) << status.message();
  }
  // A channel list shorter than its declared size: Imf parses a chlist to its end whatever its
  // size says and then reads the following bytes as attributes (a fuzzer input made it allocate
  // 1.6 GB that way); OpenEXRCore's parse, run first, refuses the mismatch.
  const size_t chlist = bytes.find(std::string("chlist\0", 7));
  ASSERT_NE(chlist, std::string::npos);
  std::string short_list = bytes;
  const int32_t too_short = 5;
  short_list.replace(chlist + 7, 4, std::string(reinterpret_cast<const char*>(&too_short), 4));
  const fs::path mismatch = dir / "chlist_size.exr";
  WriteBytes(mismatch, short_list);
  for (const Status& status : {ReadExrInfo(mismatch).status(), ReadExrRgb(mismatch).status()}) {
    EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.ToString();
    EXPECT_TRUE(StartsWith(status.message(), mismatch.string())) << status.message();
  }
  // A 200000 x 200000 window in a file of a few hundred bytes: Imf allocates a chunk's line
  // buffers from the window alone when it opens the file (2 GB for a fuzzer input).
  std::string huge_window = bytes;
  for (const char* box : {"dataWindow", "displayWindow"}) {
    const size_t at = huge_window.find(std::string(box) + std::string("\0box2i\0", 7));
    ASSERT_NE(at, std::string::npos) << box;
    const int32_t max_xy[2] = {199999, 199999};
    huge_window.replace(at + std::strlen(box) + 7 + 4 + 8, 8,
                        std::string(reinterpret_cast<const char*>(max_xy), 8));
  }
  const fs::path huge_image = dir / "huge_window.exr";
  WriteBytes(huge_image, huge_window);
  for (const Status& status : {ReadExrInfo(huge_image).status(), ReadExrRgb(huge_image).status()}) {
    EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.ToString();
    EXPECT_NE(status.message().find("200000x200000"), std::string::npos) << status.message();
  }
  // A repeated attribute: Imf keeps the last, OpenEXRCore the first, so they would disagree on
  // what CheckPixelBytes bounds.
  const fs::path twice = dir / "twice.exr";
  const std::string repeated = std::string("compression\0compression\0", 24) +
                               std::string("\x01\0\0\0\0", 5);
  WriteBytes(twice, bytes.substr(0, 8) + repeated + bytes.substr(8));
  const Status repeated_status = ReadExrInfo(twice).status();
  EXPECT_EQ(repeated_status.code(), StatusCode::kDataLoss) << repeated_status.ToString();
  EXPECT_NE(repeated_status.message().find("appears twice"), std::string::npos)
      << repeated_status.message();
  // The unmodified file still reads.
  EXPECT_TRUE(ReadExrRgb(whole).ok());
}

TEST(ExrIo, HugeValuesAreClampedToHalfMax) {
  ScratchDir dir;
  const fs::path path = dir / "huge.exr";
  Image image(4, 1, 1);
  image.data = {1e6f, -1e6f, std::numeric_limits<float>::infinity(), 100.0f};
  ::testing::internal::CaptureStderr();
  ASSERT_TRUE(WriteExr(path, image, ExrPixelType::kHalf).ok());
  const std::string log = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(log.find(path.string()), std::string::npos) << log;
  EXPECT_NE(log.find("clamped 3 "), std::string::npos) << log;
  std::vector<std::string> names;
  StatusOr<Image> read = ReadExrChannels(path, &names);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->data[0], kHalfMax);
  EXPECT_EQ(read->data[1], -kHalfMax);
  EXPECT_EQ(read->data[2], kHalfMax);
  EXPECT_EQ(read->data[3], 100.0f);  // exactly representable in half
}

TEST(ExrIo, NonFiniteValuesNeverReachTheFile) {
  ScratchDir dir;
  Image image(3, 1, 1);
  image.data = {std::numeric_limits<float>::quiet_NaN(), -std::numeric_limits<float>::infinity(),
                0.5f};
  for (ExrPixelType type : {ExrPixelType::kHalf, ExrPixelType::kFloat}) {
    const fs::path path = dir / (type == ExrPixelType::kHalf ? "nan_half.exr" : "nan_float.exr");
    ::testing::internal::CaptureStderr();
    ASSERT_TRUE(WriteExr(path, image, type).ok());
    const std::string log = ::testing::internal::GetCapturedStderr();
    EXPECT_NE(log.find(path.string() + ": wrote 1 NaN"), std::string::npos) << log;
    std::vector<std::string> names;
    StatusOr<Image> read = ReadExrChannels(path, &names);
    ASSERT_TRUE(read.ok()) << read.status().ToString();
    EXPECT_EQ(read->data[0], 0.0f);
    EXPECT_TRUE(std::isfinite(read->data[1]));
    EXPECT_LT(read->data[1], 0.0f);
    EXPECT_EQ(read->data[2], 0.5f);
  }
}

}  // namespace
}  // namespace reflcap
