// Resample outputs shared by a run and by the merge of its shards (see resample_outputs.h).
#include "acquire/resample/resample_outputs.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <sstream>

#include "acquire/resample/mask_agreement.h"
#include "acquire/resample/resample.h"
#include "engine/core/progress.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"

namespace reflcap::resample {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// The sample-count thresholds reported as "fraction of seen texels with at least N samples".
constexpr int kSampleThresholds[] = {1, 5, 10, 20, 50};
// Half-vector angles (degrees) below which a texel counts as having seen a near-specular
// configuration: 2° resolves lobes up to n ~ 200, 5° up to n ~ 30, 10° only broad ones
// (a lobe of exponent n is ~ 1/sqrt(n) rad wide around the mirror direction, θh half that).
constexpr double kNearSpecularDeg[] = {2, 5, 10};
// Near-specular threshold used in the per-views table.
constexpr double kNearSpecularTableDeg = 5;

// Nearest-rank percentile of an ascending vector (q in [0, 1]); 0 when empty.
double Percentile(const std::vector<double>& sorted, double q) {
  if (sorted.empty()) return 0;
  const size_t rank = size_t(std::ceil(q * double(sorted.size())));
  return sorted[std::min(sorted.size() - 1, rank == 0 ? 0 : rank - 1)];
}

Json Distribution(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  const double sum = std::accumulate(values.begin(), values.end(), 0.0);
  return {{"p5", Percentile(values, 0.05)},
          {"p50", Percentile(values, 0.50)},
          {"p95", Percentile(values, 0.95)},
          {"mean", values.empty() ? 0.0 : sum / double(values.size())},
          {"max", values.empty() ? 0.0 : values.back()}};
}

Image CoveragePng(const TexelAtlas& atlas, const TexelCoverage& coverage) {
  Image png(atlas.width, atlas.height, 3, 0.0f);
  const double scale = 1.0 / std::log2(1 + kCoveragePngFullScale);
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    float* px = &png.data[size_t(atlas.pixel_of_texel[t]) * 3];
    const uint32_t n = coverage.samples(t);
    if (n == 0) {
      px[0] = 160.0f / 255.0f;
      continue;
    }
    const float grey = float(std::min(1.0, std::log2(1.0 + n) * scale));
    px[0] = px[1] = px[2] = grey;
  }
  return png;
}


}  // namespace

std::string FirstDifference(const Json& a, const Json& b) {
  for (auto it = a.begin(); it != a.end(); ++it) {
    if (!b.contains(it.key()) || b[it.key()] != it.value()) return it.key();
  }
  return a.size() == b.size() ? "" : "(keys)";
}

Json Tally::ToJson() const {
  return Json{{"outcome_counts", outcome_counts},
              {"rays", {primary_rays, tap_shadow_rays, visibility_rays, shadow_rays}},
              {"variance_images", {variance_images, ignored_variance_images}},
              {"seconds", {read_wait_s, resample_s, stream_s, gpu_s}}};
}

bool Tally::FromJson(const Json& j) {
  try {
    outcome_counts = j.at("outcome_counts").get<std::array<uint64_t, kOutcomeCount>>();
    const auto rays = j.at("rays").get<std::array<uint64_t, 4>>();
    primary_rays = rays[0];
    tap_shadow_rays = rays[1];
    visibility_rays = rays[2];
    shadow_rays = rays[3];
    const auto variance = j.at("variance_images").get<std::array<uint64_t, 2>>();
    variance_images = variance[0];
    ignored_variance_images = variance[1];
    const auto seconds = j.at("seconds").get<std::array<double, 4>>();
    read_wait_s = seconds[0];
    resample_s = seconds[1];
    stream_s = seconds[2];
    gpu_s = seconds[3];
  } catch (const Json::exception&) {
    return false;
  }
  return true;
}

void Tally::Add(const Tally& o) {
  for (size_t i = 0; i < outcome_counts.size(); ++i) outcome_counts[i] += o.outcome_counts[i];
  primary_rays += o.primary_rays;
  tap_shadow_rays += o.tap_shadow_rays;
  visibility_rays += o.visibility_rays;
  shadow_rays += o.shadow_rays;
  variance_images += o.variance_images;
  ignored_variance_images += o.ignored_variance_images;
  read_wait_s += o.read_wait_s;
  resample_s += o.resample_s;
  stream_s += o.stream_s;
  gpu_s += o.gpu_s;
}

// Writes coverage.exr, domain.exr and coverage.png from `coverage`, and sets every field of
// `report` that depends on the photographs' outcomes (counts, distributions, the domain, rays,
// the noise model's variance-image counts); the caller sets the rest. Internal when the kept
// count disagrees with the samples written.
StatusOr<Counted> WriteCountedOutputs(const fs::path& out_dir, const TexelAtlas& atlas,
                                      const TexelCoverage& coverage, const Tally& tally,
                                      uint64_t images, uint64_t samples_written, Json* report,
                                      bool write_maps) {
  Counted counted;
  // Without maps, 1x1 images that nothing writes (the loop below fills them only with maps).
  Image samples_map(write_maps ? atlas.width : 1, write_maps ? atlas.height : 1, 1, 0.0f);
  // domain.exr channels, in OpenEXR's (alphabetical) order.
  const std::vector<std::string> domain_names = {"cells", "min_half_angle_deg", "observations",
                                                 "samples", "seen", "views"};
  Image domain_map(write_maps ? atlas.width : 1, write_maps ? atlas.height : 1,
                   int(domain_names.size()), 0.0f);
  std::vector<double> samples_seen, cells_seen, views_seen, observations_seen;
  uint64_t texels_seen = 0, texels_with_samples = 0, texels_observed = 0, observations = 0;
  std::array<uint64_t, std::size(kSampleThresholds)> at_least{}, observed_at_least{},
      observed_and_kept{};
  std::array<uint64_t, std::size(kNearSpecularDeg)> near_specular{};
  // Texels grouped by their number of views: 0, 1, 2, 3-4, 5-8, 9-16, 17+.
  constexpr int kViewGroups = 7;
  const char* kViewGroupNames[kViewGroups] = {"0", "1", "2", "3-4", "5-8", "9-16", "17+"};
  auto view_group = [](uint32_t v) {
    if (v <= 2) return int(v);
    if (v <= 4) return 3;
    if (v <= 8) return 4;
    if (v <= 16) return 5;
    return 6;
  };
  struct Group {
    uint64_t texels = 0;
    double samples = 0, cells = 0;
    uint64_t near_specular = 0;
  };
  std::array<Group, kViewGroups> groups{};
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    const uint32_t n = coverage.samples(t);
    const uint32_t o = coverage.observations(t);
    if (write_maps) {
      const size_t pixel = atlas.pixel_of_texel[t];
      samples_map.data[pixel] = float(n);
      float* d = &domain_map.data[pixel * domain_names.size()];
      d[0] = float(coverage.cells(t));
      d[1] = coverage.min_half_angle_deg(t);
      d[2] = float(o);
      d[3] = float(n);
      d[4] = coverage.seen(t) ? 1.0f : 0.0f;
      d[5] = float(coverage.views(t));
    }
    texels_with_samples += n > 0;
    texels_observed += o > 0;
    observations += o;
    if (!coverage.seen(t)) continue;
    ++texels_seen;
    samples_seen.push_back(n);
    observations_seen.push_back(o);
    cells_seen.push_back(coverage.cells(t));
    views_seen.push_back(coverage.views(t));
    for (size_t i = 0; i < std::size(kSampleThresholds); ++i) {
      const uint32_t threshold = uint32_t(kSampleThresholds[i]);
      at_least[i] += n >= threshold;
      observed_at_least[i] += o >= threshold;
      observed_and_kept[i] += o >= threshold && n >= threshold;
    }
    for (size_t i = 0; i < std::size(kNearSpecularDeg); ++i) {
      near_specular[i] += coverage.min_half_angle_deg(t) < kNearSpecularDeg[i];
    }
    Group& g = groups[view_group(coverage.views(t))];
    ++g.texels;
    g.samples += n;
    g.cells += coverage.cells(t);
    g.near_specular += coverage.min_half_angle_deg(t) < kNearSpecularTableDeg;
  }
  if (write_maps) {
    REFLCAP_RETURN_IF_ERROR(WriteExr(out_dir / "coverage.exr", samples_map));
    REFLCAP_RETURN_IF_ERROR(WriteExrChannels(out_dir / "domain.exr", domain_map, domain_names));
    REFLCAP_RETURN_IF_ERROR(WritePng(out_dir / "coverage.png", CoveragePng(atlas, coverage)));
  }

  const uint64_t kept = tally.outcome_counts[size_t(Outcome::kKept)];
  std::array<uint64_t, kReasonCount>& reasons = counted.reasons;
  Json detail = Json::object();
  for (int o = 1; o < kOutcomeCount; ++o) {
    reasons[size_t(ReasonOf(Outcome(o)))] += tally.outcome_counts[o];
    detail[OutcomeName(Outcome(o))] = tally.outcome_counts[o];
  }
  Json rejected = Json::object();
  uint64_t rejected_total = 0;
  for (int r = 0; r < kReasonCount; ++r) {
    rejected[ReasonName(Reason(r))] = reasons[r];
    rejected_total += reasons[r];
  }
  if (kept != samples_written) {
    return InternalError(out_dir.string(), ": ", kept, " samples kept but ", samples_written, " written");
  }
  const double fraction_base = texels_seen > 0 ? double(texels_seen) : 1.0;
  Json at_least_json = Json::object(), observed_json = Json::object(), keep_json = Json::object();
  for (size_t i = 0; i < std::size(kSampleThresholds); ++i) {
    const std::string key = std::to_string(kSampleThresholds[i]);
    at_least_json[key] = double(at_least[i]) / fraction_base;
    observed_json[key] = double(observed_at_least[i]) / fraction_base;
    keep_json[key] = {{"texels_observed_at_least", observed_at_least[i]},
                      {"fraction_keeping_at_least",
                       observed_at_least[i] ? double(observed_and_kept[i]) / double(observed_at_least[i]) : 0.0}};
  }
  Json near_json = Json::object();
  for (size_t i = 0; i < std::size(kNearSpecularDeg); ++i) {
    near_json[StrCat(kNearSpecularDeg[i])] = double(near_specular[i]) / fraction_base;
  }
  Json by_views = Json::array();
  for (int g = 0; g < kViewGroups; ++g) {
    const Group& group = groups[g];
    const double n = group.texels > 0 ? double(group.texels) : 1.0;
    by_views.push_back({{"views", kViewGroupNames[g]},
                        {"texels", group.texels},
                        {"mean_samples", group.samples / n},
                        {"mean_cells", group.cells / n},
                        {"mean_cells_fraction", group.cells / n / kDomainCells},
                        {"near_specular_5deg_fraction", double(group.near_specular) / n}});
  }
  const uint64_t pairs = uint64_t(atlas.TexelCount()) * images;
  Json& r = *report;
  r["images"] = images;
  r["texels"] = atlas.TexelCount();
  r["texels_seen"] = texels_seen;
  r["texels_with_samples"] = texels_with_samples;
  r["pairs"] = pairs;
  r["samples_kept"] = kept;
  r["samples_rejected"] = rejected;
  r["samples_rejected_total"] = rejected_total;
  r["samples_rejected_detail"] = detail;
  r["reason_order"] =
      "each (texel, image) pair is counted once, under the first test it fails: grazing (view) > "
      "edge (outside the image) > occluded > grazing (light) > shadowed > edge (footprint: "
      "silhouette, depth or shadow boundary) > edge (a point-sampling camera's pixels around the "
      "texel all measured other texels) > invalid > clipped > dark; kept + rejected = pairs";
  r["samples_per_texel"] = Distribution(samples_seen);
  r["samples_per_texel_population"] =
      "texels_seen (texels some selected camera sees: view not grazing, inside the image, not "
      "occluded)";
  r["texels_seen_with_at_least_samples"] = at_least_json;
  r["texels_observed"] = texels_observed;
  r["observations"] = observations;
  r["observations_kept_fraction"] = observations ? double(kept) / double(observations) : 0.0;
  r["observations_definition"] =
      "an observation is a (texel, image) pair that the photograph shows lit: seen, light not "
      "grazing, not shadowed; only the footprint (edge) and pixel tests remain. Observations are "
      "what the rig offers; samples are what the resampler keeps";
  r["observations_per_texel"] = Distribution(observations_seen);
  r["texels_seen_with_at_least_observations"] = observed_json;
  r["keep_rate_by_threshold"] = keep_json;
  r["domain"] = {
      {"cells_total", kDomainCells},
      {"binning", "unordered (theta_i, theta_o) pair in 15 deg bins over [0, 90) x relative "
                  "azimuth in 30 deg bins over [0, 180]: 21 x 6 cells (reciprocity, isotropy)"},
      {"cells_per_texel", Distribution(cells_seen)},
      {"views_per_texel", Distribution(views_seen)},
      {"near_specular_fraction", near_json},
      {"near_specular_definition", "fraction of seen texels with a sample whose half vector is "
                                   "within the given angle (deg) of the shading normal"},
      {"by_views", by_views},
      {"note", "more viewpoints give more distinct cells and more near-specular samples, which "
               "is what makes a lobe identifiable (the seed paper: more viewpoints, more "
               "accurate fits)"}};
  r["rays"] = {{"visibility", tally.visibility_rays},
               {"shadow", tally.shadow_rays},
               {"pixel_map_camera", tally.primary_rays},
               {"pixel_map_shadow", tally.tap_shadow_rays}};
  Json& noise = r["noise_model"];
  noise["variance_images"] = tally.variance_images;
  noise["variance_images_ignored"] = tally.ignored_variance_images;
  noise["weights"] =
      tally.variance_images == 0
          ? "the noise model for every photograph"
          : tally.variance_images == images
                ? "every photograph's variance image (images[].variance): var = sum_k w_k^2 var_k "
                  "over the bilinear taps + (relative floor x max channel)^2; dark: every channel "
                  "<= 3 sigma; invalid: a channel < -5 sigma"
                : "the variance image (images[].variance) where a photograph has one (see "
                  "variance_images), the noise model elsewhere";
  counted.texels_seen = texels_seen;
  counted.texels_with_samples = texels_with_samples;
  counted.kept = kept;
  counted.rejected_total = rejected_total;
  counted.pairs = pairs;
  return counted;
}

// The few lines `reflcap resample` prints, from the report.
std::string SummaryText(const Json& report, double seconds) {
  std::ostringstream text;
  char line[256];
  const uint64_t images = report["images"].get<uint64_t>(), pairs = report["pairs"].get<uint64_t>();
  const uint64_t kept = report["samples_kept"].get<uint64_t>();
  std::snprintf(line, sizeof line, "resampled %llu images x %llu texels (%s split, %s) in %s\n",
                (unsigned long long)images, (unsigned long long)report["texels"].get<uint64_t>(),
                report["split"].get<std::string>().c_str(),
                report["geometry"].get<std::string>().c_str(), FormatDuration(seconds).c_str());
  text << line;
  std::snprintf(line, sizeof line, "  samples kept %llu (%.1f %% of %llu texel-image pairs); rejected:",
                (unsigned long long)kept, pairs ? 100.0 * double(kept) / double(pairs) : 0.0,
                (unsigned long long)pairs);
  text << line;
  for (int r = 0; r < kReasonCount; ++r) {
    text << " " << ReasonName(Reason(r)) << " " << report["samples_rejected"][ReasonName(Reason(r))].get<uint64_t>();
  }
  text << "\n";
  const Json& spt = report["samples_per_texel"];
  std::snprintf(line, sizeof line,
                "  texels seen %llu, with samples %llu; samples per seen texel p5 %.0f, p50 %.0f, "
                "p95 %.0f; >= 20 samples: %.1f %% (>= 20 lit observations: %.1f %%)\n",
                (unsigned long long)report["texels_seen"].get<uint64_t>(),
                (unsigned long long)report["texels_with_samples"].get<uint64_t>(),
                spt["p5"].get<double>(), spt["p50"].get<double>(), spt["p95"].get<double>(),
                100.0 * report["texels_seen_with_at_least_samples"]["20"].get<double>(),
                100.0 * report["texels_seen_with_at_least_observations"]["20"].get<double>());
  text << line;
  const Json& domain = report["domain"];
  std::snprintf(line, sizeof line,
                "  coverage: %.0f views and %.0f of %d domain cells per seen texel (median); "
                "near-specular sample (half vector < 5 deg): %.1f %% of seen texels\n",
                domain["views_per_texel"]["p50"].get<double>(),
                domain["cells_per_texel"]["p50"].get<double>(), kDomainCells,
                100.0 * domain["near_specular_fraction"]["5"].get<double>());
  text << line;
  const uint64_t variance_images = report["noise_model"]["variance_images"].get<uint64_t>();
  const uint64_t ignored = report["noise_model"]["variance_images_ignored"].get<uint64_t>();
  if (variance_images > 0 || ignored > 0) {
    std::snprintf(line, sizeof line,
                  "  weights: per-pixel variance (images[].variance) for %llu of %llu images%s%s\n",
                  (unsigned long long)variance_images, (unsigned long long)images,
                  variance_images < images ? ", noise model for the rest" : "",
                  ignored > 0 ? " (the capture has variance images; --variance-weights uses them)"
                              : "");
    text << line;
  }
  if (report.contains("height_field")) {
    const Json& hf = report["height_field"];
    if (hf.contains("residual_rms_px")) {
      std::snprintf(line, sizeof line,
                    "  cast shadows from the normal map's height field: %llu samples shadowed "
                    "(integration residual rms %.2f px, heights %.0f..%.0f px)\n",
                    (unsigned long long)report["samples_rejected"]["shadowed"].get<uint64_t>(),
                    hf["residual_rms_px"].get<double>(), hf["height_range_px"][0].get<double>(),
                    hf["height_range_px"][1].get<double>());
      text << line;
    } else {
      text << "  cast shadows: not tested (height field " << hf["cast_shadows"].get<std::string>()
           << ")\n";
    }
  }
  if (report.contains("vulkan")) {
    const Json& vk = report["vulkan"];
    std::snprintf(line, sizeof line, "  backend vulkan on %s (light map: %s, %d px)\n",
                  report["device"].get<std::string>().c_str(),
                  vk["light_map"].get<std::string>().c_str(), vk["light_map_resolution"].get<int>());
    text << line;
  }
  if (report.contains("mask_agreement")) {
    const Json& a = report["mask_agreement"];
    std::snprintf(line, sizeof line,
                  "  mask agreement with Embree: %.3f %% of %llu pairs; %llu disagreements, "
                  "%llu of them within %d px of a depth or shadow edge\n",
                  100.0 * a["agreeing_fraction"].get<double>(),
                  (unsigned long long)a["pairs_compared"].get<uint64_t>(),
                  (unsigned long long)a["disagreeing"].get<uint64_t>(),
                  (unsigned long long)a["near_edge"].get<uint64_t>(), kNearEdgePixels);
    text << line;
  }
  return text.str();
}

}  // namespace reflcap::resample
