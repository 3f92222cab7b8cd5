// Tests for engine/image/png_io.cc and the format dispatch in engine/image/image_io.cc: exact
// round trips at 8- and 16-bit quantisation, channel counts, expansion of palette, low-bit-depth,
// tRNS and interlaced files (tiny fixtures built byte by byte, see below), argument checks,
// clamping, and that missing, truncated and garbage files are errors naming the file.
#include "engine/image/png_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {

namespace fs = std::filesystem;
using testing::ScratchDir;

// Fixtures written independently of libpng by a few lines of Python (zlib.compress for IDAT,
// zlib.crc32 for chunk CRCs), so they check our decoder against the PNG specification rather
// than against our own encoder.
// clang-format off
// 16-bit grey 2x1, samples 0x0102 and 0xff00 (stored big-endian).
constexpr unsigned char kGrey16[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d,
    0x49, 0x48, 0x44, 0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x01,
    0x10, 0x00, 0x00, 0x00, 0x00, 0x81, 0xd9, 0xfc, 0x15, 0x00, 0x00, 0x00,
    0x0d, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0x60, 0x64, 0xfa, 0xcf,
    0x00, 0x00, 0x02, 0x0d, 0x01, 0x03, 0x7b, 0xe8, 0xc4, 0xbc, 0x00, 0x00,
    0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
};
// Palette 2x1: PLTE {red, (0,128,255)}, pixels index 1 then 0; gAMA 1/2.2 and sRGB chunks,
// which must not change the values.
constexpr unsigned char kPalette[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d,
    0x49, 0x48, 0x44, 0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x01,
    0x08, 0x03, 0x00, 0x00, 0x00, 0xc3, 0xfc, 0x8f, 0xb8, 0x00, 0x00, 0x00,
    0x04, 0x67, 0x41, 0x4d, 0x41, 0x00, 0x00, 0xb1, 0x8f, 0x0b, 0xfc, 0x61,
    0x05, 0x00, 0x00, 0x00, 0x01, 0x73, 0x52, 0x47, 0x42, 0x00, 0xae, 0xce,
    0x1c, 0xe9, 0x00, 0x00, 0x00, 0x06, 0x50, 0x4c, 0x54, 0x45, 0xff, 0x00,
    0x00, 0x00, 0x80, 0xff, 0x57, 0x22, 0x65, 0xc5, 0x00, 0x00, 0x00, 0x0b,
    0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0x60, 0x64, 0x00, 0x00, 0x00,
    0x05, 0x00, 0x02, 0x42, 0xc2, 0x44, 0x9f, 0x00, 0x00, 0x00, 0x00, 0x49,
    0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
};
// The same palette with tRNS {255, 64}: index 1 gets alpha 64.
constexpr unsigned char kPaletteAlpha[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d,
    0x49, 0x48, 0x44, 0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x01,
    0x08, 0x03, 0x00, 0x00, 0x00, 0xc3, 0xfc, 0x8f, 0xb8, 0x00, 0x00, 0x00,
    0x06, 0x50, 0x4c, 0x54, 0x45, 0xff, 0x00, 0x00, 0x00, 0x80, 0xff, 0x57,
    0x22, 0x65, 0xc5, 0x00, 0x00, 0x00, 0x02, 0x74, 0x52, 0x4e, 0x53, 0xff,
    0x40, 0x93, 0x6b, 0x71, 0xda, 0x00, 0x00, 0x00, 0x0b, 0x49, 0x44, 0x41,
    0x54, 0x78, 0xda, 0x63, 0x60, 0x64, 0x00, 0x00, 0x00, 0x05, 0x00, 0x02,
    0x42, 0xc2, 0x44, 0x9f, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44,
    0xae, 0x42, 0x60, 0x82,
};
// 1-bit grey 8x1, bits 10110000.
constexpr unsigned char kGrey1Bit[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d,
    0x49, 0x48, 0x44, 0x52, 0x00, 0x00, 0x00, 0x08, 0x00, 0x00, 0x00, 0x01,
    0x01, 0x00, 0x00, 0x00, 0x00, 0xcb, 0x7b, 0xd2, 0xee, 0x00, 0x00, 0x00,
    0x0a, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0xd8, 0x00, 0x00, 0x00,
    0xb2, 0x00, 0xb1, 0xf8, 0x82, 0x92, 0xa7, 0x00, 0x00, 0x00, 0x00, 0x49,
    0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
};
// Adam7-interlaced 8-bit grey 2x2 with rows (10, 20) and (30, 40).
constexpr unsigned char kInterlaced[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d,
    0x49, 0x48, 0x44, 0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x02,
    0x08, 0x00, 0x00, 0x00, 0x01, 0x20, 0xda, 0x62, 0x6e, 0x00, 0x00, 0x00,
    0x0f, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0xe0, 0x62, 0x10, 0x61,
    0x90, 0xd3, 0x00, 0x00, 0x00, 0xf7, 0x00, 0x65, 0x26, 0x2e, 0x0e, 0x42,
    0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
};
// IHDR claims 100000x100000 RGB; the IDAT holds 16 bytes of image data.
constexpr unsigned char kHugeHeader[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d,
    0x49, 0x48, 0x44, 0x52, 0x00, 0x01, 0x86, 0xa0, 0x00, 0x01, 0x86, 0xa0,
    0x08, 0x02, 0x00, 0x00, 0x00, 0x27, 0x30, 0x9c, 0x9f, 0x00, 0x00, 0x00,
    0x0b, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0x60, 0x40, 0x05, 0x00,
    0x00, 0x10, 0x00, 0x01, 0xaa, 0x19, 0xf8, 0x82, 0x00, 0x00, 0x00, 0x00,
    0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
};
// clang-format on

template <size_t N>
std::string Bytes(const unsigned char (&bytes)[N]) {
  return std::string(reinterpret_cast<const char*>(bytes), N);
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

// Every code k / max_code, cycled over the image's samples in a scrambled order.
Image QuantisedImage(int width, int height, int channels, uint32_t max_code) {
  Image image(width, height, channels);
  for (size_t i = 0; i < image.data.size(); ++i) {
    const uint32_t code = uint32_t((i * 2654435761u) % (uint64_t(max_code) + 1));
    image.data[i] = float(code) / float(max_code);
  }
  return image;
}

StatusOr<Image> ReadFixture(const ScratchDir& dir, const std::string& name,
                            const std::string& bytes) {
  const fs::path path = dir / name;
  WriteBytes(path, bytes);
  return ReadPng(path);
}

TEST(PngIo, EightBitRoundTripIsExactAtQuantisation) {
  ScratchDir dir;
  const fs::path path = dir / "rgb8.png";
  Image image(256, 1, 3);
  for (int k = 0; k < 256; ++k) {
    image.at(k, 0, 0) = float(k) / 255.0f;
    image.at(k, 0, 1) = float(255 - k) / 255.0f;
    image.at(k, 0, 2) = float((k * 7) % 256) / 255.0f;
  }
  ASSERT_TRUE(WritePng(path, image, 8).ok());
  StatusOr<Image> read = ReadPng(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->width, 256);
  EXPECT_EQ(read->height, 1);
  EXPECT_EQ(read->channels, 3);
  EXPECT_EQ(read->data, image.data);
}

TEST(PngIo, SixteenBitRoundTripIsExactAtQuantisation) {
  ScratchDir dir;
  const fs::path path = dir / "rgba16.png";
  Image image = QuantisedImage(37, 23, 4, 65535);
  image.data[0] = 0.0f;
  image.data[1] = 1.0f / 65535.0f;
  image.data[2] = 256.0f / 65535.0f;
  image.data[3] = 1.0f;
  ASSERT_TRUE(WritePng(path, image, 16).ok());
  StatusOr<Image> read = ReadPng(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->channels, 4);
  EXPECT_EQ(read->data, image.data);
}

TEST(PngIo, ChannelCountsSurviveRoundTrip) {
  ScratchDir dir;
  for (int channels = 1; channels <= 4; ++channels) {
    for (int bit_depth : {8, 16}) {
      const fs::path path =
          dir / ("c" + std::to_string(channels) + "_" + std::to_string(bit_depth) + ".png");
      const Image image = QuantisedImage(5, 3, channels, bit_depth == 8 ? 255 : 65535);
      ASSERT_TRUE(WritePng(path, image, bit_depth).ok());
      StatusOr<ImageInfo> info = ReadPngInfo(path);
      ASSERT_TRUE(info.ok()) << info.status().ToString();
      EXPECT_EQ(info->width, 5);
      EXPECT_EQ(info->height, 3);
      EXPECT_EQ(info->channels, channels);
      StatusOr<Image> read = ReadPng(path);
      ASSERT_TRUE(read.ok()) << read.status().ToString();
      EXPECT_EQ(read->channels, channels);
      EXPECT_EQ(read->data, image.data) << path;
    }
  }
}

TEST(PngIo, SixteenBitSamplesAreBigEndian) {
  ScratchDir dir;
  StatusOr<Image> read = ReadFixture(dir, "grey16.png", Bytes(kGrey16));
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->channels, 1);
  EXPECT_EQ(read->at(0, 0), float(0x0102) / 65535.0f);
  EXPECT_EQ(read->at(1, 0), float(0xff00) / 65535.0f);
}

TEST(PngIo, PaletteExpandsToRgbIgnoringGamma) {
  ScratchDir dir;
  StatusOr<Image> read = ReadFixture(dir, "palette.png", Bytes(kPalette));
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->channels, 3);
  EXPECT_EQ(read->at(0, 0, 0), 0.0f);
  EXPECT_EQ(read->at(0, 0, 1), 128.0f / 255.0f);
  EXPECT_EQ(read->at(0, 0, 2), 1.0f);
  EXPECT_EQ(read->at(1, 0, 0), 1.0f);
  EXPECT_EQ(read->at(1, 0, 1), 0.0f);
  EXPECT_EQ(read->at(1, 0, 2), 0.0f);
}

TEST(PngIo, PaletteTransparencyBecomesAlpha) {
  ScratchDir dir;
  const std::string bytes = Bytes(kPaletteAlpha);
  StatusOr<Image> read = ReadFixture(dir, "palette_alpha.png", bytes);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->channels, 4);
  EXPECT_EQ(read->at(0, 0, 1), 128.0f / 255.0f);
  EXPECT_EQ(read->at(0, 0, 3), 64.0f / 255.0f);
  EXPECT_EQ(read->at(1, 0, 3), 1.0f);
  StatusOr<ImageInfo> info = ReadPngInfo(dir / "palette_alpha.png");
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->channels, 4);
}

TEST(PngIo, LowBitDepthGreyExpandsToFullRange) {
  ScratchDir dir;
  StatusOr<Image> read = ReadFixture(dir, "grey1.png", Bytes(kGrey1Bit));
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->channels, 1);
  ASSERT_EQ(read->width, 8);
  const std::vector<float> expected = {1, 0, 1, 1, 0, 0, 0, 0};
  EXPECT_EQ(std::vector<float>(read->data.begin(), read->data.end()), expected);
}

TEST(PngIo, InterlacedImageIsDeinterlaced) {
  ScratchDir dir;
  StatusOr<Image> read = ReadFixture(dir, "interlaced.png", Bytes(kInterlaced));
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  const std::vector<float> expected = {10 / 255.0f, 20 / 255.0f, 30 / 255.0f, 40 / 255.0f};
  EXPECT_EQ(std::vector<float>(read->data.begin(), read->data.end()), expected);
}

TEST(PngIo, HeaderLargerThanFileCanHoldIsDataLoss) {
  ScratchDir dir;
  StatusOr<Image> read = ReadFixture(dir, "huge.png", Bytes(kHugeHeader));
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), StatusCode::kDataLoss) << read.status().ToString();
}

TEST(PngIo, OutOfRangeValuesAreClamped) {
  ScratchDir dir;
  const fs::path path = dir / "clamp.png";
  Image image(5, 1, 1);
  image.data = {-0.5f, 2.0f, std::numeric_limits<float>::quiet_NaN(),
                std::numeric_limits<float>::infinity(), 0.5f};
  ::testing::internal::CaptureStderr();
  ASSERT_TRUE(WritePng(path, image, 16).ok());
  const std::string log = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(log.find(path.string() + ": wrote 1 NaN"), std::string::npos) << log;
  StatusOr<Image> read = ReadPng(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->data[0], 0.0f);
  EXPECT_EQ(read->data[1], 1.0f);
  EXPECT_EQ(read->data[2], 0.0f);
  EXPECT_EQ(read->data[3], 1.0f);
  EXPECT_EQ(read->data[4], 32768.0f / 65535.0f);  // 0.5 * 65535 = 32767.5 rounds up
}

TEST(PngIo, BadWriteArgumentsAreInvalidArgument) {
  ScratchDir dir;
  const fs::path path = dir / "bad.png";
  const Status twelve_bit = WritePng(path, Image(2, 2, 3), 12);
  EXPECT_EQ(twelve_bit.code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(StartsWith(twelve_bit.message(), path.string())) << twelve_bit.message();
  EXPECT_EQ(WritePng(path, Image(2, 2, 5)).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(WritePng(path, Image()).code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(fs::exists(path));
}

TEST(PngIo, MissingFileIsNotFound) {
  ScratchDir dir;
  const fs::path path = dir / "absent.png";
  StatusOr<Image> read = ReadPng(path);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), StatusCode::kNotFound);
  EXPECT_EQ(read.status().message(), path.string() + ": cannot open");
  EXPECT_EQ(ReadPngInfo(path).status().code(), StatusCode::kNotFound);
}

TEST(PngIo, TruncatedFileIsDataLoss) {
  ScratchDir dir;
  const fs::path whole = dir / "whole.png";
  ASSERT_TRUE(WritePng(whole, QuantisedImage(48, 32, 3, 255)).ok());
  const std::string bytes = ReadBytes(whole);
  // Half the file, a cut inside IHDR, and one byte short (IEND incomplete).
  for (size_t keep : {bytes.size() / 2, size_t(20), bytes.size() - 1}) {
    const fs::path cut = dir / ("cut" + std::to_string(keep) + ".png");
    WriteBytes(cut, bytes.substr(0, keep));
    StatusOr<Image> read = ReadPng(cut);
    ASSERT_FALSE(read.ok()) << "kept " << keep << " of " << bytes.size() << " bytes";
    EXPECT_EQ(read.status().code(), StatusCode::kDataLoss) << read.status().ToString();
    EXPECT_TRUE(StartsWith(read.status().message(), cut.string())) << read.status().message();
  }
}

TEST(PngIo, GarbageFileIsDataLoss) {
  ScratchDir dir;
  std::string garbage(2048, '\0');
  uint32_t state = 11u;
  for (char& c : garbage) {
    state = state * 1664525u + 1013904223u;
    c = char(state >> 24);
  }
  const fs::path plain = dir / "garbage.png";
  WriteBytes(plain, garbage);
  // A valid signature, then garbage: gets past the first check.
  const fs::path signed_garbage = dir / "signed.png";
  WriteBytes(signed_garbage, std::string("\x89PNG\r\n\x1a\n", 8) + garbage);
  for (const fs::path& path : {plain, signed_garbage}) {
    StatusOr<Image> read = ReadPng(path);
    ASSERT_FALSE(read.ok());
    EXPECT_EQ(read.status().code(), StatusCode::kDataLoss) << read.status().ToString();
    EXPECT_TRUE(StartsWith(read.status().message(), path.string())) << read.status().message();
    EXPECT_EQ(ReadPngInfo(path).status().code(), StatusCode::kDataLoss);
  }
}

// image_io.cc is tested here: it is a thin dispatcher and the test target lists only the two
// format test files.
TEST(ImageIo, DispatchesOnExtensionCaseInsensitively) {
  ScratchDir dir;
  Image grey(3, 2, 1, 0.0f);
  for (size_t i = 0; i < grey.data.size(); ++i) grey.data[i] = float(i) / 255.0f;
  ASSERT_TRUE(WritePng(dir / "grey.PNG", grey).ok());
  ASSERT_TRUE(WriteExr(dir / "grey.Exr", grey).ok());
  for (const char* name : {"grey.PNG", "grey.Exr"}) {
    StatusOr<Image> rgb = ReadImageRgb(dir / name);
    ASSERT_TRUE(rgb.ok()) << rgb.status().ToString();
    ASSERT_EQ(rgb->channels, 3);
    for (size_t i = 0; i < grey.PixelCount(); ++i) {
      for (int c = 0; c < 3; ++c) EXPECT_EQ(rgb->data[3 * i + size_t(c)], grey.data[i]) << name;
    }
    StatusOr<ImageInfo> info = ReadImageInfo(dir / name);
    ASSERT_TRUE(info.ok()) << info.status().ToString();
    EXPECT_EQ(info->width, 3);
    EXPECT_EQ(info->channels, 1);
  }
}

TEST(ImageIo, RgbaPngLosesAlpha) {
  ScratchDir dir;
  const fs::path path = dir / "rgba.png";
  const Image rgba = QuantisedImage(4, 4, 4, 255);
  ASSERT_TRUE(WritePng(path, rgba).ok());
  StatusOr<Image> rgb = ReadImageRgb(path);
  ASSERT_TRUE(rgb.ok()) << rgb.status().ToString();
  ASSERT_EQ(rgb->channels, 3);
  for (size_t i = 0; i < rgba.PixelCount(); ++i) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(rgb->data[3 * i + size_t(c)], rgba.data[4 * i + size_t(c)]);
    }
  }
}

TEST(ImageIo, UnknownExtensionIsInvalidArgument) {
  ScratchDir dir;
  const fs::path path = dir / "photo.tif";
  WriteBytes(path, "not really a tiff");
  StatusOr<Image> read = ReadImageRgb(path);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(StartsWith(read.status().message(), path.string() + ": unsupported image type"))
      << read.status().message();
  EXPECT_EQ(ReadImageInfo(path).status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace reflcap
