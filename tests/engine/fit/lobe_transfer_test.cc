// Lobe transfer (engine/fit/lobe_transfer.h): who is a recipient, who may donate, and when the
// recipient's own samples refuse a donor's lobe. Built on a 4 x 1 atlas whose fits are set by
// hand and a chunk of samples rendered from known BRDFs.
#include "engine/fit/lobe_transfer.h"

#include <gtest/gtest.h>

#include <cmath>

#include "engine/brdf/lafortune.h"
#include "engine/math/types.h"

namespace reflcap::fit {
namespace {

// The glossy material the tests use: albedo (0.4, 0.3, 0.2) and a mirror lobe of peak `peak` / sr,
// n = 40 (half-width ~11 degrees). Peak 0.5 stays within the transfer's evidence bound (10x the
// recipient's brightest sample per channel: blue, the darkest, shows 0.2 / pi = 0.064 / sr off the
// highlight); peak 5 exceeds it.
brdf::BrdfParams Glossy(double peak = 0.5) {
  brdf::BrdfParams p;
  p.num_lobes = 1;
  p.rho_d = {0.4f, 0.3f, 0.2f};
  for (int c = 0; c < brdf::kChannels; ++c) p.lobes[0][c] = brdf::MirrorLobe(peak, 40.0);
  return p;
}

TexelFit DonorFit(const brdf::BrdfParams& p) {
  TexelFit f;
  f.params = p;
  f.status = FitStatus::kConverged;
  f.samples = 50;
  return f;
}

// A recipient as the fitter leaves it: Lambert-only (zero lobe), kUnidentifiableLobe.
TexelFit RecipientFit(const std::array<float, 3>& rho) {
  TexelFit f;
  f.params.num_lobes = 1;
  f.params.rho_d = rho;
  for (int c = 0; c < brdf::kChannels; ++c) f.params.lobes[0][c] = {0, 0, 0, 20};
  f.status = FitStatus::kUnidentifiableLobe;
  f.lambert_only = true;
  f.samples = 24;
  return f;
}

std::vector<int64_t> NoneBorrowed(size_t texels) { return std::vector<int64_t>(texels, -1); }

TexelAtlas LineAtlas(int texels) {
  TexelAtlas atlas;
  atlas.width = texels;
  atlas.height = 1;
  for (int t = 0; t < texels; ++t) atlas.pixel_of_texel.push_back(uint32_t(t));
  return atlas;
}

Vec3f Direction(double theta_deg, double phi_deg) {
  const double t = DegToRad(theta_deg), p = DegToRad(phi_deg);
  return Vec3f(float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)), float(std::cos(t)));
}

// Samples of `truth` for one texel: 24 configurations, wi at 20..70 degrees from the normal and
// azimuth 0, wo at the same elevation and azimuth 60..90 or 260..290 — at least 90 degrees of
// azimuth from the mirror direction (azimuth 180), where an n = 40 lobe is negligible — except,
// with `near_mirror`, every sixth sample, which lies exactly on the mirror direction.
std::vector<BrdfSample> Samples(const brdf::BrdfParams& truth, bool near_mirror) {
  std::vector<BrdfSample> out;
  for (int i = 0; i < 24; ++i) {
    const Vec3f wi = Direction(20 + 10 * (i % 6), 0);
    const double phi = near_mirror && i % 6 == 0 ? 180 : 60 + 10 * (i / 6) + (i % 2 ? 200 : 0);
    const Vec3f wo = Direction(20 + 10 * (i % 6), phi);
    BrdfSample s{};
    const Vec3f f = brdf::EvalRgb(truth, wi, wo);
    for (int j = 0; j < 3; ++j) {
      s.wi[j] = wi[j];
      s.wo[j] = wo[j];
      s.value[j] = f[j];
      s.weight[j] = 1e4f;  // sigma 0.01 / sr
    }
    out.push_back(s);
  }
  return out;
}

TexelSampleChunk Chunk(const std::vector<std::vector<BrdfSample>>& per_texel) {
  TexelSampleChunk chunk;
  chunk.first_texel = 0;
  chunk.texel_count = uint32_t(per_texel.size());
  chunk.offsets.push_back(0);
  for (const auto& v : per_texel) {
    chunk.samples.insert(chunk.samples.end(), v.begin(), v.end());
    chunk.offsets.push_back(chunk.samples.size());
  }
  return chunk;
}

TEST(LobeTransfer, ASimilarNeighboursLobeIsLentWhenTheSamplesAgree) {
  const brdf::BrdfParams truth = Glossy();
  // Texel 0: donor. Texel 1: the same material, never near its mirror direction. Texel 2: a
  // different material (albedo 2.5x) beside the donor. Texel 3: a donor that is Lambert-only.
  std::vector<TexelFit> fits = {DonorFit(truth), RecipientFit({0.41f, 0.3f, 0.2f}),
                                RecipientFit({1.0f, 0.75f, 0.5f}), DonorFit(truth)};
  fits[3].lambert_only = true;
  const TexelAtlas atlas = LineAtlas(4);
  LobeTransferOptions options;
  LobeTransferStats stats;
  const auto candidates = FindLobeDonors(atlas, fits, NoneBorrowed(fits.size()), options, &stats);
  EXPECT_EQ(stats.recipients, 2u);
  EXPECT_EQ(stats.no_donor, 1u);  // texel 2: no donor within the albedo tolerance
  ASSERT_EQ(candidates[1].size(), 1u);
  EXPECT_EQ(candidates[1][0], 0u);  // not texel 3: Lambert-only texels do not lend
  EXPECT_TRUE(candidates[2].empty());

  const TexelSampleChunk chunk = Chunk({Samples(truth, true), Samples(truth, false),
                                        Samples(truth, false), Samples(truth, true)});
  std::vector<int64_t> donor(4, -1);
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &fits, &donor, &stats);
  EXPECT_EQ(stats.transferred, 1u);
  EXPECT_EQ(donor[1], 0);
  EXPECT_EQ(donor[2], -1);
  EXPECT_FALSE(fits[1].lambert_only);
  EXPECT_EQ(fits[1].status, FitStatus::kUnidentifiableLobe);  // borrowed, not measured
  EXPECT_EQ(fits[1].params.lobes[0][0].n, truth.lobes[0][0].n);
  // The albedo is re-fitted with the lobe in place: the samples are exact, so it is the truth's
  // to float rounding of the least-squares sums (1e-4 relative).
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(fits[1].params.rho_d[c], truth.rho_d[c], 1e-4 * truth.rho_d[c]);
}

TEST(LobeTransfer, SamplesThatContradictTheLobeRefuseIt) {
  // The recipient is matte (no lobe at all) but its albedo matches the glossy donor's, and one
  // of its samples sits on the mirror direction, where the donor's lobe would add 0.5 / sr.
  brdf::BrdfParams matte = Glossy();
  for (int c = 0; c < 3; ++c) matte.lobes[0][c] = {0, 0, 0, 20};
  std::vector<TexelFit> fits = {DonorFit(Glossy()), RecipientFit({0.4f, 0.3f, 0.2f})};
  LobeTransferOptions options;
  LobeTransferStats stats;
  const auto candidates = FindLobeDonors(LineAtlas(2), fits, NoneBorrowed(2), options, &stats);
  ASSERT_EQ(candidates[1].size(), 1u);
  const TexelSampleChunk chunk = Chunk({Samples(Glossy(), true), Samples(matte, true)});
  std::vector<int64_t> donor(2, -1);
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &fits, &donor, &stats);
  EXPECT_EQ(stats.rejected, 1u);
  EXPECT_EQ(stats.transferred, 0u);
  EXPECT_EQ(donor[1], -1);
  EXPECT_TRUE(fits[1].lambert_only);
  EXPECT_EQ(fits[1].params.lobes[0][0].cx, 0.0f);
}

TEST(LobeTransfer, ALobeFarAboveTheRecipientsBrightestSampleIsRefused) {
  // The same material with a lobe of peak 5 / sr: 40-80x the recipient's brightest samples (it never
  // saw the highlight), beyond the evidence bound a texel's own fit is held to (problem.h).
  const brdf::BrdfParams bright = Glossy(5.0);
  std::vector<TexelFit> fits = {DonorFit(bright), RecipientFit({0.4f, 0.3f, 0.2f})};
  LobeTransferOptions options;
  LobeTransferStats stats;
  const auto candidates = FindLobeDonors(LineAtlas(2), fits, NoneBorrowed(2), options, &stats);
  ASSERT_EQ(candidates[1].size(), 1u);
  const TexelSampleChunk chunk = Chunk({Samples(bright, true), Samples(bright, false)});
  std::vector<int64_t> donor(2, -1);
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &fits, &donor, &stats);
  EXPECT_EQ(stats.rejected, 1u);
  EXPECT_EQ(donor[1], -1);
  EXPECT_TRUE(fits[1].lambert_only);
}

TEST(LobeTransfer, DisabledOrOutOfReachDoesNothing) {
  std::vector<TexelFit> fits = {DonorFit(Glossy()), RecipientFit({0.4f, 0.3f, 0.2f}),
                                RecipientFit({0.4f, 0.3f, 0.2f})};
  // Texel 2 sits 8 texels from the donor: beyond a radius of 4.
  TexelAtlas atlas = LineAtlas(3);
  atlas.width = 9;
  atlas.pixel_of_texel = {0, 1, 8};
  LobeTransferOptions options;
  options.radius = 4;
  LobeTransferStats stats;
  auto candidates = FindLobeDonors(atlas, fits, NoneBorrowed(fits.size()), options, &stats);
  EXPECT_EQ(candidates[1].size(), 1u);
  EXPECT_TRUE(candidates[2].empty());
  options.enabled = false;
  LobeTransferStats none;
  candidates = FindLobeDonors(atlas, fits, NoneBorrowed(fits.size()), options, &none);
  EXPECT_EQ(none.recipients, 0u);
  for (const auto& c : candidates) EXPECT_TRUE(c.empty());
  // Options are checked.
  options.radius = 0;
  EXPECT_FALSE(options.Validate().ok());
  options.radius = 6;
  options.albedo_tolerance = std::nan("");
  EXPECT_FALSE(options.Validate().ok());
}

TEST(LobeTransfer, ABorrowedLobeIsLentOnInTheNextRound) {
  // Donor at x = 0, recipients at x = 3 and x = 6; radius 4: the second is out of the donor's
  // reach and gets the lobe only from the first, once that has borrowed it.
  const brdf::BrdfParams truth = Glossy();
  std::vector<TexelFit> fits = {DonorFit(truth), RecipientFit({0.4f, 0.3f, 0.2f}),
                                RecipientFit({0.4f, 0.3f, 0.2f})};
  TexelAtlas atlas = LineAtlas(3);
  atlas.width = 7;
  atlas.pixel_of_texel = {0, 3, 6};
  LobeTransferOptions options;
  options.radius = 4;
  const TexelSampleChunk chunk =
      Chunk({Samples(truth, true), Samples(truth, false), Samples(truth, false)});
  std::vector<int64_t> donor = NoneBorrowed(3);
  LobeTransferStats round1, round2;
  auto candidates = FindLobeDonors(atlas, fits, donor, options, &round1);
  EXPECT_TRUE(candidates[2].empty());
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &fits, &donor, &round1);
  EXPECT_EQ(round1.transferred, 1u);
  candidates = FindLobeDonors(atlas, fits, donor, options, &round2);
  EXPECT_EQ(round2.recipients, 1u);  // texel 1 borrowed: no longer a recipient
  ASSERT_EQ(candidates[2].size(), 1u);
  EXPECT_EQ(candidates[2][0], 1u);
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &fits, &donor, &round2);
  EXPECT_EQ(donor[2], 1);
  EXPECT_EQ(fits[2].params.lobes[0][1].n, truth.lobes[0][1].n);
}

}  // namespace
}  // namespace reflcap::fit
