// `reflcap export FIT --gltf OUT.glb` through the executable: the GLB's structure, its raw
// parameters against params.exr, the Khronos glTF validator (npm gltf-validator, installed by
// .ci/install-deps), and bad input (exit 2, nothing written).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>

#include <nlohmann/json.hpp>

#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/texel/brdf_maps.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;
using testing::CliResult;
using testing::WriteText;

CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

// A tiny synthetic capture, made once for this file; its gt/ folder is the FIT exported.
const fs::path& TinyCapture() {
  static const testing::ScratchDir* dir = &reflcap::testing::NewProcessScratchDir();
  static const fs::path capture = [] {
    testing::ScratchDir logs;
    const fs::path out = *dir / "tiny";
    CliResult r = RunCli("synth --quiet --out " + out.string() +
                             " --texels 3000 --image-size 48 --cameras 2 --lights 2 --steps 4",
                         logs);
    REFLCAP_CHECK(r.exit_code == 0) << r.err;
    return out;
  }();
  return capture;
}

// The channels `wanted` of an EXR, interleaved in that order (ADD_FAILURE when one is missing).
StatusOr<Image> ReadChannelsInOrder(const fs::path& path, const std::vector<std::string>& wanted) {
  std::vector<std::string> names;
  REFLCAP_ASSIGN_OR_RETURN(Image all, ReadExrChannels(path, &names));
  Image out(all.width, all.height, int(wanted.size()));
  for (size_t w = 0; w < wanted.size(); ++w) {
    const auto it = std::find(names.begin(), names.end(), wanted[w]);
    if (it == names.end()) return NotFoundError(path.string(), ": no channel ", wanted[w]);
    const size_t c = size_t(it - names.begin());
    for (size_t p = 0; p < all.PixelCount(); ++p) {
      out.data[p * wanted.size() + w] = all.data[p * all.channels + c];
    }
  }
  return out;
}

struct Glb {
  Json json;
  std::string bin;
};

// Splits a .glb into its JSON and BIN chunks (ADD_FAILURE on a malformed file).
Glb ReadGlb(const fs::path& path) {
  auto bytes = ReadTextFile(path);
  Glb glb;
  if (!bytes.ok() || bytes->size() < 28) {
    ADD_FAILURE() << path << ": unreadable or short";
    return glb;
  }
  const std::string& b = *bytes;
  auto u32 = [&](size_t offset) {
    uint32_t v;
    std::memcpy(&v, b.data() + offset, 4);
    return v;
  };
  EXPECT_EQ(u32(0), 0x46546C67u) << "magic";
  EXPECT_EQ(u32(4), 2u) << "version";
  EXPECT_EQ(u32(8), b.size()) << "length";
  const uint32_t json_length = u32(12);
  EXPECT_EQ(u32(16), 0x4E4F534Au);
  glb.json = Json::parse(b.substr(20, json_length));
  const size_t bin_at = 20 + json_length;
  EXPECT_EQ(u32(bin_at + 4), 0x004E4942u);
  glb.bin = b.substr(bin_at + 8, u32(bin_at));
  return glb;
}

TEST(ExportCli, WritesAGlbWhoseRawParametersAreTheFit) {
  testing::ScratchDir dir;
  const fs::path cap = TinyCapture();
  const fs::path glb = dir / "tiny.glb";
  CliResult r = RunCli("export " + (cap / "gt").string() + " --gltf " + glb.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("relative RMS error"), std::string::npos) << r.out;
  ASSERT_TRUE(fs::exists(glb));
  ASSERT_TRUE(fs::exists(dir / "tiny.lafortune.exr"));
  const Glb g = ReadGlb(glb);
  const Json& material = g.json["materials"][0];
  ASSERT_TRUE(material["extensions"].contains("REFLCAP_lafortune"));
  const Json& ext = material["extensions"]["REFLCAP_lafortune"];
  const int width = ext["width"], height = ext["height"], lobes = ext["lobes"];
  const std::vector<std::string> channels = ext["channels"];
  EXPECT_EQ(channels, BrdfChannelNames(lobes));
  // The raw parameters equal params.exr bit for bit.
  auto params = ReadChannelsInOrder(cap / "gt" / "params.exr", channels);
  ASSERT_TRUE(params.ok()) << params.status().ToString();
  ASSERT_EQ(params->width, width);
  ASSERT_EQ(params->height, height);
  const Json& accessor = g.json["accessors"][ext["parameters"].get<int>()];
  ASSERT_EQ(accessor["count"].get<size_t>(), params->data.size());
  const Json& view = g.json["bufferViews"][accessor["bufferView"].get<int>()];
  ASSERT_EQ(view["byteLength"].get<size_t>(), 4 * params->data.size());
  EXPECT_EQ(std::memcmp(g.bin.data() + view["byteOffset"].get<size_t>(), params->data.data(),
                        4 * params->data.size()),
            0);
  // The EXR beside it: the same channels plus the approximation error, finite and >= 0.
  std::vector<std::string> with_error = channels;
  with_error.push_back("gltf.error");
  auto exr = ReadChannelsInOrder(dir / "tiny.lafortune.exr", with_error);
  ASSERT_TRUE(exr.ok()) << exr.status().ToString();
  for (size_t p = 0; p < exr->PixelCount(); ++p) {
    const float e = exr->data[p * exr->channels + channels.size()];
    ASSERT_TRUE(std::isfinite(e) && e >= 0) << p;
  }
  // Mesh and textures.
  const Json& prim = g.json["meshes"][0]["primitives"][0];
  for (const char* a : {"POSITION", "NORMAL", "TANGENT", "TEXCOORD_0"}) {
    EXPECT_TRUE(prim["attributes"].contains(a)) << a;
  }
  EXPECT_EQ(g.json["images"].size(), 2u);
  EXPECT_EQ(g.json["asset"]["version"], "2.0");
}

TEST(ExportCli, PassesTheKhronosValidator) {
  const fs::path modules = REFLCAP_NODE_MODULES_DIR;
  if (std::system("node --version > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "node is not installed (.ci/install-deps installs nodejs)";
  }
  if (!fs::exists(modules / "gltf-validator" / "package.json")) {
    GTEST_SKIP() << modules / "gltf-validator" << " is missing (.ci/install-deps runs npm ci)";
  }
  testing::ScratchDir dir;
  const fs::path glb = dir / "v.glb";
  CliResult r = RunCli("export " + (TinyCapture() / "gt").string() + " --gltf " + glb.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const fs::path report = dir / "report.json";
  const std::string command = "node " + std::string(REFLCAP_GLTF_VALIDATE_JS) + " " +
                              modules.string() + " " + glb.string() + " > " + report.string();
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  auto text = ReadTextFile(report);
  ASSERT_TRUE(text.ok());
  const Json issues = Json::parse(*text)["issues"];
  EXPECT_EQ(issues["numErrors"].get<int>(), 0) << issues.dump(1);
  EXPECT_EQ(issues["numWarnings"].get<int>(), 0) << issues.dump(1);
  // The infos expected: the validator does not know REFLCAP_lafortune, so it calls the
  // extension unsupported, its parameter accessor unused and the tangents (which only the
  // extension uses) unused; the atlas need not be a power of two.
  for (const Json& m : issues["messages"]) {
    const std::string code = m["code"];
    EXPECT_TRUE(code == "UNSUPPORTED_EXTENSION" || code == "UNUSED_OBJECT" ||
                code == "UNUSED_MESH_TANGENT" || code == "IMAGE_NPOT_DIMENSIONS")
        << m.dump();
  }
}

// A page that loads a .glb with three.js's GLTFLoader and reports what it got in its title.
// createImageBitmap is hidden so that GLTFLoader decodes the atlas through an <img> (its path on
// Safari): Chromium's --virtual-time-budget waits for resource loads but not for
// createImageBitmap's off-thread decode, and under load (CI, 2 cores) it dumped the page while
// that decode was still running (title "loading": 2 of 25 runs beside 4 busy processes; 0 of 60
// with the <img> path). What is tested, that three.js reads the file's mesh and maps, is the same.
constexpr char kThreeLoadPage[] = R"(<!DOCTYPE html><html><head><title>loading</title>
<script type="importmap">{"imports": {"three": "file://MODULES/three/build/three.module.js"}}</script>
</head><body><script type="module">
import {GLTFLoader} from 'file://MODULES/three/examples/jsm/loaders/GLTFLoader.js';
globalThis.createImageBitmap = undefined;
new GLTFLoader().load('file://GLB', (gltf) => {
  let meshes = 0, triangles = 0, material = null;
  gltf.scene.traverse((o) => {
    if (o.isMesh) { meshes++; triangles += o.geometry.index.count / 3; material = o.material; }
  });
  document.title = 'loaded meshes=' + meshes + ' triangles=' + triangles + ' map=' +
      (material.map ? material.map.image.width : 0) + ' metalnessMap=' +
      (material.metalnessMap ? 1 : 0);
}, undefined, (e) => { document.title = 'error ' + e; });
</script></body></html>
)";

std::string ReplaceAll(std::string text, const std::string& from, const std::string& to) {
  for (size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size())) {
    text.replace(at, from.size(), to);
  }
  return text;
}

TEST(ExportCli, LoadsInThreeJs) {
  const fs::path modules = REFLCAP_NODE_MODULES_DIR;
  if (std::system("command -v chromium > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "chromium is not installed (.ci/install-deps installs it)";
  }
  if (!fs::exists(modules / "three" / "examples" / "jsm" / "loaders" / "GLTFLoader.js")) {
    GTEST_SKIP() << modules / "three" << " is missing (.ci/install-deps runs npm ci)";
  }
  testing::ScratchDir dir;
  const fs::path glb = dir / "t.glb";
  CliResult r = RunCli("export " + (TinyCapture() / "gt").string() + " --gltf " + glb.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  WriteText(dir / "load.html", ReplaceAll(ReplaceAll(kThreeLoadPage, "MODULES", modules.string()),
                                          "GLB", glb.string()));
  const fs::path dom = dir / "dom.html";
  const std::string command =
      "chromium --headless=new --no-sandbox --allow-file-access-from-files "
      "--use-angle=swiftshader --enable-unsafe-swiftshader --user-data-dir=" +
      (dir / "profile").string() + " --virtual-time-budget=20000 --dump-dom 'file://" +
      (dir / "load.html").string() + "' > " + dom.string() + " 2> /dev/null";
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  auto text = ReadTextFile(dom);
  ASSERT_TRUE(text.ok());
  const Glb g = ReadGlb(glb);
  const std::string expected = "<title>loaded meshes=1 triangles=" +
                               std::to_string(g.json["accessors"][g.json["meshes"][0]["primitives"]
                                                          [0]["indices"].get<int>()]["count"]
                                                  .get<size_t>() / 3) +
                               " map=" + std::to_string(g.json["materials"][0]["extensions"]
                                                            ["REFLCAP_lafortune"]["width"]
                                                                .get<int>()) +
                               " metalnessMap=1</title>";
  EXPECT_NE(text->find(expected), std::string::npos)
      << "expected " << expected << " in\n" << text->substr(0, 2000);
}

TEST(ExportCli, BadInputExitsTwoAndWritesNothing) {
  testing::ScratchDir dir;
  const fs::path cap = TinyCapture();
  const std::string fit = (cap / "gt").string();
  auto nothing_written = [&](const std::string& name) {
    EXPECT_FALSE(fs::exists(dir / (name + ".glb")));
    EXPECT_FALSE(fs::exists(dir / (name + ".lafortune.exr")));
    for (const auto& entry : fs::directory_iterator(dir.path())) {
      EXPECT_EQ(entry.path().filename().string().rfind(".", 0), std::string::npos)
          << "temporary left behind: " << entry.path();
    }
  };
  // Textures too large for the limit: exit 2 naming params.exr.
  CliResult r = RunCli("export " + fit + " --gltf " + (dir / "big.glb").string() +
                           " --max-texture-size 16", dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("params.exr"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("texture limit"), std::string::npos) << r.err;
  nothing_written("big");
  // No params.exr.
  r = RunCli("export " + (dir / "nofit").string() + " --gltf " + (dir / "a.glb").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("params.exr"), std::string::npos) << r.err;
  nothing_written("a");
  // A fit whose capture cannot be found: asks for --capture.
  fs::create_directories(dir / "lonely");
  fs::copy_file(cap / "gt" / "params.exr", dir / "lonely" / "params.exr");
  r = RunCli("export " + (dir / "lonely").string() + " --gltf " + (dir / "b.glb").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--capture"), std::string::npos) << r.err;
  nothing_written("b");
  // ... and with --capture it works.
  r = RunCli("export " + (dir / "lonely").string() + " --capture " + cap.string() + " --gltf " +
                 (dir / "b.glb").string() + " --no-exr", dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "b.glb"));
  EXPECT_FALSE(fs::exists(dir / "b.lafortune.exr"));
  // An existing output is not replaced without --overwrite.
  const auto size = fs::file_size(dir / "b.glb");
  r = RunCli("export " + fit + " --gltf " + (dir / "b.glb").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--overwrite"), std::string::npos) << r.err;
  EXPECT_EQ(fs::file_size(dir / "b.glb"), size);
  // A normal-map capture has no mesh.
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
  light.direction = Vec3d(0, 0, 1);
  light.intensity = Vec3d(1, 1, 1);
  nm.lights.push_back(light);
  CaptureImage image;
  image.file = "images/0.exr";
  image.exposure_s = 1;
  nm.images.push_back(image);
  ASSERT_TRUE(WriteExr(dir / "nm" / "normals.exr", Image(4, 4, 3, 0.5f)).ok());
  ASSERT_TRUE(WritePng(dir / "nm" / "mask.png", Image(4, 4, 1, 1.0f)).ok());
  const Status written = WriteCapture(nm, nm.json_path);
  ASSERT_TRUE(written.ok()) << written.ToString();
  r = RunCli("export " + fit + " --capture " + (dir / "nm").string() + " --gltf " +
                 (dir / "c.glb").string(), dir);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("normal-map"), std::string::npos) << r.err;
  nothing_written("c");
  // Usage errors.
  EXPECT_EQ(RunCli("export " + fit, dir).exit_code, 1) << "no --gltf";
  EXPECT_EQ(RunCli("export " + fit + " --gltf x.gltf", dir).exit_code, 1) << "not .glb";
}

}  // namespace
}  // namespace reflcap
