// Albedo fill (engine/fit/albedo_fill.h): which texels are filled, from whom, how far a hole
// fills, and that the texels with samples never change. Built on small atlases whose fits are set
// by hand.
#include "engine/fit/albedo_fill.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <utility>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/fit/fit_store.h"
#include "tests/engine/fit/fit_test_util.h"
#include "engine/fit/problem.h"

namespace reflcap::fit {
namespace {

using testing::LineAtlas;
using testing::StoreOf;

// A fitted texel: albedo `rho`, a lobe, samples and residuals.
TexelFit Seen(const std::array<float, 3>& rho) {
  TexelFit f;
  f.params.num_lobes = 1;
  f.params.rho_d = rho;
  for (int c = 0; c < brdf::kChannels; ++c) f.params.lobes[0][c] = brdf::MirrorLobe(0.5, 40.0);
  f.status = FitStatus::kConverged;
  f.samples = 30;
  f.residuals = 90;
  return f;
}

// A texel with no valid sample, as the fitter leaves it: zero parameters, kTooFewSamples.
TexelFit Unseen() {
  TexelFit f;
  BeginTexel(1, &f);
  f.status = FitStatus::kTooFewSamples;
  return f;
}

TEST(AlbedoFill, AnUnseenTexelTakesTheMeanAlbedoOfItsSeenNeighbours) {
  // seen(0.2) unseen seen(0.6) . . . . seen(0.9): the window of radius 2 around texel 1 holds
  // texels 0 and 2 (texel 3 is unseen too, and filled in the same round, so not read).
  const std::array<float, 3> a{0.2f, 0.3f, 0.4f}, b{0.6f, 0.5f, 0.4f}, far{0.9f, 0.9f, 0.9f};
  FitStore store = StoreOf({Seen(a), Unseen(), Seen(b), Unseen(), Unseen(), Unseen(), Unseen(),
                          Unseen(), Seen(far)});
  std::vector<uint8_t> filled;
  const AlbedoFillStats stats =
      FillUnseenAlbedo(LineAtlas(9), AlbedoFillOptions{}, &store, &filled);
  EXPECT_EQ(stats.unseen, 6u);
  EXPECT_EQ(stats.filled, 6u);
  const TexelFit t1 = store.Get(1);
  for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(t1.params.rho_d[c], 0.5f * (a[c] + b[c]));
  // The filled texel keeps what it was: no lobe, kTooFewSamples, no samples.
  EXPECT_EQ(t1.status, FitStatus::kTooFewSamples);
  EXPECT_EQ(t1.params.lobes[0][0].cz, 0.0f);
  EXPECT_EQ(t1.residuals, 0);
  EXPECT_EQ(filled, (std::vector<uint8_t>{0, 1, 0, 1, 1, 1, 1, 1, 0}));
  // Texel 3 (round 0, like texel 1) reads texel 2 only: b.
  EXPECT_FLOAT_EQ(store.Get(3).params.rho_d[0], b[0]);
  // The seen texels are untouched, lobes included.
  EXPECT_EQ(store.Get(0).params.rho_d, a);
  EXPECT_EQ(store.Get(8).params.rho_d, far);
  EXPECT_EQ(store.Get(0).params.lobes[0][0].cz, Seen(a).params.lobes[0][0].cz);
}

TEST(AlbedoFill, AHoleFillsInwardsUpToRadiusTimesRounds) {
  // One seen texel, then 10 unseen: radius 2 x 3 rounds reaches 6 texels in.
  std::vector<TexelFit> fits = {Seen({0.5f, 0.5f, 0.5f})};
  for (int i = 0; i < 10; ++i) fits.push_back(Unseen());
  FitStore store = StoreOf(fits);
  AlbedoFillOptions options;
  options.radius = 2;
  options.rounds = 3;
  std::vector<uint8_t> filled;
  const AlbedoFillStats stats = FillUnseenAlbedo(LineAtlas(11), options, &store, &filled);
  EXPECT_EQ(stats.unseen, 10u);
  EXPECT_EQ(stats.filled, 6u);
  EXPECT_EQ(stats.rounds, 3);
  for (int t = 1; t <= 6; ++t) {
    EXPECT_EQ(filled[t], 1) << t;
    EXPECT_FLOAT_EQ(store.Get(t).params.rho_d[1], 0.5f) << t;
  }
  for (int t = 7; t <= 10; ++t) {
    EXPECT_EQ(filled[t], 0) << t;
    EXPECT_EQ(store.Get(t).params.rho_d[1], 0.0f) << t;
  }
}

TEST(AlbedoFill, ALargeAtlasFillsRoundByRoundWhateverTheThreads) {
  // A 160 x 160 atlas (25,600 texels: the fill's parallel loops cut it into many tasks) seen
  // everywhere but a 70 x 70 hole and a scatter of single texels, each seen texel with its own
  // albedo. Expected: exactly what the rounds define, computed here one texel at a time (a
  // round reads the albedos of the texels seen or filled before it), the same on 1, 2 and 3
  // threads; the hole's centre is 35 texels from its rim, beyond 2 x 16, so some stay unseen.
  constexpr int kSide = 160;
  TexelAtlas atlas;
  atlas.width = atlas.height = kSide;
  std::vector<TexelFit> fits;
  for (int y = 0; y < kSide; ++y) {
    for (int x = 0; x < kSide; ++x) {
      atlas.pixel_of_texel.push_back(uint32_t(y * kSide + x));
      const bool hole = (x >= 45 && x < 115 && y >= 45 && y < 115) || (x * 7 + y * 13) % 17 == 0;
      fits.push_back(hole ? Unseen()
                          : Seen({0.1f + 0.005f * float(x % 100), 0.2f + 0.004f * float(y % 100),
                                  0.3f + 0.001f * float((x + y) % 100)}));
    }
  }
  const AlbedoFillOptions options;
  // The reference.
  std::vector<std::array<float, 3>> rho(fits.size());
  std::vector<uint8_t> known(fits.size()), expected_filled(fits.size(), 0);
  for (size_t t = 0; t < fits.size(); ++t) {
    rho[t] = fits[t].params.rho_d;
    known[t] = fits[t].residuals > 0;
  }
  int expected_rounds = 0;
  for (int round = 0; round < options.rounds; ++round) {
    std::vector<std::pair<size_t, std::array<float, 3>>> updates;
    for (size_t t = 0; t < fits.size(); ++t) {
      if (known[t]) continue;
      const int x0 = int(t) % kSide, y0 = int(t) / kSide, r = options.radius;
      std::array<double, 3> sum{};
      int n = 0;
      for (int y = std::max(0, y0 - r); y <= std::min(kSide - 1, y0 + r); ++y) {
        for (int x = std::max(0, x0 - r); x <= std::min(kSide - 1, x0 + r); ++x) {
          const size_t d = size_t(y * kSide + x);
          if (!known[d]) continue;
          for (int c = 0; c < 3; ++c) sum[size_t(c)] += rho[d][size_t(c)];
          ++n;
        }
      }
      if (n > 0) {
        updates.push_back({t, {float(sum[0] / n), float(sum[1] / n), float(sum[2] / n)}});
      }
    }
    if (updates.empty()) break;
    for (const auto& [t, value] : updates) {
      rho[t] = value;
      known[t] = 1;
      expected_filled[t] = 1;
    }
    ++expected_rounds;
  }
  ASSERT_EQ(expected_rounds, options.rounds);  // the hole is not filled before the last round
  ASSERT_NE(std::count(expected_filled.begin(), expected_filled.end(), 1), 0);
  ASSERT_NE(std::count(known.begin(), known.end(), 0), 0);  // the hole's centre stays unseen

  for (int threads : {1, 2, 3}) {
    FitStore store = StoreOf(fits);
    std::vector<uint8_t> filled;
    const AlbedoFillStats stats = FillUnseenAlbedo(atlas, options, &store, &filled, threads);
    EXPECT_EQ(stats.rounds, expected_rounds) << threads << " threads";
    EXPECT_EQ(filled, expected_filled) << threads << " threads";
    for (size_t t = 0; t < fits.size(); ++t) {
      ASSERT_EQ(store.Get(t).params.rho_d, rho[t]) << "texel " << t << ", " << threads << " threads";
    }
  }
}

TEST(AlbedoFill, DisabledOrNothingToFillChangesNothing) {
  FitStore store = StoreOf({Seen({0.5f, 0.5f, 0.5f}), Unseen()});
  AlbedoFillOptions off;
  off.enabled = false;
  std::vector<uint8_t> filled;
  AlbedoFillStats stats = FillUnseenAlbedo(LineAtlas(2), off, &store, &filled);
  EXPECT_EQ(stats.filled, 0u);
  EXPECT_EQ(filled, (std::vector<uint8_t>{0, 0}));
  EXPECT_EQ(store.Get(1).params.rho_d[0], 0.0f);
  // No seen texel anywhere: nothing to draw on.
  FitStore dark = StoreOf({Unseen(), Unseen(), Unseen()});
  stats = FillUnseenAlbedo(LineAtlas(3), AlbedoFillOptions{}, &dark, &filled);
  EXPECT_EQ(stats.unseen, 3u);
  EXPECT_EQ(stats.filled, 0u);
  EXPECT_EQ(stats.rounds, 0);
}

TEST(AlbedoFill, OptionsAreValidated) {
  AlbedoFillOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.radius = 0;
  EXPECT_FALSE(o.Validate().ok());
  o.radius = 2;
  o.rounds = 0;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace reflcap::fit
