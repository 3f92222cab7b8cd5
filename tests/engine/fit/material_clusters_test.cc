// Material clusters (engine/fit/material_clusters.h): which texels form a material, which lobe
// the material's pooled samples choose, and which texels take it. Fits are set by hand, samples
// rendered from known BRDFs, all texels in one chunk.
#include "engine/fit/material_clusters.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdint>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/fit/fit_store.h"
#include "engine/fit/lobe_transfer.h"
#include "tests/engine/fit/fit_test_util.h"
#include "tests/engine/fit/transfer_fixtures.h"

namespace reflcap::fit {
namespace {

using testing::Chunk;
using testing::Direction;
using testing::DonorFit;
using testing::Glossy;
using testing::RecipientFit;
using testing::Samples;
using testing::StoreOf;

// Samples of `truth` around its highlight, as a texel that saw it: wi at 20..65 degrees, wo at the
// same elevation, azimuth 180 + offsets of -12..12 degrees (the n = 40 lobe falls to ~1/4 of its
// peak at 12 degrees off the mirror direction) and some far from it. Exact values, sigma 0.01 / sr.
std::vector<BrdfSample> HighlightSamples(const brdf::BrdfParams& truth, int texel) {
  std::vector<BrdfSample> out;
  for (int i = 0; i < 40; ++i) {
    const double theta = 20 + 5 * ((i + texel) % 10);
    const double phi = i < 30 ? 180 - 12 + 0.8 * ((i * 7 + texel) % 31) : 60 + 7 * (i - 30);
    out.push_back(testing::ExactSample(truth, Direction(theta, 0), Direction(theta, phi)));
  }
  return out;
}

brdf::BrdfParams Matte(const std::array<float, 3>& rho) {
  brdf::BrdfParams p;
  p.num_lobes = 1;
  p.rho_d = rho;
  for (int c = 0; c < brdf::kChannels; ++c) p.lobes[0][c] = {0, 0, 0, 20};
  return p;
}

// A texel that saw its mirror configuration and showed no lobe: kConverged, Lambert-only.
TexelFit LobeAbsentFit(const std::array<float, 3>& rho) {
  TexelFit f = RecipientFit(rho);
  f.status = FitStatus::kConverged;
  f.samples = 40;
  return f;
}

// Runs the three steps on one chunk holding every texel.
MaterialClusterStats RunClusters(const TexelSampleChunk& chunk, FitStore* store, int threads = 1,
                                 MaterialClusters* out = nullptr) {
  FitOptions options;
  options.threads = threads;
  MaterialClusterStats stats;
  MaterialClusters clusters = BuildMaterialClusters(*store, options.clusters, &stats);
  StashClusterSamples(chunk, options.min_cos_theta, &clusters);
  ChooseClusterLobes(options, &clusters, &stats);
  ApplyClusterLobes(chunk, clusters, options, store, &stats);
  if (out) *out = std::move(clusters);
  return stats;
}

const std::array<float, 3> kGlossyAlbedo = {0.4f, 0.3f, 0.2f};
const std::array<float, 3> kMatteAlbedo = {0.2f, 0.5f, 0.6f};

TEST(MaterialClusters, AGlossyMaterialLendsItsLobeAndAMatteOneNothing) {
  // Texels 0..39 glossy donors, 40..99 glossy texels that never saw the highlight, 100..139
  // matte texels that saw their mirror configuration, 140..199 matte texels that did not.
  const brdf::BrdfParams glossy = Glossy();
  const brdf::BrdfParams matte = Matte(kMatteAlbedo);
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 200; ++t) {
    if (t < 40) {
      fits.push_back(DonorFit(glossy));
      samples.push_back(HighlightSamples(glossy, t));
    } else if (t < 100) {
      fits.push_back(RecipientFit(kGlossyAlbedo));
      samples.push_back(Samples(glossy, false));
    } else if (t < 140) {
      fits.push_back(LobeAbsentFit(kMatteAlbedo));
      samples.push_back(HighlightSamples(matte, t));
    } else {
      fits.push_back(RecipientFit(kMatteAlbedo));
      samples.push_back(Samples(matte, false));
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore store = StoreOf(fits);
  MaterialClusters clusters;
  const MaterialClusterStats stats = RunClusters(chunk, &store, 1, &clusters);
  // Two albedos, each exact: two clusters, no spread left to split.
  EXPECT_EQ(stats.clusters, 2);
  EXPECT_EQ(stats.clustered_texels, 200u);
  EXPECT_EQ(clusters.cluster_of[0], clusters.cluster_of[99]);
  EXPECT_EQ(clusters.cluster_of[100], clusters.cluster_of[199]);
  EXPECT_NE(clusters.cluster_of[0], clusters.cluster_of[100]);
  EXPECT_EQ(stats.clusters_with_lobe, 1);
  EXPECT_EQ(stats.recipients, 120u);
  EXPECT_EQ(stats.transferred, 60u);  // every glossy texel that missed its highlight
  EXPECT_EQ(stats.no_lobe, 60u);      // the matte cluster has no lobe to lend
  for (size_t t = 40; t < 100; ++t) {
    EXPECT_EQ(store.donor(t), FitStore::kClusterLobe) << t;
    const TexelFit f = store.Get(t);
    EXPECT_FALSE(f.lambert_only);
    EXPECT_EQ(f.status, FitStatus::kUnidentifiableLobe);  // the material's lobe, not measured
    // Exact samples and exact donors: the lobe is the truth's to the refinement's tolerance
    // (1e-5 relative steps) and the albedo re-fit's float sums (1e-4 relative).
    EXPECT_NEAR(f.params.lobes[0][0].n, glossy.lobes[0][0].n, 1e-3 * glossy.lobes[0][0].n);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(f.params.rho_d[c], glossy.rho_d[c], 1e-3);
  }
  for (size_t t = 100; t < 200; ++t) {
    EXPECT_EQ(store.donor(t), FitStore::kNoDonor) << t;
    EXPECT_TRUE(store.lambert_only(t)) << t;
  }
  // The donors keep their own (exact) lobes: the cluster's cannot beat them by the criterion.
  for (size_t t = 0; t < 40; ++t) EXPECT_EQ(store.donor(t), FitStore::kNoDonor) << t;
}

// Samples 25-45 degrees from the mirror direction (and a few far from it), every elevation and
// azimuth: a texel that missed its highlight but saw the lobe's flank, where a broad lobe still
// shows and a sharp one has fallen to nothing.
std::vector<BrdfSample> FlankSamples(const brdf::BrdfParams& truth, int texel) {
  std::vector<BrdfSample> out;
  for (int i = 0; i < 36; ++i) {
    const double theta = 20 + 5 * ((i + texel) % 10), phi = 37.0 * i + 11.0 * texel;
    const double off = i < 30 ? 40 + 2 * ((i * 7 + texel) % 15) : 120;  // azimuth from mirror
    out.push_back(testing::ExactSample(truth, Direction(theta, phi), Direction(theta, phi + 180 + off)));
  }
  return out;
}

TEST(MaterialClusters, ARecipientWhoseSamplesContradictItsClustersLobeTakesTheLobeTheyShow) {
  // Two materials with lobes: A (the glossy albedo, n = 40) and B (another albedo, a broad n = 8
  // lobe). Texels 80..99 are A's that missed the highlight; 100..119 have A's albedo — so they
  // cluster with A — but B's lobe (a texture patch of B whose colour matches A's): their flank
  // samples show a lobe that A's (fallen to nothing there) cannot, and B's fits them exactly.
  const brdf::BrdfParams glossy = Glossy();
  brdf::BrdfParams broad;
  broad.num_lobes = 1;
  broad.rho_d = kMatteAlbedo;
  for (int c = 0; c < 3; ++c) broad.lobes[0][size_t(c)] = brdf::MirrorLobe(0.3, 8);
  brdf::BrdfParams patch = broad;
  patch.rho_d = kGlossyAlbedo;
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 120; ++t) {
    if (t < 40) {
      fits.push_back(DonorFit(glossy));
      samples.push_back(HighlightSamples(glossy, t));
    } else if (t < 80) {
      fits.push_back(DonorFit(broad));
      samples.push_back(HighlightSamples(broad, t));
    } else {
      fits.push_back(RecipientFit(kGlossyAlbedo));
      samples.push_back(FlankSamples(t < 100 ? glossy : patch, t));
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore store = StoreOf(fits);
  MaterialClusters clusters;
  const MaterialClusterStats stats = RunClusters(chunk, &store, 1, &clusters);
  ASSERT_EQ(stats.clusters, 2);
  ASSERT_EQ(stats.clusters_with_lobe, 2);
  EXPECT_EQ(clusters.cluster_of[80], clusters.cluster_of[0]);
  EXPECT_EQ(clusters.cluster_of[100], clusters.cluster_of[0]);  // the albedo says A
  EXPECT_EQ(stats.foreign_lent, 20u);
  for (size_t t = 80; t < 120; ++t) {
    ASSERT_EQ(store.donor(t), FitStore::kClusterLobe) << t;
    const TexelFit f = store.Get(t);
    const brdf::BrdfParams& want = t < 100 ? glossy : broad;
    // The cluster's pooled lobe: the truth's to the refinement's tolerance (1 %).
    EXPECT_NEAR(f.params.lobes[0][0].n, want.lobes[0][0].n, 1e-2 * want.lobes[0][0].n) << t;
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(f.params.rho_d[size_t(c)], kGlossyAlbedo[size_t(c)], 1e-2) << t;
  }
}

// A recipient of a sharp material whose samples reach the lobe's tail only, reading less there
// than the lobe predicts by `tail_share` of it (as a direction error of a fraction of a degree
// makes them: the tail of n = 250 moves +-75 % per 0.5 degrees): 60 samples, 8 of them 15
// degrees from the mirror direction (the tail ~3 sigma), the rest 40+ degrees away; sigma 1 %
// of the value, deviations of 2 sigma with alternating signs.
std::vector<BrdfSample> TailSamples(const brdf::BrdfParams& truth, int texel, double tail_share) {
  std::vector<BrdfSample> out;
  brdf::BrdfParams lambert = truth;
  for (int c = 0; c < 3; ++c) lambert.lobes[0][size_t(c)] = {0, 0, 0, 1};
  for (int i = 0; i < 60; ++i) {
    const double theta = 30 + 3 * ((i + texel) % 8), phi = 29.0 * i;
    // Azimuth offset of wo from the mirror direction that puts it `a` degrees from it:
    // cos a = sin^2 theta cos off + cos^2 theta.
    const double st = std::sin(DegToRad(theta)), ct = std::cos(DegToRad(theta));
    const double off = i < 8 ? RadToDeg(std::acos((std::cos(DegToRad(15.0)) - ct * ct) / (st * st)))
                             : 40 + 2 * (i % 30);
    const Vec3f wi = Direction(theta, phi), wo = Direction(theta, phi + 180 + off);
    BrdfSample s = testing::ExactSample(truth, wi, wo);
    const BrdfSample flat = testing::ExactSample(lambert, wi, wo);
    for (int c = 0; c < 3; ++c) {
      const double tail = s.value[c] - flat.value[c];
      const double y = (flat.value[c] + (1 - tail_share) * tail) * (1 + 0.02 * (i % 2 ? 1 : -1));
      s.value[c] = float(y);
      s.weight[c] = float(1 / std::pow(0.01 * flat.value[c], 2));
    }
    s.image = uint32_t(i);
    out.push_back(s);
  }
  return out;
}

TEST(MaterialClusters, ASharpLobesTailReadingSlightlyLowIsNoContradiction) {
  // Texels 40..47 read 55 % of the tail low: the lobe costs them more than Lambert by more than
  // the absolute bar (2) but less than 5 % of their Lambert cost, and they take it; texels
  // 48..55 read none of it: a contradiction, refused.
  const brdf::BrdfParams sharp = [] {
    brdf::BrdfParams p = Glossy();
    for (int c = 0; c < 3; ++c) p.lobes[0][size_t(c)] = brdf::MirrorLobe(20, 250);
    return p;
  }();
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 56; ++t) {
    fits.push_back(t < 40 ? DonorFit(sharp) : RecipientFit(kGlossyAlbedo));
    samples.push_back(t < 40 ? HighlightSamples(sharp, t) : TailSamples(sharp, t, t < 48 ? 0.55 : 1.0));
  }
  // The scenario's premise, on the recipients' own samples: the true lobe against Lambert.
  for (int t : {40, 48}) {
    std::vector<UsableSample> usable;
    for (const BrdfSample& x : samples[size_t(t)]) usable.push_back(PrepareUsableSample(x, 0.0));
    std::array<float, 3> rho{};
    const double lambert = RefitAlbedoCost(samples[size_t(t)].data(), 60, usable.data(), nullptr, &rho);
    const double lobe = RefitAlbedoCost(samples[size_t(t)].data(), 60, usable.data(), &sharp, &rho);
    std::printf("texel %d: Lambert %.1f, the true lobe %.1f\n", t, lambert, lobe);
    if (t == 40) {
      ASSERT_GT(lobe - lambert, 2.0);
      ASSERT_LT(lobe - lambert, 0.05 * lambert);
    } else {
      ASSERT_GT(lobe - lambert, 0.05 * lambert);
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore store = StoreOf(fits);
  const MaterialClusterStats stats = RunClusters(chunk, &store);
  ASSERT_EQ(stats.clusters_with_lobe, 1);
  for (size_t t = 40; t < 56; ++t) {
    EXPECT_EQ(store.donor(t), t < 48 ? FitStore::kClusterLobe : FitStore::kNoDonor) << t;
  }
  EXPECT_EQ(stats.rejected, 8u);
}

TEST(MaterialClusters, ThePooledFitRecoversTheLobeNoDonorGotRight) {
  // Every donor's own fit is off in n by up to +-25 % (too few samples near the peak, say); the
  // samples are the truth's. The refinement on the pooled samples finds n = 40 again, and the
  // texels that never saw the highlight get that lobe, not a donor's.
  const brdf::BrdfParams truth = Glossy();
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 100; ++t) {
    if (t < 40) {
      brdf::BrdfParams off = truth;
      const double n = 40 * (0.75 + 0.5 * (t % 9) / 8.0 + (t % 9 == 4 ? 0.05 : 0.0));
      for (int c = 0; c < 3; ++c) off.lobes[0][c] = brdf::MirrorLobe(0.5, n);
      fits.push_back(DonorFit(off));
      samples.push_back(HighlightSamples(truth, t));
    } else {
      fits.push_back(RecipientFit(kGlossyAlbedo));
      samples.push_back(Samples(truth, false));
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore store = StoreOf(fits);
  const MaterialClusterStats stats = RunClusters(chunk, &store);
  EXPECT_EQ(stats.refined, 1);
  EXPECT_EQ(stats.transferred, 60u);
  // Exact pooled samples: the refined n within 0.1 % of the truth; the best donor is >= 5 % off.
  EXPECT_NEAR(store.Get(50).params.lobes[0][0].n, 40.0, 0.04);
  // The donors whose own n is off by 25 % or 19 % (t % 9 in {0, 1, 7, 8}) take the material's
  // lobe by the information criterion; those within 6 % (t % 9 in {3, 4, 5}) keep their own:
  // with 120 residuals the criterion lets 12 more parameters buy a cost drop of 6 ln 120 = 29.
  EXPECT_EQ(stats.replaced, 18u);
  for (size_t t = 0; t < 40; ++t) {
    const int level = int(t % 9);
    if (level <= 1 || level >= 7) {
      EXPECT_EQ(store.donor(t), FitStore::kClusterLobe) << t;
    }
    if (level >= 3 && level <= 5) {
      EXPECT_EQ(store.donor(t), FitStore::kNoDonor) << t;
    }
  }
}

TEST(MaterialClusters, AClusterWhoseSamplesContradictTheLobeLendsNothing) {
  // One albedo, two materials: 30 glossy donors and 90 matte texels that saw their mirror
  // configuration (lobe absent). Any glossy lobe contradicts three quarters of the pool: the
  // matte recipients must not get it.
  const brdf::BrdfParams glossy = Glossy();
  const brdf::BrdfParams matte = Matte(kGlossyAlbedo);
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 160; ++t) {
    if (t < 30) {
      fits.push_back(DonorFit(glossy));
      samples.push_back(HighlightSamples(glossy, t));
    } else if (t < 120) {
      fits.push_back(LobeAbsentFit(kGlossyAlbedo));
      samples.push_back(HighlightSamples(matte, t));
    } else {
      fits.push_back(RecipientFit(kGlossyAlbedo));
      samples.push_back(Samples(matte, false));
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore store = StoreOf(fits);
  const MaterialClusterStats stats = RunClusters(chunk, &store);
  EXPECT_EQ(stats.clusters, 1);
  EXPECT_EQ(stats.clusters_with_lobe, 0);
  EXPECT_EQ(stats.transferred, 0u);
  EXPECT_EQ(stats.no_lobe, 40u);
  for (size_t t = 30; t < 160; ++t) EXPECT_TRUE(store.lambert_only(t)) << t;
}

TEST(MaterialClusters, ATexelWhoseSamplesShowAnotherLobeKeepsItsOwn) {
  // 60 texels of the material, 40 of them donors; texel 59 is a donor whose samples show a much
  // sharper lobe (n = 200) and whose own fit has it: the material's lobe costs it far more than
  // the criterion allows, so it keeps its own. The same for the threads: 1 and 2 agree exactly.
  const brdf::BrdfParams truth = Glossy();
  brdf::BrdfParams sharp = truth;
  for (int c = 0; c < 3; ++c) sharp.lobes[0][c] = brdf::MirrorLobe(0.5, 200);
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 60; ++t) {
    const bool odd = t == 59;
    if (t < 40 || odd) {
      fits.push_back(DonorFit(odd ? sharp : truth));
      samples.push_back(HighlightSamples(odd ? sharp : truth, t));
    } else {
      fits.push_back(RecipientFit(kGlossyAlbedo));
      samples.push_back(Samples(truth, false));
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore one = StoreOf(fits), two = StoreOf(fits);
  RunClusters(chunk, &one, 1);
  RunClusters(chunk, &two, 2);
  EXPECT_EQ(one.donor(59), FitStore::kNoDonor);
  EXPECT_EQ(one.Get(59).params.lobes[0][0].n, 200.0f);
  EXPECT_EQ(one.donor(45), FitStore::kClusterLobe);
  for (size_t t = 0; t < 60; ++t) {
    for (int i = 0; i < one.ParamsPerTexel(); ++i) {
      ASSERT_EQ(one.params(t)[i], two.params(t)[i]) << t << " " << i;
    }
    EXPECT_EQ(one.donor(t), two.donor(t));
  }
}

TEST(MaterialClusters, AClusterWithoutEvidenceTakesTheNearestEvidencedMaterialsVerdict) {
  // Texels 0..39 glossy donors and 40..79 glossy texels that missed the highlight; 80..119 matte
  // texels that saw their mirror configuration (lobe absent); 120..159 texels of a redder albedo
  // and 160..199 texels of a greener one, none of which saw a highlight or measured its absence.
  // Each group's albedo is exact, so five clusters form. The red one is nearest the glossy
  // material and takes its lobe; the green one is nearest the matte material and takes nothing,
  // though it is a lobe-bearing cluster's recipient by nothing but distance in albedo.
  const brdf::BrdfParams glossy = Glossy();
  brdf::BrdfParams red = glossy;
  red.rho_d = {0.5f, 0.3f, 0.2f};
  const std::array<float, 3> green_albedo = {0.28f, 0.5f, 0.52f};
  const brdf::BrdfParams matte = Matte(kMatteAlbedo), green = Matte(green_albedo);
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 200; ++t) {
    if (t < 40) {
      fits.push_back(DonorFit(glossy));
      samples.push_back(HighlightSamples(glossy, t));
    } else if (t < 80) {
      fits.push_back(RecipientFit(kGlossyAlbedo));
      samples.push_back(Samples(glossy, false));
    } else if (t < 120) {
      fits.push_back(LobeAbsentFit(kMatteAlbedo));
      samples.push_back(HighlightSamples(matte, t));
    } else if (t < 160) {
      fits.push_back(RecipientFit(red.rho_d));
      samples.push_back(Samples(red, false));
    } else {
      fits.push_back(RecipientFit(green_albedo));
      samples.push_back(Samples(green, false));
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore store = StoreOf(fits);
  MaterialClusters clusters;
  const MaterialClusterStats stats = RunClusters(chunk, &store, 1, &clusters);
  EXPECT_EQ(stats.clusters, 4);  // glossy (both groups), matte, red, green
  const int32_t glossy_k = clusters.cluster_of[0], red_k = clusters.cluster_of[120],
                green_k = clusters.cluster_of[160], matte_k = clusters.cluster_of[80];
  ASSERT_NE(red_k, glossy_k);
  ASSERT_NE(green_k, matte_k);
  EXPECT_EQ(clusters.lend_from[size_t(glossy_k)], glossy_k);
  EXPECT_EQ(clusters.lend_from[size_t(matte_k)], -1);
  EXPECT_EQ(clusters.lend_from[size_t(red_k)], glossy_k);
  EXPECT_EQ(clusters.lend_from[size_t(green_k)], -1);
  EXPECT_EQ(stats.borrowing, 1);
  for (size_t t = 120; t < 160; ++t) {
    EXPECT_EQ(store.donor(t), FitStore::kClusterLobe) << t;
    // The glossy material's lobe, the red texel's own albedo (re-fitted under it).
    EXPECT_NEAR(store.Get(t).params.lobes[0][0].n, glossy.lobes[0][0].n, 1e-3 * glossy.lobes[0][0].n);
    EXPECT_NEAR(store.Get(t).params.rho_d[0], red.rho_d[0], 1e-3) << t;
  }
  for (size_t t = 160; t < 200; ++t) EXPECT_TRUE(store.lambert_only(t)) << t;
}

TEST(MaterialClusters, SparseTexelsJoinTheNearestMaterialWithinReach) {
  // 40 glossy donors and 40 texels that missed the highlight form the material. Texel 80 has one
  // sample (no highlight) and the material's albedo; texel 81 no sample but a filled albedo of the
  // material; texel 82 no sample and a filled albedo of another colour (beyond
  // kSparseAssignRadius); texel 83 no sample and no fill (albedo 0: nothing known).
  const brdf::BrdfParams glossy = Glossy();
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 84; ++t) {
    if (t < 40) {
      fits.push_back(DonorFit(glossy));
      samples.push_back(HighlightSamples(glossy, t));
    } else if (t < 80) {
      fits.push_back(RecipientFit(kGlossyAlbedo));
      samples.push_back(Samples(glossy, false));
    } else {
      TexelFit f = RecipientFit(t == 82 ? kMatteAlbedo : t == 83 ? std::array<float, 3>{0, 0, 0}
                                                                   : kGlossyAlbedo);
      f.status = FitStatus::kTooFewSamples;
      f.samples = t == 80 ? 1 : 0;
      fits.push_back(f);
      samples.push_back(t == 80 ? std::vector<BrdfSample>{Samples(glossy, false)[3]}
                                : std::vector<BrdfSample>{});
    }
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore store = StoreOf(fits);
  FitOptions options;
  MaterialClusterStats stats;
  MaterialClusters clusters = BuildMaterialClusters(store, options.clusters, &stats);
  std::vector<uint8_t> filled(84, 0);
  filled[81] = filled[82] = 1;  // texel 83 was not filled
  AssignSparseTexels(store, filled, options.clusters, &clusters, &stats);
  EXPECT_EQ(stats.sparse_assigned, 2u);  // 80 and 81
  EXPECT_EQ(clusters.cluster_of[80], clusters.cluster_of[0]);
  EXPECT_EQ(clusters.cluster_of[81], clusters.cluster_of[0]);
  EXPECT_EQ(clusters.cluster_of[82], -1);
  EXPECT_EQ(clusters.cluster_of[83], -1);
  StashClusterSamples(chunk, options.min_cos_theta, &clusters);
  ChooseClusterLobes(options, &clusters, &stats);
  ApplyClusterLobes(chunk, clusters, options, &store, &stats);
  EXPECT_EQ(stats.sparse_lent, 2u);
  EXPECT_EQ(store.donor(80), FitStore::kClusterLobe);
  EXPECT_EQ(store.donor(81), FitStore::kClusterLobe);
  // The unseen texel keeps its filled albedo (nothing to re-fit it on) under the material's lobe.
  EXPECT_EQ(store.Get(81).params.rho_d, kGlossyAlbedo);
  EXPECT_NEAR(store.Get(81).params.lobes[0][1].n, glossy.lobes[0][1].n, 1e-3 * glossy.lobes[0][1].n);
  EXPECT_TRUE(store.lambert_only(82));
  EXPECT_TRUE(store.lambert_only(83));
}

TEST(MaterialClusters, TheSplitOverManyBlocksFindsEachMaterialWhateverTheThreads) {
  // 120,000 texels: more than seven of the build's 16,384-item blocks, so its per-block sums,
  // their order and the sides' assembly from the blocks are all exercised. Six albedos (a 1 %
  // per-channel jitter: well under a unit of albedo space, so no material is split) scattered
  // over the texels. Expected: exactly six clusters, each holding one material's texels, and the
  // same clusters and centroids, bit for bit, on 1, 2 and 3 threads.
  constexpr size_t kTexels = 120000;
  const std::array<std::array<float, 3>, 6> albedo = {{{0.40f, 0.30f, 0.20f},
                                                       {0.20f, 0.50f, 0.60f},
                                                       {0.60f, 0.20f, 0.10f},
                                                       {0.10f, 0.10f, 0.10f},
                                                       {0.70f, 0.70f, 0.70f},
                                                       {0.30f, 0.60f, 0.20f}}};
  const auto material = [](size_t t) { return int((t * 2654435761u >> 7) % 6); };
  FitStore store(kTexels, 1);
  for (size_t t = 0; t < kTexels; ++t) {
    std::array<float, 3> rho = albedo[size_t(material(t))];
    for (int c = 0; c < 3; ++c) {
      const double u = double((t * 7 + size_t(c) * 13) % 101) / 100.0;  // 0 .. 1
      rho[size_t(c)] *= float(0.99 + 0.02 * u);
    }
    store.Set(t, LobeAbsentFit(rho));
  }
  MaterialClusterOptions options;
  std::vector<MaterialClusters> runs;
  for (int threads : {1, 2, 3}) {
    MaterialClusterStats stats;
    runs.push_back(BuildMaterialClusters(store, options, &stats, threads));
  }
  const MaterialClusters& one = runs[0];
  ASSERT_EQ(one.count, 6);
  std::array<int, 6> cluster_of_material;
  cluster_of_material.fill(-1);
  for (size_t t = 0; t < kTexels; ++t) {
    int& k = cluster_of_material[size_t(material(t))];
    if (k < 0) k = one.cluster_of[t];
    ASSERT_EQ(one.cluster_of[t], k) << "texel " << t << " of material " << material(t);
  }
  std::sort(cluster_of_material.begin(), cluster_of_material.end());
  EXPECT_EQ(cluster_of_material, (std::array<int, 6>{0, 1, 2, 3, 4, 5}));
  for (size_t r = 1; r < runs.size(); ++r) {
    EXPECT_EQ(runs[r].cluster_of, one.cluster_of) << "run " << r;
    EXPECT_EQ(runs[r].centroid, one.centroid) << "run " << r;
  }
}

TEST(MaterialClusters, KFoldKeepsTheTruthAndDoesNotDependOnThreads) {
  // Samples numbered as photographs (every fold filled), so step 4 takes the k-fold path: the
  // glossy donors' own lobes are refitted without each fold by the CPU fitter. Every sample is
  // exact, so whichever lobe each donor ends with — its own or the material's — must be the
  // truth's to the fits' tolerance, the recipients get the material's, and 1 and 2 threads
  // agree bit for bit.
  const brdf::BrdfParams glossy = Glossy();
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  for (int t = 0; t < 100; ++t) {
    std::vector<BrdfSample> texel = t < 40 ? HighlightSamples(glossy, t) : Samples(glossy, false);
    for (size_t s = 0; s < texel.size(); ++s) texel[s].image = uint32_t(s);
    fits.push_back(t < 40 ? DonorFit(glossy) : RecipientFit(kGlossyAlbedo));
    samples.push_back(std::move(texel));
  }
  const TexelSampleChunk chunk = Chunk(samples);
  FitStore one = StoreOf(fits), two = StoreOf(fits);
  const MaterialClusterStats stats = RunClusters(chunk, &one, 1);
  RunClusters(chunk, &two, 2);
  EXPECT_EQ(stats.transferred, 60u);
  std::printf("k-fold: %zu of 40 donors took the material's lobe\n", stats.replaced);
  // The k-fold path ran (no silent fall-back to the criterion, which keeps every exact own lobe
  // here): refitted on four fifths of its 40 samples, a donor finds no lobe evidence (30 of them
  // lie in the highlight, so it stands no 5 robust sigmas above their median) and its Lambert
  // refit predicts the fifth it did not see worse than the material's lobe.
  // KFoldRefitsStopOnceTheClusterLobeHasWonWithTheSameChoices has donors whose refits find it.
  EXPECT_GT(stats.replaced, 0u);
  for (size_t t = 0; t < 100; ++t) {
    const TexelFit f = one.Get(t);
    ASSERT_FALSE(f.lambert_only) << t;
    // n: the refinement's and the LM's tolerances on exact samples (1e-5 relative steps).
    EXPECT_NEAR(f.params.lobes[0][0].n, glossy.lobes[0][0].n, 1e-2 * glossy.lobes[0][0].n) << t;
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(f.params.rho_d[c], glossy.rho_d[c], 1e-2) << t;
    for (int i = 0; i < one.ParamsPerTexel(); ++i) {
      ASSERT_EQ(one.params(t)[i], two.params(t)[i]) << t << " " << i;
    }
    EXPECT_EQ(one.donor(t), two.donor(t)) << t;
  }
}

// 40 donors of the glossy material whose samples carry 0-10 % noise (uniform, relative), 4
// donors of a much sharper lobe (n = 200, exact), 56 recipients that never saw the highlight.
// Refitted without each fold, the material's own lobes predict the held-out fold worse than its
// lobe refined on the pooled samples and lose, most before all five folds are refitted; the
// sharp donors keep theirs after all five.
void NoisyDonorsAndSharpOnes(std::vector<TexelFit>* fits_out,
                             std::vector<std::vector<BrdfSample>>* samples_out) {
  const brdf::BrdfParams glossy = Glossy();
  brdf::BrdfParams sharp = glossy;
  for (int c = 0; c < 3; ++c) sharp.lobes[0][c] = brdf::MirrorLobe(0.5, 200);
  const double kDonorNoise[4] = {0.0, 0.01, 0.03, 0.1};
  std::vector<TexelFit>& fits = *fits_out;
  std::vector<std::vector<BrdfSample>>& samples = *samples_out;
  uint32_t state = 12345;
  const auto uniform = [&state] {  // a fixed LCG: the same noise on every platform
    state = state * 1664525u + 1013904223u;
    return double(state >> 8) / double(1u << 24);
  };
  for (int t = 0; t < 100; ++t) {
    const bool is_sharp = t >= 40 && t < 44;
    std::vector<BrdfSample> texel;
    if (t < 44) {
      // A donor as the fitter meets one: 20 samples within 12 degrees of the mirror direction
      // and 40 elsewhere, every azimuth (the lobe's three C's all identifiable), so that its
      // refits find the lobe (the evidence test: a highlight 5 robust sigmas above the median).
      for (int i = 0; i < 60; ++i) {
        const double theta = 20 + 45 * uniform(), phi = 360 * uniform();
        const double off = i < 20 ? 12 * (2 * uniform() - 1) : 30 + 150 * uniform();
        texel.push_back(testing::ExactSample(is_sharp ? sharp : glossy, Direction(theta, phi),
                                             Direction(theta, phi + 180 + off)));
      }
    } else {
      texel = Samples(glossy, false);
    }
    const double noise = t < 40 ? kDonorNoise[t % 4] : 0.0;
    for (size_t s = 0; s < texel.size(); ++s) {
      texel[s].image = uint32_t(s);
      for (int c = 0; c < 3; ++c) texel[s].value[c] *= float(1 + noise * (2 * uniform() - 1));
    }
    fits.push_back(t < 40 ? DonorFit(glossy) : is_sharp ? DonorFit(sharp) : RecipientFit(kGlossyAlbedo));
    samples.push_back(std::move(texel));
  }
}

TEST(MaterialClusters, KFoldRefitsStopOnceTheClusterLobeHasWonWithTheSameChoices) {
  // Stopping early must not change a single choice: each further fold only adds a cost >= 0 to
  // the own lobe's score.
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  NoisyDonorsAndSharpOnes(&fits, &samples);
  const TexelSampleChunk chunk = Chunk(samples);
  const auto run = [&](bool stop, FitStore* store) {
    FitOptions options;
    options.clusters.stop_decided_refits = stop;
    MaterialClusterStats stats;
    MaterialClusters clusters = BuildMaterialClusters(*store, options.clusters, &stats);
    StashClusterSamples(chunk, options.min_cos_theta, &clusters);
    ChooseClusterLobes(options, &clusters, &stats);
    ApplyClusterLobes(chunk, clusters, options, store, &stats);
    return stats;
  };
  FitStore stopped = StoreOf(fits), every = StoreOf(fits);
  const MaterialClusterStats a = run(true, &stopped), b = run(false, &every);
  std::printf("refits: %zu stopping, %zu without (%zu texels); %zu of 44 donors replaced\n",
              a.kfold_refits, b.kfold_refits, a.kfold_refit, a.replaced);
  ASSERT_EQ(a.kfold_refit, 44u);
  EXPECT_EQ(b.kfold_refits, 5 * b.kfold_refit);
  EXPECT_LT(a.kfold_refits, b.kfold_refits);  // the saving is real
  EXPECT_EQ(a.replaced, b.replaced);
  for (size_t t = 0; t < 100; ++t) {
    if (t >= 40 && t < 44) {
      EXPECT_EQ(stopped.donor(t), FitStore::kNoDonor) << t;  // the sharp lobe stays, 5 folds
    }
    EXPECT_EQ(stopped.donor(t), every.donor(t)) << t;
    for (int i = 0; i < stopped.ParamsPerTexel(); ++i) {
      ASSERT_EQ(stopped.params(t)[i], every.params(t)[i]) << t << " " << i;
    }
  }
}

TEST(MaterialClusters, KFoldRefitsBatchedOverChunksMakeThePerChunkChoices) {
  // reflcap fit scores every store chunk first and refits the own lobes of many chunks in one
  // batch (KFoldScores): each texel's refits see only its own samples, so the choices, the
  // parameters and the counts must be those of refitting chunk by chunk, whether a batch is
  // refitted after every chunk, after two, or only once every chunk is scored. Four chunks of
  // 25 texels: the donors (60 samples each) in the first two.
  std::vector<TexelFit> fits;
  std::vector<std::vector<BrdfSample>> samples;
  NoisyDonorsAndSharpOnes(&fits, &samples);
  std::vector<TexelSampleChunk> chunks;
  for (size_t first = 0; first < samples.size(); first += 25) {
    TexelSampleChunk c = Chunk({samples.begin() + std::ptrdiff_t(first),
                                samples.begin() + std::ptrdiff_t(first + 25)});
    c.first_texel = uint32_t(first);
    chunks.push_back(std::move(c));
  }
  const FitOptions options;
  const auto clusters_of = [&](const FitStore& store, MaterialClusterStats* stats) {
    MaterialClusters clusters = BuildMaterialClusters(store, options.clusters, stats);
    for (const TexelSampleChunk& c : chunks) {
      StashClusterSamples(c, options.min_cos_theta, &clusters);
    }
    ChooseClusterLobes(options, &clusters, stats);
    return clusters;
  };
  // The reference: each chunk scored, refitted and applied before the next.
  FitStore reference = StoreOf(fits);
  MaterialClusterStats want;
  {
    const MaterialClusters clusters = clusters_of(reference, &want);
    for (const TexelSampleChunk& c : chunks) {
      ApplyClusterLobes(c, clusters, options, &reference, &want);
    }
  }
  ASSERT_EQ(want.kfold_refit, 44u);
  ASSERT_GT(want.replaced, 0u);
  // 1 sample: a batch per chunk with donors; 2,000: chunks 0 and 1 together (1,500 + 1,140
  // samples); the default: one batch at the end.
  for (const uint64_t batch : {uint64_t{1}, uint64_t{2000}, KFoldScores::kRefitBatchSamples}) {
    FitStore store = StoreOf(fits);
    MaterialClusterStats got;
    const MaterialClusters clusters = clusters_of(store, &got);
    KFoldScores scores(store.size(), options, batch);
    for (const TexelSampleChunk& c : chunks) {
      ScoreClusterLobes(c, clusters, options, store, &scores, &got);
    }
    RefitOwnLobes(options, &scores, &got);
    for (const TexelSampleChunk& c : chunks) {
      ApplyClusterLobes(c, clusters, options, scores, &store, &got);
    }
    EXPECT_EQ(got.kfold_refit, want.kfold_refit) << batch;
    EXPECT_EQ(got.kfold_refits, want.kfold_refits) << batch;
    EXPECT_EQ(got.replaced, want.replaced) << batch;
    EXPECT_EQ(got.transferred, want.transferred) << batch;
    EXPECT_EQ(got.rejected, want.rejected) << batch;
    for (size_t t = 0; t < fits.size(); ++t) {
      ASSERT_EQ(store.donor(t), reference.donor(t)) << batch << " " << t;
      for (int i = 0; i < store.ParamsPerTexel(); ++i) {
        ASSERT_EQ(store.params(t)[i], reference.params(t)[i]) << batch << " " << t << " " << i;
      }
    }
  }
}

TEST(MaterialClusters, PhotographFoldsStayFilledWhenTheSplitIsPeriodic) {
  // The train photographs of a capture that holds out every k-th one (indices i % k != k - 1):
  // every fold must get a share near 1/folds — with the index modulo the fold count, k = folds
  // left one fold empty for every texel. Balanced within 25 % (200-odd photographs, 2..8 folds).
  for (int folds = 2; folds <= 8; ++folds) {
    for (int period = 2; period <= 10; ++period) {
      std::vector<int> count(size_t(folds), 0);
      int total = 0;
      for (uint32_t image = 0; image < 240; ++image) {
        if (int(image % uint32_t(period)) == period - 1) continue;
        const int f = PhotographFold(image, folds);
        ASSERT_GE(f, 0);
        ASSERT_LT(f, folds);
        ++count[size_t(f)];
        ++total;
      }
      for (int f = 0; f < folds; ++f) {
        EXPECT_GT(count[size_t(f)], 0.75 * total / folds)
            << folds << " folds, every " << period << "th held out, fold " << f;
        EXPECT_LT(count[size_t(f)], 1.25 * total / folds)
            << folds << " folds, every " << period << "th held out, fold " << f;
      }
    }
  }
}

TEST(MaterialClusters, DisabledOrLambertOnlyFitsDoNothingAndOptionsAreChecked) {
  std::vector<TexelFit> fits = {DonorFit(Glossy()), RecipientFit(kGlossyAlbedo)};
  const FitStore store = StoreOf(fits);
  MaterialClusterOptions options;
  options.enabled = false;
  MaterialClusterStats stats;
  const MaterialClusters off = BuildMaterialClusters(store, options, &stats);
  EXPECT_EQ(off.count, 0);
  EXPECT_EQ(off.cluster_of, (std::vector<int32_t>{-1, -1}));
  FitStore lambert(2, 0);
  options.enabled = true;
  EXPECT_EQ(BuildMaterialClusters(lambert, options, &stats).count, 0);
  EXPECT_TRUE(options.Validate().ok());
  options.chroma_scale = 0;
  EXPECT_FALSE(options.Validate().ok());
  options.chroma_scale = 0.02;
  options.lobes_per_cluster = kClusterLobeCandidates + 1;
  EXPECT_FALSE(options.Validate().ok());
  options.lobes_per_cluster = 3;
  options.max_clusters = 0;
  EXPECT_FALSE(options.Validate().ok());
}

}  // namespace
}  // namespace reflcap::fit
