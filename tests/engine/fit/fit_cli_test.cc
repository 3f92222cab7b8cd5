// `reflcap fit` end to end: a small sample store written with the store API from synthetic
// ground truth → the executable → FIT/params.exr, sigma.exr, status.exr, fit_report.json; its
// exit codes for usage errors (1), bad input (2) and the unavailable Vulkan backend (3, on a
// machine without a Vulkan driver, which the test makes by pointing the loader nowhere); and,
// in builds with Vulkan, `--backend vulkan` against the CPU backend on the same store.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/fit/fitter.h"
#include "engine/fit/synthetic_samples.h"
#include "engine/image/exr_io.h"
#include "engine/texel/brdf_maps.h"
#include "engine/texel/sample_store.h"
#include "tests/support/test_support.h"

namespace reflcap::fit {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

constexpr int kAtlasSize = 20;      // 20 x 20 atlas
constexpr uint32_t kTexels = 300;   // texel t at pixel 1 + t (pixel 0 and the tail hold none)
constexpr uint32_t kChunkTexels = 128;

struct CliResult {
  int exit_code = -1;
  std::string out, err;
};

// Environment prefix under which the Vulkan loader finds no driver (no ICD): a machine without
// any Vulkan device, as tests/engine/gpu/context_test.cc makes it.
constexpr const char* kNoVulkan =
    "VK_DRIVER_FILES=/nonexistent/reflcap_no_icd.json VK_ICD_FILENAMES=/nonexistent/reflcap_no_icd.json ";

CliResult RunCli(const std::string& args, const reflcap::testing::ScratchDir& dir,
                 const std::string& env = "") {
  const fs::path out = dir / "stdout.txt", err = dir / "stderr.txt";
  const std::string command = env + std::string(REFLCAP_BINARY) + " " + args + " >" +
                              out.string() + " 2>" + err.string();
  const int status = std::system(command.c_str());
  CliResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ReadTextFile(out).value();
  r.err = ReadTextFile(err).value();
  return r;
}

// Writes a store of kTexels synth-material texels in chunks of kChunkTexels.
std::vector<brdf::BrdfParams> WriteStore(const fs::path& dir) {
  fs::create_directories(dir);
  const std::vector<brdf::BrdfParams> truth = SynthMaterialTexels(kTexels, 5);
  SampleStoreInfo info;
  info.texels = kTexels;
  info.chunk_texels = kChunkTexels;
  info.chunks = (kTexels + kChunkTexels - 1) / kChunkTexels;
  info.atlas_width = info.atlas_height = kAtlasSize;
  for (uint32_t t = 0; t < kTexels; ++t) info.pixel_of_texel.push_back(1 + t);
  info.capture = "synthetic";
  info.split = "train";
  info.geometry = "mesh";
  SyntheticSampleOptions so;
  so.seed = 5;
  for (uint32_t c = 0; c < info.chunks; ++c) {
    const uint32_t first = c * kChunkTexels, count = std::min(kChunkTexels, kTexels - first);
    const std::vector<brdf::BrdfParams> part(truth.begin() + first, truth.begin() + first + count);
    const TexelSampleChunk chunk = MakeSyntheticChunk(part, so, first);
    info.samples += chunk.samples.size();
    REFLCAP_CHECK(WriteSampleChunk(dir / SampleChunkFileName(c), chunk).ok());
  }
  REFLCAP_CHECK(WriteSampleStoreInfo(dir, info).ok());
  return truth;
}

TEST(FitCli, FitsAStoreAndWritesEveryOutput) {
  reflcap::testing::ScratchDir dir;
  const std::vector<brdf::BrdfParams> truth = WriteStore(dir / "samples");
  const fs::path out = dir / "fit";
  const CliResult r = RunCli("fit " + (dir / "samples").string() + " --out " + out.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("converged"), std::string::npos) << r.out;

  TexelAtlas atlas;
  atlas.width = atlas.height = kAtlasSize;
  for (uint32_t t = 0; t < kTexels; ++t) atlas.pixel_of_texel.push_back(1 + t);
  auto params = ReadBrdfMaps(out / "params.exr", atlas);
  ASSERT_TRUE(params.ok()) << params.status().ToString();
  EXPECT_EQ(params->num_lobes, 1);
  // Texel 1 is the glossy material: fitted to the accuracy.
  EXPECT_NEAR(params->texels[1].rho_d[2], truth[1].rho_d[2], 0.01 * truth[1].rho_d[2]);
  EXPECT_NEAR(params->texels[1].lobes[0][0].n, truth[1].lobes[0][0].n, 0.05 * truth[1].lobes[0][0].n);
  auto sigma = ReadBrdfMaps(out / "sigma.exr", atlas);
  ASSERT_TRUE(sigma.ok()) << sigma.status().ToString();
  EXPECT_GT(sigma->texels[1].rho_d[0], 0.0f);

  std::vector<std::string> names;
  auto status = ReadExrChannels(out / "status.exr", &names);
  ASSERT_TRUE(status.ok()) << status.status().ToString();
  EXPECT_EQ(names, (std::vector<std::string>{"albedo_filled", "cost", "iterations", "lobe_donor",
                                             "material_cluster", "model", "status"}));
  const int status_channel = 6;
  EXPECT_EQ(status->at(1, 0, 0), 0.0f);  // albedo_filled: texel 1 has samples
  EXPECT_EQ(status->at(0, 0, status_channel), -1.0f);  // pixel 0 holds no texel
  EXPECT_EQ(status->at(1, 0, status_channel), float(int(FitStatus::kConverged)));

  auto text = ReadTextFile(out / "fit_report.json");
  ASSERT_TRUE(text.ok());
  const Json report = Json::parse(*text);
  // --backend auto: the CPU on a machine whose only Vulkan device is lavapipe (or none), a GPU
  // otherwise; the report says which and why.
  EXPECT_TRUE(report["backend"] == "cpu" || report["backend"] == "vulkan") << report["backend"];
  EXPECT_NE(report["backend_choice"].get<std::string>().find("auto"), std::string::npos);
  EXPECT_EQ(report["texels"], kTexels);
  EXPECT_EQ(report["status_counts"]["converged"], kTexels);
  EXPECT_GT(report["fits_per_second"].get<double>(), 0);
  EXPECT_EQ(report["options"]["albedo_fill"]["enabled"], true);
  EXPECT_EQ(report["albedo_fill"]["unseen"], 0);  // every texel has samples
  // The diffuse fall-off pass runs by default and reports its counts and its model.
  EXPECT_EQ(report["options"]["diffuse_falloff"], true);
  EXPECT_TRUE(report["diffuse_falloff"].contains("candidates"));
  EXPECT_TRUE(report["model_counts"].contains("falloff_lobe"));
  for (const char* key : {"device", "cost_percentiles", "timings_s", "options", "iterations"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }

  // An existing non-empty FIT is refused (bad input), replaced with --overwrite.
  EXPECT_EQ(RunCli("fit " + (dir / "samples").string() + " --out " + out.string(), dir).exit_code, 2);
  EXPECT_EQ(RunCli("fit " + (dir / "samples").string() + " --out " + out.string() +
                       " --overwrite --backend ceres --lobe-model shared --loss cauchy"
                       " --no-albedo-fill --no-diffuse-falloff --quiet",
                   dir).exit_code, 0);
  const Json ceres = Json::parse(ReadTextFile(out / "fit_report.json").value());
  EXPECT_EQ(ceres["backend"], "ceres");
  EXPECT_EQ(ceres["options"]["lobe_model"], "shared");
  EXPECT_EQ(ceres["options"]["albedo_fill"]["enabled"], false);
  EXPECT_EQ(ceres["options"]["diffuse_falloff"], false);
  EXPECT_EQ(ceres["diffuse_falloff"]["candidates"], 0);
  EXPECT_EQ(ceres["model_counts"]["falloff_lobe"], 0);
}

// --lobe-model auto: each texel keeps the anisotropic or the isotropic fit, the better by BIC.
TEST(FitCli, AutoLobeModelPicksPerTexelByBic) {
  reflcap::testing::ScratchDir dir;
  const std::vector<brdf::BrdfParams> truth = WriteStore(dir / "samples");
  const fs::path out = dir / "fit";
  CliResult r = RunCli("fit " + (dir / "samples").string() + " --out " + out.string() +
                           " --backend cpu --lobe-model auto --quiet",
                       dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json report = Json::parse(ReadTextFile(out / "fit_report.json").value());
  EXPECT_EQ(report["options"]["lobe_model"], "auto");
  const size_t aniso = report["lobe_model_choice"]["aniso"], iso = report["lobe_model_choice"]["iso"];
  EXPECT_EQ(aniso + iso, size_t(kTexels));
  TexelAtlas atlas;
  atlas.width = atlas.height = kAtlasSize;
  for (uint32_t t = 0; t < kTexels; ++t) atlas.pixel_of_texel.push_back(1 + t);
  auto params = ReadBrdfMaps(out / "params.exr", atlas);
  ASSERT_TRUE(params.ok()) << params.status().ToString();
  // Texels whose truth is isotropic (Cx = Cy) and that have a lobe: how many kept the isotropic
  // fit (its Cx and Cy equal to float rounding). The synth materials' anisotropy is mild (0.985),
  // so both models fit the isotropic ones to the noise and BIC prefers the 3 fewer parameters.
  size_t isotropic_truth = 0, kept_isotropic = 0;
  for (uint32_t t = 0; t < kTexels; ++t) {
    const brdf::LobeParams& lobe = truth[t].lobes[0][0];
    if (truth[t].num_lobes == 0 || lobe.cx != lobe.cy || lobe.cz == 0) continue;
    ++isotropic_truth;
    const brdf::LobeParams& fitted = params->texels[t].lobes[0][0];
    kept_isotropic += fitted.cz != 0 && fitted.cx == fitted.cy;
  }
  std::printf("auto: %zu aniso, %zu iso; isotropic truth %zu, fitted isotropic %zu\n", aniso, iso,
              isotropic_truth, kept_isotropic);
  EXPECT_GT(isotropic_truth, 0u);
  EXPECT_GT(kept_isotropic, isotropic_truth / 2);
}

TEST(FitCli, ExitCodes) {
  reflcap::testing::ScratchDir dir;
  WriteStore(dir / "samples");
  const std::string samples = (dir / "samples").string();
  EXPECT_EQ(RunCli("fit --help", dir).exit_code, 0);
  EXPECT_EQ(RunCli("fit", dir).exit_code, 1);                                   // no SAMPLES
  EXPECT_EQ(RunCli("fit " + samples, dir).exit_code, 1);                        // no --out
  EXPECT_EQ(RunCli("fit " + samples + " --out x --lobes 9", dir).exit_code, 1);
  EXPECT_EQ(RunCli("fit " + samples + " --out x --loss square", dir).exit_code, 1);
  EXPECT_EQ(RunCli("fit " + samples + " --out x --lobe-model shared --lobes 3", dir).exit_code, 1);
  const CliResult missing = RunCli("fit " + (dir / "nothing").string() + " --out " + (dir / "o").string(), dir);
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_NE(missing.err.find("store.json"), std::string::npos) << missing.err;
  // Without any Vulkan driver: --backend vulkan is unavailable (3) with a message naming Vulkan,
  // and auto falls back to the CPU with a warning.
  const CliResult vulkan =
      RunCli("fit " + samples + " --out " + (dir / "v").string() + " --backend vulkan", dir, kNoVulkan);
  EXPECT_EQ(vulkan.exit_code, 3) << vulkan.err;
  EXPECT_NE(vulkan.err.find("Vulkan"), std::string::npos) << vulkan.err;
  EXPECT_FALSE(fs::exists(dir / "v"));
  const CliResult fallback =
      RunCli("fit " + samples + " --out " + (dir / "a").string() + " --backend auto", dir, kNoVulkan);
  EXPECT_EQ(fallback.exit_code, 0) << fallback.err;
  EXPECT_NE(fallback.err.find("fitting on the CPU"), std::string::npos) << fallback.err;
  EXPECT_EQ(Json::parse(ReadTextFile(dir / "a" / "fit_report.json").value())["backend"], "cpu");
  EXPECT_EQ(RunCli("fit " + samples + " --out x --backend gpu", dir).exit_code, 1);
  EXPECT_EQ(RunCli("fit " + samples + " --out x --backend cpu --device 0", dir).exit_code, 1);
  // A corrupted chunk is bad input, and nothing is left behind.
  {
    std::FILE* f = std::fopen((dir / "samples" / SampleChunkFileName(1)).c_str(), "r+b");
    ASSERT_NE(f, nullptr);
    std::fseek(f, 200, SEEK_SET);
    std::fputc(0x5a, f);
    std::fclose(f);
  }
  const CliResult corrupt = RunCli("fit " + samples + " --out " + (dir / "c").string(), dir);
  EXPECT_EQ(corrupt.exit_code, 2) << corrupt.err;
  EXPECT_FALSE(fs::exists(dir / "c"));
}

#ifdef REFLCAP_HAVE_VULKAN_FITTER
// --backend vulkan on the machine's Vulkan device (lavapipe in CI): the same outputs as the CPU
// backend, the device's name in the report.
TEST(FitCli, VulkanBackendMatchesTheCpuBackend) {
  reflcap::testing::ScratchDir dir;
  const std::vector<brdf::BrdfParams> truth = WriteStore(dir / "samples");
  const std::string samples = (dir / "samples").string();
  const CliResult cpu = RunCli("fit " + samples + " --out " + (dir / "cpu").string() + " --backend cpu", dir);
  ASSERT_EQ(cpu.exit_code, 0) << cpu.err;
  const CliResult gpu = RunCli("fit " + samples + " --out " + (dir / "gpu").string() + " --backend vulkan", dir);
  if (gpu.exit_code == 3 && gpu.err.find("no Vulkan driver") != std::string::npos) {
    GTEST_SKIP() << "no Vulkan driver or device on this machine: " << gpu.err;
  }
  ASSERT_EQ(gpu.exit_code, 0) << gpu.err;
  EXPECT_NE(gpu.out.find("vulkan"), std::string::npos) << gpu.out;
  const Json cpu_report = Json::parse(ReadTextFile(dir / "cpu" / "fit_report.json").value());
  const Json gpu_report = Json::parse(ReadTextFile(dir / "gpu" / "fit_report.json").value());
  EXPECT_EQ(gpu_report["backend"], "vulkan");
  EXPECT_FALSE(gpu_report["device"].get<std::string>().empty());
  EXPECT_EQ(gpu_report["status_counts"], cpu_report["status_counts"]);
  EXPECT_EQ(gpu_report["texels"], kTexels);

  TexelAtlas atlas;
  atlas.width = atlas.height = kAtlasSize;
  for (uint32_t t = 0; t < kTexels; ++t) atlas.pixel_of_texel.push_back(1 + t);
  auto cpu_params = ReadBrdfMaps(dir / "cpu" / "params.exr", atlas);
  auto gpu_params = ReadBrdfMaps(dir / "gpu" / "params.exr", atlas);
  ASSERT_TRUE(cpu_params.ok() && gpu_params.ok());
  // Every texel of this store is converged and well determined: the 1e-3 bar.
  for (uint32_t t = 0; t < kTexels; ++t) {
    const brdf::BrdfParams &a = cpu_params->texels[t], &b = gpu_params->texels[t];
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(b.rho_d[c], a.rho_d[c], 1e-3 * std::abs(a.rho_d[c]) + 1e-7) << t;
      if (truth[t].num_lobes > 0 && a.lobes[0][c].n > 0) {
        EXPECT_NEAR(b.lobes[0][c].n, a.lobes[0][c].n, 1e-3 * a.lobes[0][c].n) << t;
      }
    }
  }
  // A device that does not exist is refused, naming it.
  const CliResult missing = RunCli("fit " + samples + " --out " + (dir / "m").string() +
                                       " --backend vulkan --device no-such-gpu", dir);
  EXPECT_NE(missing.exit_code, 0);
  EXPECT_NE(missing.err.find("no-such-gpu"), std::string::npos) << missing.err;
}

// --vulkan-chunks-in-flight 2 fits two of the store's three chunks at once, each on its own
// fitter (auto on a GPU; lavapipe's default is 1): the maps are the same bytes as one chunk
// after another, with the per-texel model choice too (two fits of every chunk).
TEST(FitCli, TwoChunksInFlightWriteTheSameMaps) {
  reflcap::testing::ScratchDir dir;
  WriteStore(dir / "samples");
  const std::string samples = (dir / "samples").string();
  for (const std::string model : {"aniso", "auto"}) {
    std::string outs[2];
    for (int depth = 1; depth <= 2; ++depth) {
      outs[depth - 1] = (dir / (model + std::to_string(depth))).string();
      const CliResult r = RunCli("fit " + samples + " --out " + outs[depth - 1] +
                                     " --backend vulkan --lobe-model " + model +
                                     " --vulkan-chunks-in-flight " + std::to_string(depth),
                                 dir);
      if (r.exit_code == 3 && r.err.find("no Vulkan driver") != std::string::npos) {
        GTEST_SKIP() << "no Vulkan driver or device on this machine: " << r.err;
      }
      ASSERT_EQ(r.exit_code, 0) << r.err;
    }
    for (const char* map : {"params.exr", "sigma.exr", "status.exr"}) {
      const auto a = ReadTextFile(fs::path(outs[0]) / map), b = ReadTextFile(fs::path(outs[1]) / map);
      ASSERT_TRUE(a.ok() && b.ok()) << map;
      EXPECT_TRUE(*a == *b) << model << ": " << map << " differs between 1 and 2 chunks in flight";
    }
    const Json one = Json::parse(ReadTextFile(fs::path(outs[0]) / "fit_report.json").value());
    const Json two = Json::parse(ReadTextFile(fs::path(outs[1]) / "fit_report.json").value());
    EXPECT_EQ(one["status_counts"], two["status_counts"]);
    EXPECT_EQ(one["vulkan"]["device_problems"], two["vulkan"]["device_problems"]);
    EXPECT_EQ(one["vulkan"]["chunks_in_flight"], 1);
    EXPECT_EQ(two["vulkan"]["chunks_in_flight"], 2);
    if (model == "auto") {
      EXPECT_EQ(one["lobe_model_choice"], two["lobe_model_choice"]);
    }
  }
  // Only 0, 1 or 2: a usage error otherwise.
  const CliResult bad = RunCli("fit " + samples + " --out " + (dir / "bad").string() +
                                   " --backend vulkan --vulkan-chunks-in-flight 3", dir);
  EXPECT_EQ(bad.exit_code, 1) << bad.err;
  EXPECT_NE(bad.err.find("--vulkan-chunks-in-flight"), std::string::npos) << bad.err;
  EXPECT_FALSE(fs::exists(dir / "bad"));
}
#endif  // REFLCAP_HAVE_VULKAN_FITTER

}  // namespace
}  // namespace reflcap::fit
