// Lobe transfer (engine/fit/lobe_transfer.h): who is a recipient, who may donate, and when the
// recipient's own samples refuse a donor's lobe. Built on a 4 x 1 atlas whose fits are set by
// hand and a chunk of samples rendered from known BRDFs.
#include "engine/fit/lobe_transfer.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/fit/fit_store.h"
#include "tests/engine/fit/fit_test_util.h"
#include "tests/engine/fit/transfer_fixtures.h"
#include "engine/math/types.h"

namespace reflcap::fit {
namespace {

using testing::Chunk;
using testing::DonorFit;
using testing::Glossy;
using testing::LineAtlas;
using testing::RecipientFit;
using testing::Samples;
using testing::StoreOf;

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
  FitStore store = StoreOf(fits);
  const LobeCandidates candidates = FindLobeDonors(atlas, store, options, &stats);
  EXPECT_EQ(stats.recipients, 2u);
  EXPECT_EQ(stats.no_donor, 1u);  // texel 2: no donor within the albedo tolerance
  ASSERT_EQ(candidates.Of(1).size(), 1u);
  EXPECT_EQ(candidates.Of(1)[0], 0u);  // not texel 3: Lambert-only texels do not lend
  EXPECT_TRUE(candidates.Of(2).empty());
  EXPECT_TRUE(candidates.AnyIn(0, 2));
  EXPECT_FALSE(candidates.AnyIn(2, 4));

  const TexelSampleChunk chunk = Chunk({Samples(truth, true), Samples(truth, false),
                                        Samples(truth, false), Samples(truth, true)});
  std::vector<uint8_t> borrowed(4, 0);
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &store, &stats, &borrowed);
  EXPECT_EQ(stats.transferred, 1u);
  EXPECT_EQ(store.donor(1), 0);
  EXPECT_EQ(store.donor(2), -1);
  EXPECT_EQ(borrowed, (std::vector<uint8_t>{0, 1, 0, 0}));
  const TexelFit lent = store.Get(1);
  EXPECT_FALSE(lent.lambert_only);
  EXPECT_EQ(lent.status, FitStatus::kUnidentifiableLobe);  // borrowed, not measured
  EXPECT_EQ(lent.params.lobes[0][0].n, truth.lobes[0][0].n);
  // The albedo is re-fitted with the lobe in place: the samples are exact, so it is the truth's
  // to float rounding of the least-squares sums (1e-4 relative).
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(lent.params.rho_d[c], truth.rho_d[c], 1e-4 * truth.rho_d[c]);
}

TEST(LobeTransfer, SamplesThatContradictTheLobeRefuseIt) {
  // The recipient is matte (no lobe at all) but its albedo matches the glossy donor's, and one
  // of its samples sits on the mirror direction, where the donor's lobe would add 0.5 / sr.
  brdf::BrdfParams matte = Glossy();
  for (int c = 0; c < 3; ++c) matte.lobes[0][c] = {0, 0, 0, 20};
  std::vector<TexelFit> fits = {DonorFit(Glossy()), RecipientFit({0.4f, 0.3f, 0.2f})};
  LobeTransferOptions options;
  LobeTransferStats stats;
  FitStore store = StoreOf(fits);
  const LobeCandidates candidates = FindLobeDonors(LineAtlas(2), store, options, &stats);
  ASSERT_EQ(candidates.Of(1).size(), 1u);
  const TexelSampleChunk chunk = Chunk({Samples(Glossy(), true), Samples(matte, true)});
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &store, &stats);
  EXPECT_EQ(stats.rejected, 1u);
  EXPECT_EQ(stats.transferred, 0u);
  EXPECT_EQ(store.donor(1), -1);
  EXPECT_TRUE(store.lambert_only(1));
  EXPECT_EQ(store.Get(1).params.lobes[0][0].cx, 0.0f);
}

TEST(LobeTransfer, ALobeFarAboveTheRecipientsBrightestSampleIsRefused) {
  // The same material with a lobe of peak 5 / sr: 40-80x the recipient's brightest samples (it never
  // saw the highlight), beyond the evidence bound a texel's own fit is held to (problem.h).
  const brdf::BrdfParams bright = Glossy(5.0);
  std::vector<TexelFit> fits = {DonorFit(bright), RecipientFit({0.4f, 0.3f, 0.2f})};
  LobeTransferOptions options;
  LobeTransferStats stats;
  FitStore store = StoreOf(fits);
  const LobeCandidates candidates = FindLobeDonors(LineAtlas(2), store, options, &stats);
  ASSERT_EQ(candidates.Of(1).size(), 1u);
  const TexelSampleChunk chunk = Chunk({Samples(bright, true), Samples(bright, false)});
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &store, &stats);
  EXPECT_EQ(stats.rejected, 1u);
  EXPECT_EQ(store.donor(1), -1);
  EXPECT_TRUE(store.lambert_only(1));
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
  const FitStore store = StoreOf(fits);
  LobeCandidates candidates = FindLobeDonors(atlas, store, options, &stats);
  EXPECT_EQ(candidates.Of(1).size(), 1u);
  EXPECT_TRUE(candidates.Of(2).empty());
  options.enabled = false;
  LobeTransferStats none;
  candidates = FindLobeDonors(atlas, store, options, &none);
  EXPECT_EQ(none.recipients, 0u);
  EXPECT_TRUE(candidates.recipients.empty());
  EXPECT_TRUE(candidates.donors.empty());
  for (uint32_t t = 0; t < 3; ++t) EXPECT_TRUE(candidates.Of(t).empty());
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
  FitStore store = StoreOf(fits);
  LobeTransferStats round1, round2;
  std::vector<uint8_t> lenders(3, 0);
  LobeCandidates candidates = FindLobeDonors(atlas, store, options, &round1);
  EXPECT_TRUE(candidates.Of(2).empty());
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &store, &round1, &lenders);
  EXPECT_EQ(round1.transferred, 1u);
  EXPECT_EQ(lenders, (std::vector<uint8_t>{0, 1, 0}));
  candidates = FindLobeDonors(atlas, store, options, &round2, &lenders);
  EXPECT_EQ(round2.recipients, 1u);  // texel 1 borrowed: no longer a recipient
  ASSERT_EQ(candidates.Of(2).size(), 1u);
  EXPECT_EQ(candidates.Of(2)[0], 1u);
  ApplyLobeTransfer(chunk, candidates, options, 0.05, 1, &store, &round2);
  EXPECT_EQ(store.donor(2), 1);
  EXPECT_EQ(store.Get(2).params.lobes[0][1].n, truth.lobes[0][1].n);
}

// A plain scan of every recipient's window, as lobe_transfer.h states the rule: FindLobeDonors
// skips windows without a donor and reads a grid of the donors, and must find exactly this.
std::vector<std::vector<uint32_t>> PlainScan(const TexelAtlas& atlas, const FitStore& fits,
                                             const LobeTransferOptions& options,
                                             const std::vector<uint8_t>* lenders) {
  const auto albedo_distance = [&](size_t a, size_t b) {
    double diff = 0, na = 0, nb = 0;
    for (int c = 0; c < 3; ++c) {
      const double x = fits.params(a)[c], y = fits.params(b)[c];
      diff += (x - y) * (x - y);
      na += x * x;
      nb += y * y;
    }
    return std::sqrt(diff) / std::max({std::sqrt(na), std::sqrt(nb), 1e-3});
  };
  std::vector<std::vector<uint32_t>> out(fits.size());
  for (size_t t = 0; t < fits.size(); ++t) {
    if (!(fits.status(t) == FitStatus::kUnidentifiableLobe && fits.samples(t) >= 3 &&
          fits.lambert_only(t) && fits.donor(t) == FitStore::kNoDonor)) {
      continue;
    }
    const int xt = int(atlas.pixel_of_texel[t] % uint32_t(atlas.width));
    const int yt = int(atlas.pixel_of_texel[t] / uint32_t(atlas.width));
    std::vector<std::pair<double, uint32_t>> found;
    for (size_t d = 0; d < fits.size(); ++d) {
      const int xd = int(atlas.pixel_of_texel[d] % uint32_t(atlas.width));
      const int yd = int(atlas.pixel_of_texel[d] / uint32_t(atlas.width));
      if (std::abs(xd - xt) > options.radius || std::abs(yd - yt) > options.radius) continue;
      if (lenders && !(*lenders)[d]) continue;
      if (fits.lambert_only(d) ||
          !(fits.status(d) == FitStatus::kConverged || fits.donor(d) >= 0)) {
        continue;
      }
      const double distance = albedo_distance(t, d);
      if (distance <= options.albedo_tolerance) found.emplace_back(distance, uint32_t(d));
    }
    std::sort(found.begin(), found.end());
    for (size_t i = 0; i < found.size() && i < size_t(kMaxTransferCandidates); ++i) {
      out[t].push_back(found[i].second);
    }
  }
  return out;
}

TEST(LobeTransfer, CandidatesAreThoseOfAPlainScanOfEveryWindow) {
  // 600 texels on random pixels of a 47 x 31 atlas (a third of the pixels empty), in three
  // materials with albedo jitter around the tolerance: donors, recipients, Lambert-only texels,
  // texels that borrowed; windows clipped at all four borders. Then a later round, where only
  // random lenders lend.
  uint32_t state = 12345;
  const auto next = [&state] {
    state = state * 1664525u + 1013904223u;
    return state >> 8;
  };
  TexelAtlas atlas;
  atlas.width = 47;
  atlas.height = 31;
  std::vector<uint32_t> pixels(size_t(atlas.width * atlas.height));
  for (size_t i = 0; i < pixels.size(); ++i) pixels[i] = uint32_t(i);
  for (size_t i = pixels.size() - 1; i > 0; --i) std::swap(pixels[i], pixels[next() % (i + 1)]);
  const size_t texels = 600;
  atlas.pixel_of_texel.assign(pixels.begin(), pixels.begin() + texels);
  const std::array<std::array<float, 3>, 3> materials = {
      {{0.4f, 0.3f, 0.2f}, {0.1f, 0.5f, 0.2f}, {0.42f, 0.33f, 0.2f}}};
  std::vector<TexelFit> fits;
  std::vector<int64_t> donor_of(texels, FitStore::kNoDonor);
  for (size_t t = 0; t < texels; ++t) {
    std::array<float, 3> rho = materials[next() % 3];
    for (float& v : rho) v *= 1.0f + 0.2f * (float(next() % 1000) / 1000.0f - 0.5f);
    const uint32_t role = next() % 10;
    TexelFit f = role < 3 ? DonorFit(Glossy()) : RecipientFit(rho);
    f.params.rho_d = rho;
    if (role == 9) f.samples = 2;                  // too few samples to be a recipient
    if (role == 8) f.status = FitStatus::kConverged;  // Lambert-only, lobe absent: neither
    if (role == 7) {                               // borrowed: lends, receives no more
      f.lambert_only = false;
      donor_of[t] = int64_t(next() % texels);
    }
    fits.push_back(f);
  }
  FitStore store = StoreOf(fits);
  for (size_t t = 0; t < texels; ++t) {
    if (donor_of[t] != FitStore::kNoDonor) store.set_donor(t, donor_of[t]);
  }
  std::vector<uint8_t> lenders(texels);
  for (uint8_t& l : lenders) l = next() % 4 == 0;
  size_t found = 0, not_found = 0;
  for (int radius : {1, 3, 6}) {
    for (const std::vector<uint8_t>* lend : {static_cast<const std::vector<uint8_t>*>(nullptr),
                                             static_cast<const std::vector<uint8_t>*>(&lenders)}) {
      LobeTransferOptions options;
      options.radius = radius;
      LobeTransferStats stats;
      const LobeCandidates got = FindLobeDonors(atlas, store, options, &stats, lend);
      const std::vector<std::vector<uint32_t>> want = PlainScan(atlas, store, options, lend);
      size_t recipients = 0, with_candidates = 0;
      for (uint32_t t = 0; t < texels; ++t) {
        EXPECT_EQ(got.Of(t), want[t]) << "texel " << t << ", radius " << radius;
        with_candidates += !want[t].empty();
      }
      for (size_t t = 0; t < texels; ++t) {
        recipients += store.status(t) == FitStatus::kUnidentifiableLobe && store.samples(t) >= 3 &&
                      store.lambert_only(t) && store.donor(t) == FitStore::kNoDonor;
      }
      EXPECT_EQ(stats.recipients, recipients);
      EXPECT_EQ(stats.no_donor, recipients - with_candidates);
      found += with_candidates;
      not_found += recipients - with_candidates;
    }
  }
  // Not vacuous: many recipients find candidates, and many do not.
  EXPECT_GT(found, 100u);
  EXPECT_GT(not_found, 100u);
}

// Samples in every direction (some below the horizon: not usable), with a NaN value, a zero and
// an infinite weight, and a zeroed record among them. A fixed LCG: the same on every platform.
std::vector<BrdfSample> MixedSamples(int count) {
  uint32_t state = 7;
  const auto uniform = [&state] {
    state = state * 1664525u + 1013904223u;
    return double(state >> 8) / double(1u << 24);
  };
  std::vector<BrdfSample> out;
  for (int i = 0; i < count; ++i) {
    const double ti = 95 * uniform(), pi = 360 * uniform();
    const double to = 95 * uniform(), po = 360 * uniform();
    BrdfSample s{};
    const Vec3f wi = testing::Direction(ti, pi), wo = testing::Direction(to, po);
    for (int j = 0; j < 3; ++j) {
      s.wi[j] = wi[j];
      s.wo[j] = wo[j];
      s.value[j] = float(0.05 + uniform());
      s.weight[j] = float(1 + 100 * uniform());
    }
    s.image = uint32_t(i);
    out.push_back(s);
  }
  out[3].value[1] = std::nanf("");
  out[5].weight[0] = 0;
  out[8].weight[2] = std::numeric_limits<float>::infinity();
  out[11] = BrdfSample{};
  return out;
}

TEST(TexelResiduals, VectorLobeSumsMatchEvalChannel) {
  // EvaluateLobeSum's exp(n log b) against EvalChannel's pow, lobe by lobe and summed: broad,
  // glossy and the sharpest lobes, an off-specular one, one cut off everywhere (Cz < 0 with
  // Cx = Cy = 0 on the upper hemisphere) and one saturated (3^100 > kMaxLobeValue).
  // Tolerance: float rounding of the base (~1e-7 relative, amplified n-fold in b^n: lafortune.h)
  // plus exp/log's few ulps, relative; 1e-6 of the lobe's peak absolute, for bases that cancel.
  const std::vector<BrdfSample> samples = MixedSamples(300);
  TexelResiduals r;
  r.Prepare(samples.data(), samples.size(), 0.0);
  ASSERT_GT(r.usable(), 100u);
  ASSERT_EQ(r.padded() % 16, 0u);
  const std::vector<brdf::LobeParams> lobes = {
      {0, 0, 0.9f, 0.25f},      {-1, -1, 1, 1},       {-1.02f, -0.98f, 1, 40},
      {-1, -1, 1, 10000},       {-1.1f, -1.1f, 0.7f, 8}, {0, 0, -1, 3},
      {-3, -3, 3, 100}};
  for (size_t k = 0; k < lobes.size(); ++k) {
    brdf::BrdfParams p;
    p.num_lobes = k + 1 < lobes.size() ? 2 : 1;  // each with the next one, the last alone
    p.rho_d = {0.3f, 0.2f, 0.1f};
    for (int c = 0; c < 3; ++c) {
      p.lobes[0][size_t(c)] = lobes[k];
      if (p.num_lobes == 2) p.lobes[1][size_t(c)] = lobes[k + 1];
    }
    const float* got = r.Lobes(&p, 1);
    std::vector<float> values(got, got + r.padded());
    std::vector<float> model(r.padded());
    const float* m = r.Model(p, 2);
    model.assign(m, m + r.padded());
    double peak = 0, n_max = 0;
    for (int l = 0; l < p.num_lobes; ++l) {
      const brdf::LobeParams& q = p.lobes[size_t(l)][1];
      peak += std::min(std::pow(std::max({std::abs(q.cx), std::abs(q.cy), q.cz}), double(q.n)),
                       brdf::kMaxLobeValue);
      n_max = std::max(n_max, double(q.n));
    }
    size_t j = 0;
    for (const BrdfSample& s : samples) {
      const UsableSample u = PrepareUsableSample(s, 0.0);
      if (!u.usable) continue;
      auto channel = p.Channel(1);
      channel[0] = 0;
      const double want = brdf::EvalChannel(u.wi, u.wo, channel.data(), p.num_lobes);
      const double tolerance = 4e-7 * (n_max + 100) * std::abs(want) + 1e-6 * peak;
      ASSERT_NEAR(values[j], want, tolerance) << "lobe " << k << " sample " << j;
      const double want_model = brdf::EvalChannel(u.wi, u.wo, p.Channel(2).data(), p.num_lobes);
      ASSERT_NEAR(model[j], want_model, 4e-7 * (n_max + 100) * std::abs(want_model) + 1e-6 * peak)
          << "lobe " << k << " sample " << j;
      ++j;
    }
    ASSERT_EQ(j, r.usable());
    for (; j < r.padded(); ++j) EXPECT_EQ(values[j], 0.0f) << "padding";
  }
}

TEST(TexelResiduals, RefitAlbedoCostMatchesThePerSampleSums) {
  // The prepared residuals (invalid channels as weight 0, padding) give the per-sample
  // RefitAlbedoCost's albedo and cost, with and without lobes. 1e-5 relative: the lobes'
  // float evaluation (above); the sums are double in both.
  const std::vector<BrdfSample> samples = MixedSamples(200);
  TexelResiduals r;
  r.Prepare(samples.data(), samples.size(), 0.1);
  std::vector<UsableSample> usable;
  for (const BrdfSample& s : samples) usable.push_back(PrepareUsableSample(s, 0.1));
  const brdf::BrdfParams glossy = Glossy();
  for (const brdf::BrdfParams* p : {static_cast<const brdf::BrdfParams*>(nullptr), &glossy}) {
    std::array<float, 3> rho_a{}, rho_b{};
    const double a = RefitAlbedoCost(&r, p, &rho_a);
    const double b = RefitAlbedoCost(samples.data(), samples.size(), usable.data(), p, &rho_b);
    EXPECT_GT(b, 0.0);
    EXPECT_NEAR(a, b, 1e-5 * b);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(rho_a[size_t(c)], rho_b[size_t(c)], 1e-5) << c;
  }
}

TEST(FitStore, KeepsEveryFieldOfTheFittedLobesAndStartsAsTooFewSamples) {
  for (int lobes = 0; lobes <= brdf::kMaxLobes; ++lobes) {
    FitStore store(3, lobes);
    EXPECT_EQ(store.ParamsPerTexel(), 3 + 12 * lobes);
    // A texel no chunk held: BeginTexel's state, status kTooFewSamples, no donor.
    const TexelFit empty = store.Get(2);
    EXPECT_EQ(empty.status, FitStatus::kTooFewSamples);
    EXPECT_EQ(empty.params.num_lobes, lobes);
    EXPECT_EQ(empty.sigma.rho_d[1], -1.0f);
    EXPECT_EQ(store.donor(2), -1);
    // Every slot of the fitted lobes survives exactly; distinct values catch a swapped slot.
    TexelFit f;
    f.params.num_lobes = f.sigma.num_lobes = lobes;
    float v = 0.5f;
    for (int c = 0; c < brdf::kChannels; ++c) {
      f.params.rho_d[c] = v += 1;
      f.sigma.rho_d[c] = -v;
    }
    for (int k = 0; k < lobes; ++k) {
      for (int c = 0; c < brdf::kChannels; ++c) {
        f.params.lobes[k][c] = {v + 1, v + 2, v + 3, v + 4};
        f.sigma.lobes[k][c] = {-v - 1, -v - 2, -v - 3, -v - 4};
        v += 4;
      }
    }
    f.status = FitStatus::kMaxIterations;
    f.cost = 12.25f;
    f.iterations = 37;
    f.samples = 41;
    f.residuals = 120;
    f.lambert_only = true;
    store.Set(1, f);
    store.set_donor(1, 0);
    const TexelFit g = store.Get(1);
    EXPECT_EQ(g.params.rho_d, f.params.rho_d);
    EXPECT_EQ(g.sigma.rho_d[0], -1.0f);  // sigmas are not held (SigmaSpill)
    for (int k = 0; k < lobes; ++k) {
      for (int c = 0; c < brdf::kChannels; ++c) {
        EXPECT_EQ(g.params.lobes[k][c].cx, f.params.lobes[k][c].cx);
        EXPECT_EQ(g.params.lobes[k][c].cy, f.params.lobes[k][c].cy);
        EXPECT_EQ(g.params.lobes[k][c].cz, f.params.lobes[k][c].cz);
        EXPECT_EQ(g.params.lobes[k][c].n, f.params.lobes[k][c].n);
      }
    }
    EXPECT_EQ(g.status, f.status);
    EXPECT_EQ(g.cost, f.cost);
    EXPECT_EQ(g.iterations, f.iterations);
    EXPECT_EQ(g.samples, f.samples);
    EXPECT_EQ(g.residuals, f.residuals);
    EXPECT_TRUE(g.lambert_only);
    EXPECT_EQ(store.donor(1), 0);
    // Releasing the parameter arrays keeps the scalars the report reads.
    store.ReleaseParams();
    EXPECT_EQ(store.status(1), FitStatus::kMaxIterations);
    EXPECT_EQ(store.cost(1), 12.25f);
    EXPECT_EQ(store.residuals(1), 120);
  }
}

TEST(SigmaSpill, ReadsBackWhatWasWrittenAndUnknownElsewhere) {
  const std::filesystem::path path = std::filesystem::path(::testing::TempDir()) / "sigma.scratch";
  // Two lobes, 40000 texels: more than one read block; the chunk written straddles a block edge.
  auto spill = SigmaSpill::Create(path, 40000, 2);
  ASSERT_TRUE(spill.ok()) << spill.status().ToString();
  std::vector<TexelFit> chunk(3);
  for (size_t i = 0; i < chunk.size(); ++i) {
    chunk[i].sigma.num_lobes = 2;
    chunk[i].sigma.rho_d = {float(i), 0.5f, 0.25f};
    chunk[i].sigma.lobes[1][2] = {1.5f, 2.5f, 3.5f, float(10 + i)};
  }
  ASSERT_TRUE((*spill)->Write(16383, chunk).ok());
  size_t seen = 0;
  ASSERT_TRUE((*spill)->ReadAll([&](size_t t, const float* sigma) {
    EXPECT_EQ(t, seen++);
    if (t >= 16383 && t < 16386) {
      EXPECT_EQ(sigma[0], float(t - 16383));
      EXPECT_EQ(sigma[1], 0.5f);
      EXPECT_EQ(sigma[3], 0.0f);  // lobe 0, R, Cx
      const float* lobe1_b = sigma + 3 + 4 * (3 * 1 + 2);
      EXPECT_EQ(lobe1_b[2], 3.5f);
      EXPECT_EQ(lobe1_b[3], float(10 + t - 16383));
    } else if (t % 997 == 0) {
      for (int i = 0; i < 3 + 12 * 2; ++i) EXPECT_EQ(sigma[i], -1.0f);
    }
  }).ok());
  EXPECT_EQ(seen, 40000u);
  EXPECT_TRUE(std::filesystem::exists(path));
  EXPECT_TRUE((*spill)->Remove().ok());
  EXPECT_FALSE(std::filesystem::exists(path));
}

}  // namespace
}  // namespace reflcap::fit
