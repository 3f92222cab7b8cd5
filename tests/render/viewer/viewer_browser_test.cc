// `reflcap view` through the executable and headless Chromium (Debian's package, installed by
// .ci/install-deps): the page's WebGL re-render of held-out views against the CPU reference
// renderer's (`reflcap render --no-shadows`: the page draws no cast shadows), both through the
// page's display mapping (DisplayValue) at 8 bits; and bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include <nlohmann/json.hpp>

#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "render/reference/render_capture.h"
#include "render/viewer/viewer_page.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;
using testing::CliResult;

// The bar for the browser's re-render against the CPU reference at the same view.
constexpr double kMinScreenshotPsnrDb = 35.0;
// Away from silhouettes (kEdgePx) the two renderers run the same model on the same texel, so
// only float rounding (GPU pow/exp2 against libm) and 8-bit quantisation separate them: a pixel
// is off when a channel differs by more than kOffBy (rounding to 8 bits and ~1 % of a value).
// A few pixels still differ where the rasteriser and the CPU's ray pick different triangles on
// either side of an interior edge (geometric-normal tests, a neighbouring texel under a
// sharp lobe: measured 7 of 3,512 and 18 of 3,910 interior pixels on the two views); a wrong clamp,
// frame or texel lookup would put far more than kMaxOffFraction off.
constexpr int kEdgePx = 2;
constexpr double kOffBy = 3.0 / 255.0;
constexpr double kMaxOffFraction = 0.01;
// A view whose reference shows less than this mean display value over the object is too dark
// to test anything (guards against a black screenshot passing against a black reference).
constexpr double kMinMeanDisplayValue = 0.05;

CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

bool HaveChromium() { return std::system("command -v chromium > /dev/null 2>&1") == 0; }

// A small synthetic capture with 128-px photographs, made once for this file.
const fs::path& SmallCapture() {
  static const testing::ScratchDir* dir = &reflcap::testing::NewProcessScratchDir();
  static const fs::path capture = [] {
    testing::ScratchDir logs;
    const fs::path out = *dir / "small";
    CliResult r = RunCli("synth --quiet --out " + out.string() +
                             " --texels 4000 --image-size 128 --cameras 2 --lights 2 --steps 4",
                         logs);
    REFLCAP_CHECK(r.exit_code == 0) << r.err;
    return out;
  }();
  return capture;
}

// Headless Chromium draws only part of the page in windows smaller than about this (measured:
// a 128 x 128 window showed the top 40 rows); the page's canvas sits in the top-left corner of a
// larger window and the comparison reads that corner.
constexpr int kMinWindowSide = 512;

// Screenshot of `url` (at least width x height) by headless Chromium (software WebGL:
// SwiftShader).
StatusOr<Image> Screenshot(const std::string& url, int width, int height,
                           const testing::ScratchDir& dir, const std::string& name) {
  const fs::path png = dir / (name + ".png");
  const std::string command =
      "chromium --headless=new --no-sandbox --use-angle=swiftshader --enable-unsafe-swiftshader "
      "--force-device-scale-factor=1 --hide-scrollbars --user-data-dir=" +
      (dir / "chromium-profile").string() + " --window-size=" +
      std::to_string(std::max(width, kMinWindowSide)) + "," +
      std::to_string(std::max(height, kMinWindowSide)) + " --virtual-time-budget=20000 --screenshot=" + png.string() +
      " '" + url + "' > " + (dir / (name + ".log")).string() + " 2>&1";
  if (std::system(command.c_str()) != 0 || !fs::exists(png)) {
    auto log = ReadTextFile(dir / (name + ".log"));
    return InternalError("chromium failed: ", command, "\n", log.ok() ? *log : "");
  }
  return ReadPng(png);
}

TEST(ViewerBrowser, ScreenshotAtAHeldOutViewMatchesTheCpuReference) {
  if (!HaveChromium()) GTEST_SKIP() << "chromium is not installed (.ci/install-deps installs it)";
  if (!render::ViewerHasThreeJs()) {
    GTEST_SKIP() << "built without three.js (render/viewer/node_modules missing at configure "
                    "time; .ci/install-deps runs npm ci)";
  }
  testing::ScratchDir dir;
  const fs::path cap = SmallCapture();
  CliResult r = RunCli("view " + (cap / "gt").string() + " --out " + (dir / "view").string() +
                           " --views 2", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = RunCli("render " + cap.string() + " " + (cap / "gt").string() + " --out " +
                 (dir / "cpu").string() + " --no-shadows", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto views_text = ReadTextFile(dir / "view" / "views.json");
  ASSERT_TRUE(views_text.ok());
  const Json views = Json::parse(*views_text)["views"];
  ASSERT_EQ(views.size(), 2u);
  for (size_t k = 0; k < views.size(); ++k) {
    const std::string file = views[k]["file"];
    const int width = views[k]["width"], height = views[k]["height"];
    const float scale = views[k]["display_scale"];
    auto shot = Screenshot("file://" + (dir / "view" / "index.html").string() +
                               "?test=" + std::to_string(k),
                           width, height, dir, "shot" + std::to_string(k));
    ASSERT_TRUE(shot.ok()) << shot.status().ToString();
    ASSERT_GE(shot->width, width);
    ASSERT_GE(shot->height, height);
    auto reference = ReadExrRgb(dir / "cpu" / render::RenderPathFor(file));
    ASSERT_TRUE(reference.ok()) << reference.status().ToString();
    auto mask = ReadPng(dir / "cpu" / render::MaskPathFor(file));
    ASSERT_TRUE(mask.ok()) << mask.status().ToString();
    // Interior: every pixel within kEdgePx in the mask too (away from silhouettes, where the
    // rasteriser's coverage and the CPU's centre ray may pick different triangles).
    auto interior = [&](int x, int y) {
      for (int dy = -kEdgePx; dy <= kEdgePx; ++dy) {
        for (int dx = -kEdgePx; dx <= kEdgePx; ++dx) {
          const int xx = x + dx, yy = y + dy;
          if (xx < 0 || yy < 0 || xx >= width || yy >= height || mask->at(xx, yy) < 0.5f) {
            return false;
          }
        }
      }
      return true;
    };
    double sq = 0, sq_interior = 0, mean = 0;
    size_t n = 0, n_interior = 0, off = 0;
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        if (mask->at(x, y) < 0.5f) continue;
        const bool inside = interior(x, y);
        bool pixel_off = false;
        for (int c = 0; c < 3; ++c) {
          const double expected =
              std::round(255.0 * render::DisplayValue(reference->at(x, y, c), scale)) / 255.0;
          const double got = shot->at(x, y, c);
          sq += (got - expected) * (got - expected);
          mean += expected;
          ++n;
          if (inside) {
            sq_interior += (got - expected) * (got - expected);
            ++n_interior;
            pixel_off = pixel_off || std::abs(got - expected) > kOffBy;
          }
        }
        off += pixel_off;
      }
    }
    ASSERT_GT(n_interior, 0u);
    mean /= double(n);
    auto psnr_of = [](double squares, size_t count) {
      return squares > 0 ? 10 * std::log10(double(count) / squares) : 150.0;  // exact: the cap
    };
    const double psnr = psnr_of(sq, n), psnr_interior = psnr_of(sq_interior, n_interior);
    const double off_fraction = double(off) / double(n_interior / 3);
    std::printf("view %zu (%s): %zu object pixels, mean display value %.3f, PSNR %.2f dB; "
                "more than %d px inside the silhouette %.2f dB, %zu of %zu pixels off\n",
                k, file.c_str(), n / 3, mean, psnr, kEdgePx, psnr_interior, off, n_interior / 3);
    EXPECT_GT(mean, kMinMeanDisplayValue) << file;
    EXPECT_GE(psnr, kMinScreenshotPsnrDb) << file;
    EXPECT_LE(off_fraction, kMaxOffFraction) << file;
    if ((psnr < kMinScreenshotPsnrDb || off_fraction > kMaxOffFraction) &&
        std::getenv("REFLCAP_TEST_DUMP_DIR") != nullptr) {
      // Both images, for a look at a failed comparison.
      const fs::path dump = std::getenv("REFLCAP_TEST_DUMP_DIR");
      Image expected(width, height, 3);
      for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
          for (int c = 0; c < 3; ++c) {
            expected.at(x, y, c) = render::DisplayValue(reference->at(x, y, c), scale);
          }
        }
      }
      EXPECT_TRUE(WritePng(dump / StrCat("viewer_expected", k, ".png"), expected).ok());
      fs::copy_file(dir / StrCat("shot", k, ".png"), dump / StrCat("viewer_shot", k, ".png"),
                    fs::copy_options::overwrite_existing);
    }
  }
}

// Mean absolute difference of two screenshots over their common top-left width x height.
double MeanDifference(const Image& a, const Image& b, int width, int height) {
  double sum = 0;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      for (int c = 0; c < 3; ++c) sum += std::abs(a.at(x, y, c) - b.at(x, y, c));
    }
  }
  return sum / (3.0 * width * height);
}

// Orbiting and moving the light change the picture (and leave something lit on it).
TEST(ViewerBrowser, OrbitAndLightMoveTheRender) {
  if (!HaveChromium()) GTEST_SKIP() << "chromium is not installed (.ci/install-deps installs it)";
  if (!render::ViewerHasThreeJs()) GTEST_SKIP() << "built without three.js (.ci/install-deps)";
  // Changes well above 8-bit noise: a turned object or light moves highlights across the image.
  constexpr double kMinMeanChange = 0.002;
  testing::ScratchDir dir;
  CliResult r = RunCli("view " + (SmallCapture() / "gt").string() + " --out " +
                           (dir / "view").string() + " --views 1", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string page = "file://" + (dir / "view" / "index.html").string() + "?test=0";
  auto views_text = ReadTextFile(dir / "view" / "views.json");
  ASSERT_TRUE(views_text.ok());
  const Json view = Json::parse(*views_text)["views"][0];
  const int width = view["width"], height = view["height"];
  auto base = Screenshot(page, width, height, dir, "base");
  auto orbit = Screenshot(page + "&yaw=0.8&pitch=0.2", width, height, dir, "orbit");
  auto light = Screenshot(page + "&lightYaw=1.5", width, height, dir, "light");
  ASSERT_TRUE(base.ok() && orbit.ok() && light.ok());
  const Image black(base->width, base->height, 3, 0.0f);
  EXPECT_GT(MeanDifference(*orbit, black, width, height), kMinMeanChange) << "orbit: all black";
  EXPECT_GT(MeanDifference(*light, black, width, height), kMinMeanChange) << "light: all black";
  EXPECT_GT(MeanDifference(*base, *orbit, width, height), kMinMeanChange);
  EXPECT_GT(MeanDifference(*base, *light, width, height), kMinMeanChange);
}

TEST(ViewerCli, BadInputExitsTwoAndWritesNothing) {
  testing::ScratchDir dir;
  const fs::path cap = SmallCapture();
  // A fit whose capture cannot be traced.
  fs::create_directories(dir / "lonely");
  fs::copy_file(cap / "gt" / "params.exr", dir / "lonely" / "params.exr");
  CliResult r = RunCli("view " + (dir / "lonely").string() + " --out " + (dir / "v").string(), dir);
  if (!render::ViewerHasThreeJs()) {
    EXPECT_EQ(r.exit_code, 3) << r.err;
    EXPECT_NE(r.err.find("install-deps"), std::string::npos) << r.err;
    return;
  }
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--capture"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "v"));
  // No params.exr.
  r = RunCli("view " + (dir / "nofit").string() + " --out " + (dir / "v").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("params.exr"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "v"));
  // A normal-map capture has no mesh to show.
  Capture nm;
  nm.json_path = dir / "nm" / "capture.json";
  fs::create_directories(dir / "nm");
  nm.normal_map = NormalMapGeometry{0, "normals.exr", "mask.png"};
  Camera cam;
  cam.id = "c";
  cam.model = CameraModel::kOrthographic;
  cam.width = cam.height = 4;
  cam.pixel_size_m = 0.01;
  nm.cameras.push_back(cam);
  Light light;
  light.id = "L";
  light.type = LightType::kDirectional;
  nm.lights.push_back(light);
  CaptureImage image;
  image.file = "images/0.exr";
  image.split = Split::kHoldout;
  nm.images.push_back(image);
  ASSERT_TRUE(WriteExr(dir / "nm" / "normals.exr", Image(4, 4, 3, 0.5f)).ok());
  ASSERT_TRUE(WritePng(dir / "nm" / "mask.png", Image(4, 4, 1, 1.0f)).ok());
  ASSERT_TRUE(WriteCapture(nm, nm.json_path).ok());
  r = RunCli("view " + (cap / "gt").string() + " --capture " + (dir / "nm").string() +
                 " --out " + (dir / "v").string(), dir);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("normal-map"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "v"));
  // Usage.
  EXPECT_EQ(RunCli("view " + (cap / "gt").string(), dir).exit_code, 1) << "no --out";
  EXPECT_EQ(RunCli("view " + (cap / "gt").string() + " --out x --views 0", dir).exit_code, 1);
  EXPECT_FALSE(fs::exists("x"));
}

}  // namespace
}  // namespace reflcap
