// Re-rendering synthetic captures from their ground truth, and validating those renders: the
// renders reproduce the noise-free photographs, and on noisy photographs validate's PSNR sits at
// the bound that the capture's noise model allows (the issue's "within 0.5 dB" check, done with the
// ground-truth parameters in place of a fit).
#include "render/validate/validate.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <nlohmann/json.hpp>

#include "acquire/synth/synth.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "engine/image/png_io.h"
#include "render/reference/render_capture.h"
#include "render/validate/figures.h"
#include "tests/support/test_support.h"

namespace reflcap::validate {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

// The render uses synth's renderer, atlas and parameters (float EXR: exact), but the mesh comes back
// from mesh.obj, whose loader re-normalises the corner normals (in double): a normal may move by an
// ulp (6e-8). A lobe b^n turns a relative change db/b of its base into n db/b of its value, and the
// sharpest synthetic material has n = 250: up to ~3e-5 relative. Most values are bit-identical.
constexpr double kReproductionRelTolerance = 1e-4;
// Values below this are compared in absolute terms (relative error of a near-black value is noise).
constexpr double kReproductionAbsFloor = 1e-3;
// The issue's bar: holdout PSNR within 0.5 dB of the PSNR that the capture's noise allows.
constexpr double kNoiseBoundToleranceDb = 0.5;

StatusOr<synth::SynthSummary> Synth(const fs::path& out, double noise, int image_size, int lights) {
  synth::SynthOptions o;
  o.noise = noise;
  o.texels = 4000;
  o.image_size = image_size;
  o.cameras = 2;
  o.lights = lights;
  o.steps = 4;
  return synth::WriteSyntheticCapture(o, out);
}

TEST(RenderCapture, GroundTruthReproducesNoiseFreePhotographs) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.0, 48, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  render::CaptureRenderOptions options;
  options.split = render::SplitSelection::kAll;
  auto summary = render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary->images, capture->images.size());
  double max_abs = 0, max_rel = 0;
  size_t compared = 0, identical = 0;
  for (const CaptureImage& image : capture->images) {
    auto photo = ReadExrRgb(capture->Resolve(image.file));
    auto rendered = ReadExrRgb(dir / "renders" / render::RenderPathFor(image.file));
    ASSERT_TRUE(photo.ok() && rendered.ok());
    ASSERT_EQ(photo->data.size(), rendered->data.size());
    for (size_t i = 0; i < photo->data.size(); ++i) {
      const double d = std::abs(double(photo->data[i]) - rendered->data[i]);
      max_abs = std::max(max_abs, d);
      max_rel = std::max(max_rel, d / std::max(kReproductionAbsFloor, double(std::abs(photo->data[i]))));
      ++compared;
      identical += d == 0;
    }
    ASSERT_TRUE(fs::is_regular_file(dir / "renders" / render::MaskPathFor(image.file)));
    std::vector<std::string> names;
    auto aux = ReadExrChannels(dir / "renders" / render::AuxPathFor(image.file), &names);
    ASSERT_TRUE(aux.ok());
    EXPECT_EQ(names, render::AuxChannelNames());
  }
  std::printf("render from gt/params.exr vs noise-free synth photographs: %zu values, %.4f %% "
              "bit-identical, max |diff| %.3g, max relative %.3g\n", compared,
              100.0 * double(identical) / double(compared), max_abs, max_rel);
  EXPECT_LE(max_rel, kReproductionRelTolerance);
  // The render report names the backend and every image.
  const Json report = Json::parse(ReadTextFile(dir / "renders/render_report.json").value());
  EXPECT_EQ(report["backend"], "cpu");
  EXPECT_EQ(report["device"], "cpu");
  EXPECT_EQ(report["images"].size(), capture->images.size());
  EXPECT_EQ(report["geometry"], "mesh");
}

TEST(Validate, HoldoutPsnrFromGroundTruthMeetsTheNoiseBound) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.02, 96, 3).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  ASSERT_TRUE(render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", {}).ok());
  ValidateOptions options;
  options.max_figures = 4;
  auto summary = RunValidation(*capture, dir / "renders", dir / "report", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  ASSERT_TRUE(summary->psnr_db && summary->noise_bound_psnr_db);
  std::printf("holdout (%zu images, %zu pixels, noise 0.02): PSNR %.3f dB, noise bound %.3f dB, "
              "difference %+.3f dB\n", summary->images, summary->pixels, *summary->psnr_db,
              *summary->noise_bound_psnr_db, *summary->psnr_db - *summary->noise_bound_psnr_db);
  EXPECT_NEAR(*summary->psnr_db, *summary->noise_bound_psnr_db, kNoiseBoundToleranceDb);
  EXPECT_EQ(summary->images, capture->CountSplit(Split::kHoldout));
  EXPECT_EQ(summary->figures, 4u);

  const std::string text = ReadTextFile(dir / "report/metrics.json").value();
  EXPECT_EQ(text.find("Infinity"), std::string::npos);
  EXPECT_EQ(text.find("NaN"), std::string::npos);
  const Json metrics = Json::parse(text);
  for (const char* key : {"images", "overall", "capture", "renders", "split", "timings"}) {
    EXPECT_TRUE(metrics.contains(key)) << key;
  }
  EXPECT_EQ(metrics["split"], "holdout");
  const Json& overall = metrics["overall"];
  for (const char* key : {"psnr_db", "rel_rmse", "ssim", "scaled", "regions", "noise_bound_psnr_db"}) {
    EXPECT_TRUE(overall.contains(key)) << key;
  }
  for (const char* region : {"shadow_edge", "high_curvature", "grazing", "elsewhere"}) {
    ASSERT_TRUE(overall["regions"].contains(region)) << region;
    EXPECT_GT(overall["regions"][region]["pixels"].get<int>(), 0) << region;
  }
  const Json& first = metrics["images"][0];
  for (const char* key : {"file", "camera", "light", "turntable_deg", "psnr_db", "rel_rmse", "ssim",
                          "scaled", "regions", "noise_bound_psnr_db"}) {
    EXPECT_TRUE(first.contains(key)) << key;
  }
  // PSNR-L, its scaled variant and the worst-pixel shares, overall and per image: finite and in
  // range (noise only: the scale is ~1, so scaled PSNR-L is within a few tenths of a dB of raw).
  for (const Json* j : {&overall, &first}) {
    ASSERT_TRUE((*j)["psnr_l_db"].is_number());
    ASSERT_TRUE((*j)["scaled"]["psnr_l_db"].is_number());
    EXPECT_GT((*j)["psnr_l_db"].get<double>(), 20);
    EXPECT_LT((*j)["psnr_l_db"].get<double>(), kMaxPsnrDb);
    EXPECT_NEAR((*j)["scaled"]["psnr_l_db"].get<double>(), (*j)["psnr_l_db"].get<double>(), 0.5);
    const double s01 = (*j)["worst_0_1pct_error_share"].get<double>();
    const double s1 = (*j)["worst_1pct_error_share"].get<double>();
    EXPECT_GE(s01, 0.001);  // the worst pixels carry at least their share of pixels
    EXPECT_LE(s01, s1);
    EXPECT_LE(s1, 1.0);
  }
  EXPECT_TRUE(first["psnr_l_white"].get<double>() > 0);
  EXPECT_TRUE(overall["per_image_mean"]["psnr_l_db"].is_number());
  EXPECT_TRUE(overall["regions"]["elsewhere"]["psnr_l_db"].is_number());
  // The worst-pixels table: kWorstPixelsListed entries, worst first, each naming a holdout image.
  const Json& worst = overall["worst_pixels"];
  ASSERT_EQ(worst.size(), size_t(kWorstPixelsListed));
  for (size_t k = 0; k < worst.size(); ++k) {
    EXPECT_EQ(worst[k]["photo"].size(), 3u);
    EXPECT_EQ(worst[k]["render"].size(), 3u);
    EXPECT_TRUE(worst[k]["regions"].is_array());
    if (k > 0) {
      EXPECT_LE(worst[k]["error_share"].get<double>(), worst[k - 1]["error_share"].get<double>());
    }
  }
  double listed_share = 0;
  for (const Json& w : worst) listed_share += w["error_share"].get<double>();
  EXPECT_LE(listed_share, overall["worst_1pct_error_share"].get<double>() + 1e-12);
  // Every image scores near its own bound too (fewer pixels: looser, 1 dB).
  for (const Json& image : metrics["images"]) {
    EXPECT_NEAR(image["psnr_db"].get<double>(), image["noise_bound_psnr_db"].get<double>(), 1.0)
        << image["file"];
  }
  int figures = 0;
  for (const auto& e : fs::directory_iterator(dir / "report/figures")) {
    figures += e.path().filename().string().find("_regions") == std::string::npos;
  }
  EXPECT_EQ(figures, 4);
  const std::string html = ReadTextFile(dir / "report/report.html").value();
  EXPECT_NE(html.find("<img src=\"figures/"), std::string::npos);
  EXPECT_NE(html.find("Where the error is"), std::string::npos);
  EXPECT_NE(html.find("<h2>Worst pixels</h2>"), std::string::npos);
  EXPECT_NE(html.find("PSNR-L (dB)"), std::string::npos);
  EXPECT_EQ(html.find("</html>") + 8, html.size());
}

TEST(Validate, ExactRendersReportTheFiniteCapAndMissingFitFilesAreSkipped) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.0, 32, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  ASSERT_TRUE(render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", {}).ok());
  // Renders replaced by the photographs themselves: an exact match.
  for (const CaptureImage& image : capture->images) {
    if (image.split != Split::kHoldout) continue;
    fs::copy_file(capture->Resolve(image.file), dir / "renders" / render::RenderPathFor(image.file),
                  fs::copy_options::overwrite_existing);
  }
  ValidateOptions options;
  options.fit_dir = dir / "no_fit";
  options.samples_dir = dir / "no_samples";
  auto summary = RunValidation(*capture, dir / "renders", dir / "report", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(*summary->psnr_db, kMaxPsnrDb);
  EXPECT_EQ(*summary->rel_rmse, 0.0);
  EXPECT_DOUBLE_EQ(*summary->ssim, 1.0);
  const std::string text = ReadTextFile(dir / "report/metrics.json").value();
  EXPECT_EQ(Json::parse(text)["overall"]["psnr_db"].get<double>(), kMaxPsnrDb);
  EXPECT_EQ(text.find("Infinity"), std::string::npos);
  // PSNR-L caps too; no error at all leaves no worst pixel and no share (0 / 0 is null).
  EXPECT_EQ(*summary->psnr_l_db, kMaxPsnrDb);
  EXPECT_EQ(*summary->scaled_psnr_l_db, kMaxPsnrDb);
  EXPECT_FALSE(summary->worst_0_1pct_error_share.has_value());
  const Json exact = Json::parse(text)["overall"];
  EXPECT_TRUE(exact["worst_0_1pct_error_share"].is_null());
  EXPECT_TRUE(exact["worst_1pct_error_share"].is_null());
  EXPECT_TRUE(exact["worst_pixels"].empty());
  const std::string html = ReadTextFile(dir / "report/report.html").value();
  EXPECT_NE(html.find("fit_report.json is absent"), std::string::npos);
  EXPECT_NE(html.find("coverage.png is absent"), std::string::npos);
  // A missing render is NotFound, naming the file.
  size_t holdout = 0;
  while (capture->images[holdout].split != Split::kHoldout) ++holdout;
  const std::string missing_file = render::RenderPathFor(capture->images[holdout].file);
  fs::remove(dir / "renders" / missing_file);
  auto missing = RunValidation(*capture, dir / "renders", dir / "report2", {});
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find(missing_file), std::string::npos) << missing.status().message();
}

TEST(Validate, ReportGathersTheFitStatusMapAndTheCoverageMap) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.01, 32, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  ASSERT_TRUE(render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", {}).ok());
  // A fit folder as the fitter may write it: a summary with status names, and a status map with
  // one code per texel (-1 where there is none).
  testing::WriteText(dir / "fit/fit_report.json",
                     R"({"texels": 100, "status_names": ["converged", "max_iterations"],
                         "timings": {"total_s": 1.5}})");
  Image status(20, 10, 1, -1.0f);
  for (int x = 0; x < 10; ++x) status.at(x, 5) = float(x % 2);
  ASSERT_TRUE(WriteExr(dir / "fit/status.exr", status).ok());
  fs::create_directories(dir / "samples");
  ASSERT_TRUE(WritePng(dir / "samples/coverage.png", Image(8, 8, 3, 0.5f)).ok());
  ValidateOptions options;
  options.fit_dir = dir / "fit";
  options.samples_dir = dir / "samples";
  options.max_figures = 0;
  auto summary = RunValidation(*capture, dir / "renders", dir / "report", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary->figures, 0u);
  EXPECT_TRUE(fs::is_regular_file(dir / "report/status.png"));
  EXPECT_TRUE(fs::is_regular_file(dir / "report/coverage.png"));
  const std::string html = ReadTextFile(dir / "report/report.html").value();
  EXPECT_NE(html.find("<img src=\"status.png\""), std::string::npos);
  EXPECT_NE(html.find("<img src=\"coverage.png\""), std::string::npos);
  EXPECT_NE(html.find("timings.total_s"), std::string::npos);
  EXPECT_NE(html.find("render (cpu, cpu): total_s"), std::string::npos);
  // A single-channel map from an older fit: no model or cluster map to show.
  EXPECT_FALSE(fs::exists(dir / "report/model.png"));
  EXPECT_FALSE(fs::exists(dir / "report/clusters.png"));
  // This fit folder has no params.exr: the worst pixels keep their table without texels, and
  // the report says why, naming the file.
  EXPECT_NE(html.find("No texels: " + (dir / "fit/params.exr").string()), std::string::npos);
  const Json metrics = Json::parse(ReadTextFile(dir / "report/metrics.json").value());
  ASSERT_FALSE(metrics["overall"]["worst_pixels"].empty());
  EXPECT_TRUE(metrics["overall"]["worst_pixels"][0]["texel"].is_null());
}

TEST(Validate, ReportShowsTheModelAndClusterMapsTheFitWrote) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.01, 32, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  ASSERT_TRUE(render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", {}).ok());
  testing::WriteText(dir / "fit/fit_report.json",
                     R"({"model_names": ["lambert_lobe_absent", "lambert_no_evidence", "own_lobe"],
                         "fits_per_second": 1234.4, "timings_s": {"fit": 2.5, "total": 3.25}})");
  // Channels as the fitter writes them (status.exr): status, model, material_cluster.
  Image maps(20, 10, 3, -1.0f);
  for (int x = 0; x < 10; ++x) {
    maps.at(x, 5, 0) = 0;
    maps.at(x, 5, 1) = float(x % 3);
    maps.at(x, 5, 2) = float(x / 5);
  }
  ASSERT_TRUE(WriteExrChannels(dir / "fit/status.exr", maps, {"status", "model", "material_cluster"}).ok());
  ValidateOptions options;
  options.fit_dir = dir / "fit";
  options.max_figures = 0;
  auto summary = RunValidation(*capture, dir / "renders", dir / "report", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  for (const char* png : {"status.png", "model.png", "clusters.png"}) {
    EXPECT_TRUE(fs::is_regular_file(dir / "report" / png)) << png;
  }
  const std::string html = ReadTextFile(dir / "report/report.html").value();
  EXPECT_NE(html.find("<img src=\"model.png\""), std::string::npos);
  EXPECT_NE(html.find("<img src=\"clusters.png\""), std::string::npos);
  // The summary, above the tables, counts the models and clusters and records the fit's speed:
  // 10 texels, models 0 1 2 0 1 2 0 1 2 0 (own_lobe 3 of 10), clusters 0 x5 and 1 x5.
  const size_t tables = html.find("<section id=\"tables\">");
  ASSERT_NE(tables, std::string::npos);
  for (const char* text : {"own_lobe 30.0 %", "lambert_lobe_absent 40.0 %", "of 10 texels",
                           "2 clusters over 10 texels (largest 50.0 %)", "3.25 s total",
                           "2.50 s fitting", "1234 fits/s"}) {
    const size_t at = html.find(text);
    EXPECT_NE(at, std::string::npos) << text;
    EXPECT_LT(at, tables) << text;
  }
}

// A PNG stores a display value v as round(255 v): read back, it is off by up to half a step.
// One step leaves room for float rounding of v itself.
constexpr double kPngStep = 1.0 / 255;
// ComposeFigure's layout for 32-px images (font scale 1): pad 4, title row 7 + 2 pads, panels
// separated by a pad; the error map is the third panel.
constexpr int kFigurePad = 4, kFigureTitleH = 7 + 2 * kFigurePad, kFigureSize = 32;
constexpr int kErrorPanelX = 3 * kFigurePad + 2 * kFigureSize;

TEST(Validate, ErrorMapsOfAllImagesShareOneScaleAndTheWorstComeFirst) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.01, kFigureSize, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  ASSERT_TRUE(render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", {}).ok());
  // One holdout render ten times too bright: its PSNR falls far below every other's (the others
  // err by noise only; the lowest, ~10 dB, is a view lit from behind whose peak is noise).
  std::vector<const CaptureImage*> holdout;
  for (const CaptureImage& image : capture->images) {
    if (image.split == Split::kHoldout) holdout.push_back(&image);
  }
  ASSERT_GE(holdout.size(), 3u);
  const CaptureImage& bad = *holdout[1];
  const fs::path bad_render = dir / "renders" / render::RenderPathFor(bad.file);
  Image brighter = ReadExrRgb(bad_render).value();
  for (float& v : brighter.data) v *= 10;
  ASSERT_TRUE(WriteExr(bad_render, brighter).ok());
  ValidateOptions options;
  options.max_figures = 3;
  auto summary = RunValidation(*capture, dir / "renders", dir / "report", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();

  // metrics.json records the one scale, how it was chosen and its colour map.
  const Json metrics = Json::parse(ReadTextFile(dir / "report/metrics.json").value());
  const Json& scale = metrics["figures"]["error_scale"];
  const double error_scale = scale["fraction_of_peak"].get<double>();
  EXPECT_EQ(metrics["figures"]["error_scale_fraction_of_peak"].get<double>(), error_scale);
  EXPECT_EQ(scale["source"], "automatic");
  EXPECT_EQ(scale["quantile"].get<double>(), kMapErrorScaleQuantile);
  EXPECT_EQ(error_scale, NiceCeil(scale["pooled_quantile_fraction_of_peak"].get<double>()));
  EXPECT_NE(scale["colour_map"].get<std::string>().find("viridis"), std::string::npos);
  EXPECT_TRUE(fs::is_regular_file(dir / "report" / scale["legend"].get<std::string>()));
  // The brightened image ranks worst and is drawn, though evenly spaced figures would skip it.
  ASSERT_FALSE(metrics["figures"]["worst_shown"].empty());
  EXPECT_EQ(metrics["figures"]["worst_shown"][0], bad.file);
  // Ranks follow PSNR: rank k has the k-th lowest.
  std::vector<double> psnr_by_rank(metrics["images"].size() + 1);
  for (const Json& image : metrics["images"]) {
    psnr_by_rank.at(image["error_rank"].get<size_t>()) = image["psnr_db"].get<double>();
  }
  for (size_t k = 2; k < psnr_by_rank.size(); ++k) EXPECT_LE(psnr_by_rank[k - 1], psnr_by_rank[k]);
  std::vector<Json> drawn;
  for (const Json& image : metrics["images"]) {
    if (image["file"] == bad.file) {
      EXPECT_EQ(image["error_rank"], 1);
    }
    if (image.contains("figure")) drawn.push_back(image);
  }
  ASSERT_GE(drawn.size(), 2u);

  // Every drawn error map shows its pixels' error on that one scale: colour = Viridis(e / scale),
  // e = mean over RGB of |r - p| / peak, from the files themselves; and the colour bars match.
  std::vector<Image> figures;
  for (const Json& image : drawn) {
    SCOPED_TRACE(image["file"].get<std::string>());
    const Image figure = ReadPng(dir / "report" / image["figure"].get<std::string>()).value();
    const Image photo = ReadImageRgb(capture->Resolve(image["file"].get<std::string>())).value();
    const Image render = ReadExrRgb(dir / "renders" / image["render"].get<std::string>()).value();
    const double peak = image["peak"].get<double>();
    int checked = 0;
    for (int y = 0; y < kFigureSize; ++y) {
      for (int x = 0; x < kFigureSize; ++x) {
        const int fx = kErrorPanelX + x, fy = kFigureTitleH + y;
        bool grey = true;  // not evaluated (0.22 in all channels)
        for (int c = 0; c < 3; ++c) grey &= std::abs(figure.at(fx, fy, c) - 0.22) <= kPngStep;
        if (grey) continue;
        double e = 0;
        for (int c = 0; c < 3; ++c) e += std::abs(double(render.at(x, y, c)) - photo.at(x, y, c));
        const Rgb expected = Viridis(e / 3 / peak / error_scale);
        for (int c = 0; c < 3; ++c) {
          ASSERT_NEAR(figure.at(fx, fy, c), expected[c], kPngStep) << x << "," << y;
        }
        ++checked;
      }
    }
    EXPECT_GT(checked, 0);
    figures.push_back(figure);
  }
  for (size_t k = 1; k < figures.size(); ++k) {
    ASSERT_EQ(figures[k].width, figures[0].width);
    // Right of the error panel: the colour bar and its labels, up to the caption row.
    for (int y = 0; y < kFigureTitleH + kFigureSize; ++y) {
      for (int x = kErrorPanelX + kFigureSize; x < figures[0].width; ++x) {
        for (int c = 0; c < 3; ++c) ASSERT_EQ(figures[k].at(x, y, c), figures[0].at(x, y, c));
      }
    }
  }

  // The page: summary first, then the worst images, all figures, maps, and the tables last.
  const std::string html = ReadTextFile(dir / "report/report.html").value();
  const std::vector<std::string> order = {"<section id=\"summary\">", "images compared",
                                          "<section id=\"worst\">", "error_scale.png",
                                          "<section id=\"figures\">", "<section id=\"maps\">",
                                          "<section id=\"tables\">", "<h2>Per image</h2>",
                                          "<h2>Worst pixels</h2>", "<h2>Timings</h2>"};
  size_t at = 0;
  for (const std::string& part : order) {
    const size_t found = html.find(part, at);
    ASSERT_NE(found, std::string::npos) << part << " missing or out of order";
    at = found;
  }
  // The worst image is the first figure on the page, captioned as such.
  const size_t first_figure = html.find("<img src=\"figures/");
  ASSERT_NE(first_figure, std::string::npos);
  std::string bad_figure;
  for (const Json& image : drawn) {
    if (image["file"] == bad.file) bad_figure = image["figure"].get<std::string>();
  }
  ASSERT_FALSE(bad_figure.empty());
  EXPECT_EQ(html.find("<img src=\"" + bad_figure + "\""), first_figure);
  EXPECT_NE(html.find("#1 " + bad.file), std::string::npos);
  EXPECT_LT(html.find("#1 " + bad.file), html.find("<section id=\"figures\">"));
}

TEST(Validate, NumbersDoNotDependOnTheThreadCount) {
  // Images are scored in parallel and their sums pooled in image order: metrics.json (less its
  // timings) and the figures must be the same bytes with 1, 2 or 5 threads.
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.02, 56, 3).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  ASSERT_TRUE(render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", {}).ok());
  std::string first_metrics;
  std::vector<std::string> first_figures;
  for (int threads : {1, 2, 5}) {
    SCOPED_TRACE(threads);
    ValidateOptions options;
    options.max_figures = 3;
    options.threads = threads;
    const fs::path out = dir / ("report_" + std::to_string(threads));
    auto summary = RunValidation(*capture, dir / "renders", out, options);
    ASSERT_TRUE(summary.ok()) << summary.status().ToString();
    Json metrics = Json::parse(ReadTextFile(out / "metrics.json").value());
    metrics.erase("timings");
    std::vector<std::string> figures;
    for (const auto& entry : fs::directory_iterator(out / "figures")) {
      figures.push_back(entry.path().filename().string() + ":" +
                        ReadTextFile(entry.path()).value());
    }
    std::sort(figures.begin(), figures.end());
    if (first_metrics.empty()) {
      first_metrics = metrics.dump();
      first_figures = figures;
      EXPECT_GE(figures.size(), 3u);
      continue;
    }
    EXPECT_EQ(metrics.dump(), first_metrics);
    EXPECT_EQ(figures, first_figures);
  }
  ValidateOptions bad;
  bad.threads = -1;
  EXPECT_EQ(bad.Validate().code(), StatusCode::kInvalidArgument);
}

TEST(RenderCapture, WriterCountChangesNoFileAndBadOptionsAreRefused) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.0, 40, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  std::vector<std::string> first;
  for (int writers : {1, 4}) {
    render::CaptureRenderOptions options;
    options.split = render::SplitSelection::kAll;
    options.writers = writers;
    const fs::path out = dir / ("renders_" + std::to_string(writers));
    auto summary = render::RenderCapture(*capture, dir / "capture/gt/params.exr", out, options);
    ASSERT_TRUE(summary.ok()) << summary.status().ToString();
    EXPECT_EQ(summary->writers, writers);
    std::vector<std::string> files;
    for (const auto& entry : fs::recursive_directory_iterator(out)) {
      if (!entry.is_regular_file() || entry.path().filename() == "render_report.json") continue;
      files.push_back(fs::relative(entry.path(), out).string() + ":" +
                      ReadTextFile(entry.path()).value());
    }
    std::sort(files.begin(), files.end());
    EXPECT_EQ(files.size(), 3 * capture->images.size());
    if (first.empty()) {
      first = files;
    } else {
      EXPECT_TRUE(files == first) << "files differ between 1 and 4 writers";
    }
  }
  render::CaptureRenderOptions bad;
  bad.writers = -1;
  EXPECT_EQ(bad.Validate().code(), StatusCode::kInvalidArgument);
  bad.writers = 0;
  bad.supersampling = -1;  // 0 is auto
  EXPECT_EQ(bad.Validate().code(), StatusCode::kInvalidArgument);
  bad.supersampling = render::kMaxSupersampling + 1;
  EXPECT_EQ(bad.Validate().code(), StatusCode::kInvalidArgument);
}

// Interreflection (indirect_light.h) is added under --indirect auto only when the train
// photographs show light where no direct light reaches. A synthetic capture is rendered with
// direct light only: its unlit pixels hold noise, and the indirect light stays off. The same
// capture with every photograph replaced by a render that has the indirect light shows it
// exactly, and the auto render then reproduces those photographs.
TEST(RenderCapture, InterreflectionIsAddedOnlyWhenThePhotographsShowIt) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.01, 64, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  const fs::path gt = dir / "capture/gt/params.exr";
  auto evidence_of = [&](const Capture& c) {
    auto fitted = render::LoadFittedCapture(c, gt);
    REFLCAP_CHECK(fitted.ok()) << fitted.status().ToString();
    auto table = render::IndirectLight::Build(*(*fitted)->scene, (*fitted)->atlas, 16);
    REFLCAP_CHECK(table.ok());
    return render::MeasureIndirectEvidence(**fitted, *table, 2, true, 1);
  };
  const render::IndirectEvidence direct_only = evidence_of(*capture);
  std::printf("direct-light photographs: %zu unlit pixels in %d images, scale %.3f, error "
              "reduction %.3f\n", direct_only.pixels, direct_only.images, direct_only.scale,
              direct_only.error_reduction);
  EXPECT_GE(direct_only.pixels, size_t(1000)) << "the test scene has too few unlit pixels";
  EXPECT_FALSE(direct_only.shows);
  // Adding light to pixels that hold noise removes none of their error (it adds a little).
  EXPECT_LT(direct_only.error_reduction, 0.01);

  render::CaptureRenderOptions auto_options;
  auto_options.split = render::SplitSelection::kHoldout;
  auto_options.indirect_rays = 16;
  ASSERT_TRUE(render::RenderCapture(*capture, gt, dir / "auto_direct", auto_options).ok());
  Json report = Json::parse(ReadTextFile(dir / "auto_direct/render_report.json").value());
  EXPECT_EQ(report["indirect"]["mode"], "auto");
  EXPECT_EQ(report["indirect"]["used"], false);

  // Photographs with interreflection: every image rendered with it, written over the photograph.
  render::CaptureRenderOptions on = auto_options;
  on.split = render::SplitSelection::kAll;
  on.indirect = render::IndirectMode::kOn;
  ASSERT_TRUE(render::RenderCapture(*capture, gt, dir / "with_indirect", on).ok());
  double added = 0;
  for (const CaptureImage& image : capture->images) {
    auto photo = ReadExrRgb(capture->Resolve(image.file));
    auto lit = ReadExrRgb(dir / "with_indirect" / render::RenderPathFor(image.file));
    ASSERT_TRUE(photo.ok() && lit.ok());
    ASSERT_TRUE(WriteExr(capture->Resolve(image.file), *lit, ExrPixelType::kFloat).ok());
    for (size_t i = 0; i < lit->data.size(); ++i) added += std::max(0.0f, lit->data[i] - photo->data[i]);
  }
  EXPECT_GT(added, 0.0) << "the relief object's concavities send no light at all";
  const render::IndirectEvidence with = evidence_of(*capture);
  std::printf("photographs with interreflection: scale %.6f, error reduction %.6f\n", with.scale,
              with.error_reduction);
  EXPECT_TRUE(with.shows);
  // The photographs are the prediction itself (same table, same fit): float rounding only.
  EXPECT_NEAR(with.scale, 1.0, 1e-6);
  EXPECT_NEAR(with.error_reduction, 1.0, 1e-6);

  ASSERT_TRUE(render::RenderCapture(*capture, gt, dir / "auto_indirect", auto_options).ok());
  report = Json::parse(ReadTextFile(dir / "auto_indirect/render_report.json").value());
  EXPECT_EQ(report["indirect"]["used"], true);
  EXPECT_EQ(report["indirect"]["bounces"], 2);
  for (const CaptureImage& image : capture->images) {
    if (image.split != Split::kHoldout) continue;
    auto photo = ReadExrRgb(capture->Resolve(image.file));
    auto rendered = ReadExrRgb(dir / "auto_indirect" / render::RenderPathFor(image.file));
    ASSERT_TRUE(photo.ok() && rendered.ok());
    ASSERT_EQ(photo->data, rendered->data) << image.file;
  }
  // Bad settings.
  render::CaptureRenderOptions bad;
  bad.indirect_bounces = 0;
  EXPECT_EQ(bad.Validate().code(), StatusCode::kInvalidArgument);
  bad.indirect_bounces = render::kMaxIndirectBounces;
  bad.indirect_rays = render::kMaxIndirectRays + 1;
  EXPECT_EQ(bad.Validate().code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(render::ParseIndirectMode("sometimes", "--indirect").ok());
}

// The pixel model (--supersample auto) follows the photographs: a synthetic capture's photographs
// are point samples of the radiance at each pixel centre, and auto renders them that way — bit
// for bit what --supersample 1 renders; the same capture rendered with 3 x 3 rays averaged over
// each pixel (what a sensor or a path tracer's pixel filter records) makes auto average over the
// pixel too, which then reproduces the held-out photographs better than the pixel centre does.
TEST(RenderCapture, PixelModelFollowsThePhotographs) {
  testing::ScratchDir dir;
  auto holdout_error = [&](const Capture& c, const fs::path& renders) {
    double sum = 0;
    for (const CaptureImage& image : c.images) {
      if (image.split != Split::kHoldout) continue;
      auto photo = ReadExrRgb(c.Resolve(image.file));
      auto rendered = ReadExrRgb(renders / render::RenderPathFor(image.file));
      REFLCAP_CHECK(photo.ok() && rendered.ok());
      for (size_t i = 0; i < photo->data.size(); ++i) {
        sum += std::pow(double(photo->data[i]) - rendered->data[i], 2);
      }
    }
    return sum;
  };
  struct Photographs {
    int supersampling;
    double footprint;
  };
  for (const Photographs photos : {Photographs{1, 1.0}, Photographs{3, 1.0}, Photographs{4, 1.5}}) {
    const int photo_supersampling = photos.supersampling;
    SCOPED_TRACE(::testing::Message() << photo_supersampling << " x " << photo_supersampling
                                    << " rays over " << photos.footprint << " px");
    const fs::path cap_dir =
        dir / ("capture" + std::to_string(photo_supersampling) + "_" +
               std::to_string(int(photos.footprint * 100)));
    synth::SynthOptions o;
    o.noise = 0.01;
    o.texels = 4000;
    o.image_size = 64;
    o.cameras = 2;
    o.lights = 2;
    o.steps = 4;
    o.supersampling = photo_supersampling;
    o.pixel_footprint = photos.footprint;
    ASSERT_TRUE(synth::WriteSyntheticCapture(o, cap_dir).ok());
    auto capture = ReadCapture(cap_dir);
    ASSERT_TRUE(capture.ok());
    const fs::path gt = cap_dir / "gt/params.exr";
    auto fitted = render::LoadFittedCapture(*capture, gt);
    ASSERT_TRUE(fitted.ok()) << fitted.status().ToString();
    const render::PixelEvidence evidence = render::MeasurePixelEvidence(**fitted, true);
    std::printf("photographs at %d x %d rays per pixel: point error %.4g, box error %.4g, "
                "reduction %.3f over %zu pixels of %d images\n",
                photo_supersampling, photo_supersampling, evidence.error_point,
                evidence.error_box, evidence.reduction, evidence.pixels, evidence.images);
    EXPECT_GT(evidence.images, 0);
    EXPECT_EQ(evidence.box, photo_supersampling > 1);

    render::CaptureRenderOptions automatic, point;
    point.supersampling = 1;
    ASSERT_TRUE(render::RenderCapture(*capture, gt, cap_dir / "auto", automatic).ok());
    ASSERT_TRUE(render::RenderCapture(*capture, gt, cap_dir / "point", point).ok());
    const Json report = Json::parse(ReadTextFile(cap_dir / "auto/render_report.json").value());
    EXPECT_EQ(report["pixel_model"]["mode"], "auto");
    // A box keeps 4 rays per pixel width over its footprint: 6 x 6 over 1.5 px.
    const int chosen =
        photo_supersampling > 1 ? render::AutoBoxSupersampling(photos.footprint) : 1;
    EXPECT_EQ(chosen, photos.footprint > 1 ? 6 : photo_supersampling > 1 ? 4 : 1);
    EXPECT_EQ(report["supersampling"], chosen);
    // The footprint follows the photographs' (a candidate; 1 for point samples, which never
    // reach the footprint's evidence).
    std::printf("  footprint evidence: %s\n", report["pixel_model"]["footprint"].dump().c_str());
    EXPECT_EQ(report["pixel_model"]["footprint"]["footprint_px"].get<double>(), photos.footprint);
    const double error_auto = holdout_error(*capture, cap_dir / "auto");
    const double error_point = holdout_error(*capture, cap_dir / "point");
    std::printf("  holdout squared error: auto %.4g, point %.4g\n", error_auto, error_point);
    if (photo_supersampling == 1) {
      EXPECT_EQ(error_auto, error_point) << "auto must render point-sampled photographs as before";
    } else if (photos.footprint != 1) {
      // The photographs' own footprint against the pixel's square, both 4 x 4 rays.
      render::CaptureRenderOptions own_square = automatic;
      own_square.pixel_footprint = 1;
      ASSERT_TRUE(render::RenderCapture(*capture, gt, cap_dir / "square", own_square).ok());
      const double error_square = holdout_error(*capture, cap_dir / "square");
      std::printf("  holdout squared error at 1 px: %.4g\n", error_square);
      EXPECT_LT(error_auto, 0.5 * error_square);
    } else {
      // The truth rendered as the photographs were taken is off by their noise alone; at the
      // pixel centre it misses every edge's partial coverage.
      EXPECT_LT(error_auto, 0.5 * error_point);
    }
  }
  EXPECT_EQ(render::ParseSupersampling("auto", "--supersample").value(), render::kAutoSupersampling);
  EXPECT_EQ(render::ParseSupersampling("3", "--supersample").value(), 3);
  EXPECT_EQ(render::ParsePixelFootprint("auto", "--pixel-footprint").value(),
            render::kAutoPixelFootprint);
  EXPECT_EQ(render::ParsePixelFootprint("1.5", "--pixel-footprint").value(), 1.5);
  EXPECT_EQ(render::AutoBoxSupersampling(1.0), render::kAutoBoxSupersampling);
  EXPECT_EQ(render::AutoBoxSupersampling(1.25), 5);
  EXPECT_EQ(render::AutoBoxSupersampling(render::kMaxPixelFootprint), render::kMaxSupersampling);
  for (const char* bad : {"0.9", "5", "nan", "1.5px", ""}) {
    EXPECT_FALSE(render::ParsePixelFootprint(bad, "--pixel-footprint").ok()) << bad;
  }
  for (const char* bad : {"0", "17", "-1", "2x", "", "many"}) {
    EXPECT_FALSE(render::ParseSupersampling(bad, "--supersample").ok()) << bad;
  }
}

TEST(RenderCapture, FileLayoutKeys) {
  EXPECT_EQ(render::ImageKey("images/0003.exr"), "0003");
  EXPECT_EQ(render::ImageKey("raw/a.png"), "raw/a");
  EXPECT_EQ(render::RenderPathFor("images/0003.exr"), "images/0003.exr");
  EXPECT_EQ(render::RenderPathFor("images/001.png"), "images/001.exr");
  EXPECT_EQ(render::MaskPathFor("images/0003.exr"), "masks/0003.png");
  EXPECT_EQ(render::AuxPathFor("images/0003.exr"), "aux/0003.exr");
  // A file outside the capture's folder never makes an output outside the render folder (run as
  // root, a re-render once overwrote the photograph it was named after).
  EXPECT_EQ(render::RenderPathFor("/data/rig/images/0003.exr"), "images/0003.exr");
  EXPECT_EQ(render::RenderPathFor("../other/0003.png"), "images/0003.exr");
  EXPECT_EQ(render::RenderPathFor("images/../../0003.exr"), "images/0003.exr");
  EXPECT_EQ(render::ImageKey("/data/rig/images/0003.exr"), "0003");
  EXPECT_EQ(render::MaskPathFor("../0003.exr"), "masks/0003.png");
}

TEST(RenderCapture, ImagesGivenByAbsolutePathsAreNeverOverwritten) {
  testing::ScratchDir dir;
  ASSERT_TRUE(Synth(dir / "capture", 0.0, 40, 2).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  // The capture as a user might write it: every image by its absolute path.
  for (CaptureImage& image : capture->images) {
    image.file = fs::absolute(capture->Resolve(image.file)).string();
  }
  std::vector<std::string> before;
  for (const CaptureImage& image : capture->images) before.push_back(ReadTextFile(image.file).value());
  render::CaptureRenderOptions options;
  options.split = render::SplitSelection::kAll;
  auto summary = render::RenderCapture(*capture, dir / "capture/gt/params.exr", dir / "renders", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  for (size_t i = 0; i < capture->images.size(); ++i) {
    EXPECT_EQ(ReadTextFile(capture->images[i].file).value(), before[i]) << capture->images[i].file;
    EXPECT_TRUE(fs::exists(dir / "renders" / render::RenderPathFor(capture->images[i].file)));
  }
}

}  // namespace
}  // namespace reflcap::validate
