#include "engine/texel/brdf_maps.h"

#include <gtest/gtest.h>

#include "engine/image/exr_io.h"
#include "tests/support/shapes.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {

TEST(BrdfMaps, ChannelNamesFollowTheDocumentedScheme) {
  const auto names = BrdfChannelNames(2);
  ASSERT_EQ(names.size(), 3u + 2 * 12);
  EXPECT_EQ(names[0], "rho_d.R");
  EXPECT_EQ(names[3], "lobe0.Cx.R");
  EXPECT_EQ(names[5], "lobe0.Cx.B");
  EXPECT_EQ(names[12], "lobe0.n.R");
  EXPECT_EQ(names.back(), "lobe1.n.B");
}

TEST(BrdfMaps, ExrRoundTripIsExactInFloat) {
  testing::ScratchDir dir;
  const TriangleMesh mesh = testing::MakeGridPlane(1, 1, 2, 2);
  auto atlas = BuildTexelAtlas(mesh, 9, 7);
  ASSERT_TRUE(atlas.ok());
  BrdfMaps maps;
  maps.num_lobes = 2;
  for (size_t t = 0; t < atlas->TexelCount(); ++t) {
    brdf::BrdfParams p;
    p.num_lobes = 2;
    for (int c = 0; c < 3; ++c) {
      p.rho_d[c] = 0.01f * float(t) + 0.1f * float(c);
      for (int k = 0; k < 2; ++k) p.lobes[k][c] = {-0.9f - k, -1.1f, 1.0f + 0.001f * t, 10.0f + c + 5 * k};
    }
    maps.texels.push_back(p);
  }
  ASSERT_TRUE(WriteBrdfMaps(dir / "params.exr", maps, *atlas).ok());
  auto back = ReadBrdfMaps(dir / "params.exr", *atlas);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->num_lobes, 2);
  for (size_t t = 0; t < maps.texels.size(); ++t) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(back->texels[t].rho_d[c], maps.texels[t].rho_d[c]);
      for (int k = 0; k < 2; ++k) {
        EXPECT_EQ(back->texels[t].lobes[k][c].cz, maps.texels[t].lobes[k][c].cz);
        EXPECT_EQ(back->texels[t].lobes[k][c].n, maps.texels[t].lobes[k][c].n);
      }
    }
  }
}

TEST(BrdfMaps, MissingChannelAndWrongSizeAreNamed) {
  testing::ScratchDir dir;
  auto atlas = BuildTexelAtlas(testing::MakeGridPlane(1, 1, 1, 1), 4, 4);
  ASSERT_TRUE(atlas.ok());
  ASSERT_TRUE(WriteExrChannels(dir / "bad.exr", Image(4, 4, 2), {"rho_d.R", "rho_d.G"}).ok());
  auto missing = ReadBrdfMaps(dir / "bad.exr", *atlas);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("rho_d.B"), std::string::npos);
  EXPECT_NE(missing.status().message().find("bad.exr"), std::string::npos);
  ASSERT_TRUE(WriteExrChannels(dir / "small.exr", Image(3, 4, 1), {"rho_d.R"}).ok());
  auto wrong = ReadBrdfMaps(dir / "small.exr", *atlas);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("3x4"), std::string::npos);
}

}  // namespace
}  // namespace reflcap
