// `reflcap render --backend vulkan` through the executable: the same file set as --backend cpu,
// a render_report.json naming the backend and device, renders that agree with the CPU's by the
// issue's criterion (read back from the written files), and exit 3 for a device that is not there.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <set>
#include <string>

#include "acquire/synth/synth.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "render/reference/reference_renderer.h"
#include "tests/render/vulkan/vulkan_test_util.h"
#include "tests/support/test_support.h"

namespace reflcap::render {
namespace {
namespace fs = std::filesystem;

int RunCli(const std::string& args, const reflcap::testing::ScratchDir& dir, std::string* err) {
  const fs::path err_file = dir / "stderr.txt";
  const std::string command =
      std::string(REFLCAP_BINARY) + " " + args + " >/dev/null 2>" + err_file.string();
  const int status = std::system(command.c_str());
  auto text = ReadTextFile(err_file);
  *err = text.ok() ? *text : "";
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::set<std::string> FilesUnder(const fs::path& root) {
  std::set<std::string> files;
  for (const auto& e : fs::recursive_directory_iterator(root)) {
    if (e.is_regular_file()) files.insert(fs::relative(e.path(), root).generic_string());
  }
  return files;
}

// A render as written by `reflcap render`: pixels, mask and aux read back.
RenderResult ReadRender(const fs::path& dir, const std::string& key) {
  RenderResult r;
  auto pixels = ReadExrRgb(dir / ("images/" + key + ".exr"));
  auto mask = ReadPng(dir / ("masks/" + key + ".png"));
  std::vector<std::string> names;
  auto aux = ReadExrChannels(dir / ("aux/" + key + ".exr"), &names);
  EXPECT_EQ(names, AuxChannelNames());
  EXPECT_TRUE(pixels.ok() && mask.ok() && aux.ok()) << dir << " " << key;
  if (!pixels.ok() || !mask.ok() || !aux.ok()) return r;
  r.pixels = std::move(pixels).value();
  r.mask = Image(mask->width, mask->height, 1, 0.0f);
  for (size_t i = 0; i < r.mask.data.size(); ++i)
    r.mask.data[i] = mask->data[i * mask->channels] > 0.5f;
  r.aux = std::move(aux).value();
  return r;
}

class VulkanCli : public testing::VulkanRendererTest {};

TEST_F(VulkanCli, WritesTheSameFilesAsTheCpuBackendAndAgreesWithIt) {
  reflcap::testing::ScratchDir dir;
  synth::SynthOptions o;
  o.noise = 0;
  o.texels = 3000;
  o.image_size = 64;
  o.cameras = 2;
  o.lights = 2;
  o.steps = 4;
  ASSERT_TRUE(synth::WriteSyntheticCapture(o, dir / "cap").ok());
  const std::string cap = (dir / "cap").string();
  const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
  const std::string device_arg = device ? std::string(" --device '") + device + "'" : "";
  std::string err;
  ASSERT_EQ(RunCli("render --quiet " + cap + " " + cap + "/gt --split all --out " +
                       (dir / "cpu").string(),
                   dir, &err),
            0)
      << err;
  ASSERT_EQ(RunCli("render --quiet " + cap + " " + cap + "/gt --split all --backend vulkan" +
                       device_arg + " --out " + (dir / "vulkan").string(),
                   dir, &err),
            0)
      << err;
  const std::set<std::string> cpu_files = FilesUnder(dir / "cpu"),
                              vulkan_files = FilesUnder(dir / "vulkan");
  EXPECT_EQ(cpu_files, vulkan_files);
  EXPECT_EQ(cpu_files.size(), 3 * 16 + 1u);  // 16 images: render, mask, aux; the report

  auto report = ReadTextFile(dir / "vulkan/render_report.json");
  ASSERT_TRUE(report.ok());
  const nlohmann::json j = nlohmann::json::parse(*report);
  EXPECT_EQ(j["backend"], "vulkan");
  EXPECT_EQ(j["device"], renderer().device().ToString());
  EXPECT_EQ(j["images"].size(), 16u);

  testing::Agreement pooled;
  for (const auto& image : j["images"]) {
    const std::string key = fs::path(image["render"].get<std::string>()).stem().string();
    const RenderResult cpu = ReadRender(dir / "cpu", key), gpu = ReadRender(dir / "vulkan", key);
    const testing::Agreement a = testing::Compare(cpu, gpu);
    EXPECT_GE(a.psnr_db, testing::kMinPsnrDb) << key << ": " << a.ToString();
    pooled.Add(a);
  }
  std::printf("[ vulkan   ] reflcap render --backend vulkan vs cpu (files): %s\n",
              pooled.ToString().c_str());
}

TEST_F(VulkanCli, MissingDeviceExitsThreeAndWritesNothing) {
  reflcap::testing::ScratchDir dir;
  synth::SynthOptions o;
  o.noise = 0;
  o.texels = 1000;
  o.image_size = 32;
  o.cameras = 1;
  o.lights = 1;
  o.steps = 2;
  ASSERT_TRUE(synth::WriteSyntheticCapture(o, dir / "cap").ok());
  const std::string cap = (dir / "cap").string();
  std::string err;
  EXPECT_EQ(RunCli("render " + cap + " " + cap + "/gt --out " + (dir / "r").string() +
                       " --backend vulkan --device no-such-device",
                   dir, &err),
            3);
  EXPECT_NE(err.find("no-such-device"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir / "r"));
  EXPECT_EQ(
      RunCli("render " + cap + " " + cap + "/gt --out " + (dir / "r").string() + " --device 0", dir,
             &err),
      1)
      << "--device without --backend vulkan";
}

}  // namespace
}  // namespace reflcap::render
