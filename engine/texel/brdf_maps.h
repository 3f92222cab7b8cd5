#pragma once
// BrdfMaps: Lambert + Lafortune parameters for every texel of an atlas, and their on-disk form —
// one multi-channel OpenEXR in atlas layout with one float channel per parameter:
//   rho_d.R rho_d.G rho_d.B                       diffuse albedo (f_d = rho_d / pi)
//   lobe<k>.Cx.<c> lobe<k>.Cy.<c> lobe<k>.Cz.<c>  Lafortune coefficients of lobe k, channel c
//   lobe<k>.n.<c>                                 its exponent
// for k = 0 .. num_lobes-1 and c in R, G, B. Pixels without a texel hold 0.
#include <filesystem>
#include <string>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/core/status.h"
#include "engine/image/image.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap {

struct BrdfMaps {
  int num_lobes = 0;
  std::vector<brdf::BrdfParams> texels;  // one per atlas texel, in texel order
};

// Channel names of the parameter EXR for `num_lobes`, in the order listed above.
std::vector<std::string> BrdfChannelNames(int num_lobes);

// Lays the parameters out as an image of the atlas' size with BrdfChannelNames channels.
Image BrdfMapsToImage(const BrdfMaps& maps, const TexelAtlas& atlas);
// Inverse of BrdfMapsToImage; `names` are the image's channel names (any order, extra ignored).
// InvalidArgument naming the missing channel or a size mismatch; `file` prefixes messages.
StatusOr<BrdfMaps> BrdfMapsFromImage(const Image& image, const std::vector<std::string>& names,
                                     const TexelAtlas& atlas, const std::string& file);

Status WriteBrdfMaps(const std::filesystem::path& path, const BrdfMaps& maps,
                     const TexelAtlas& atlas);
StatusOr<BrdfMaps> ReadBrdfMaps(const std::filesystem::path& path, const TexelAtlas& atlas);

}  // namespace reflcap
