// Parameter maps <-> multi-channel EXR in atlas layout (see brdf_maps.h for the channel names).
#include "engine/texel/brdf_maps.h"

#include <map>

#include "engine/core/parallel.h"
#include "engine/image/exr_io.h"

namespace reflcap {
namespace {
constexpr const char* kChannelSuffix[3] = {"R", "G", "B"};
constexpr const char* kLobeField[4] = {"Cx", "Cy", "Cz", "n"};

// Parameter slot of channel-name index i: (lobe, field, channel); lobe -1 = rho_d.
struct Slot {
  int lobe, field, channel;
};

std::vector<Slot> Slots(int num_lobes) {
  std::vector<Slot> slots;
  for (int c = 0; c < 3; ++c) slots.push_back({-1, 0, c});
  for (int k = 0; k < num_lobes; ++k) {
    for (int f = 0; f < 4; ++f) {
      for (int c = 0; c < 3; ++c) slots.push_back({k, f, c});
    }
  }
  return slots;
}

float& SlotRef(brdf::BrdfParams& p, const Slot& s) {
  if (s.lobe < 0) return p.rho_d[s.channel];
  brdf::LobeParams& lobe = p.lobes[s.lobe][s.channel];
  switch (s.field) {
    case 0: return lobe.cx;
    case 1: return lobe.cy;
    case 2: return lobe.cz;
    default: return lobe.n;
  }
}
}  // namespace

std::vector<std::string> BrdfChannelNames(int num_lobes) {
  std::vector<std::string> names;
  for (const Slot& s : Slots(num_lobes)) {
    names.push_back(s.lobe < 0 ? StrCat("rho_d.", kChannelSuffix[s.channel])
                               : StrCat("lobe", s.lobe, ".", kLobeField[s.field], ".",
                                        kChannelSuffix[s.channel]));
  }
  return names;
}

Image BrdfMapsToImage(const BrdfMaps& maps, const TexelAtlas& atlas) {
  REFLCAP_CHECK(maps.texels.size() == atlas.TexelCount());
  const std::vector<Slot> slots = Slots(maps.num_lobes);
  Image image(atlas.width, atlas.height, int(slots.size()), 0.0f);
  for (size_t t = 0; t < maps.texels.size(); ++t) {
    brdf::BrdfParams p = maps.texels[t];
    float* px = &image.data[size_t(atlas.pixel_of_texel[t]) * slots.size()];
    for (size_t i = 0; i < slots.size(); ++i) px[i] = SlotRef(p, slots[i]);
  }
  return image;
}

StatusOr<BrdfMaps> BrdfMapsFromImage(const Image& image, const std::vector<std::string>& names,
                                     const TexelAtlas& atlas, const std::string& file) {
  if (image.width != atlas.width || image.height != atlas.height) {
    return InvalidArgumentError(file, ": parameter map is ", image.width, "x", image.height,
                                " but the atlas is ", atlas.width, "x", atlas.height);
  }
  std::map<std::string, int> index;
  for (size_t i = 0; i < names.size(); ++i) index[names[i]] = int(i);
  BrdfMaps maps;
  while (maps.num_lobes < brdf::kMaxLobes &&
         index.count(StrCat("lobe", maps.num_lobes, ".n.R"))) {
    ++maps.num_lobes;
  }
  const std::vector<std::string> wanted = BrdfChannelNames(maps.num_lobes);
  std::vector<int> source;
  for (const std::string& name : wanted) {
    auto it = index.find(name);
    if (it == index.end()) return InvalidArgumentError(file, ": channel ", name, " is missing");
    source.push_back(it->second);
  }
  const std::vector<Slot> slots = Slots(maps.num_lobes);
  maps.texels.assign(atlas.TexelCount(), brdf::BrdfParams{});
  constexpr int64_t kTexelsPerTask = 1 << 14;  // a million-texel atlas: ~60 tasks
  ParallelFor(0, int64_t(maps.texels.size()), kTexelsPerTask, [&](int64_t begin, int64_t end, int) {
    for (int64_t t = begin; t < end; ++t) {
      brdf::BrdfParams& p = maps.texels[size_t(t)];
      p.num_lobes = maps.num_lobes;
      const float* px = &image.data[size_t(atlas.pixel_of_texel[size_t(t)]) * image.channels];
      for (size_t i = 0; i < slots.size(); ++i) SlotRef(p, slots[i]) = px[source[i]];
    }
  });
  return maps;
}

Status WriteBrdfMaps(const std::filesystem::path& path, const BrdfMaps& maps,
                     const TexelAtlas& atlas) {
  return WriteExrChannels(path, BrdfMapsToImage(maps, atlas), BrdfChannelNames(maps.num_lobes),
                          ExrPixelType::kFloat);
}

StatusOr<BrdfMaps> ReadBrdfMaps(const std::filesystem::path& path, const TexelAtlas& atlas) {
  std::vector<std::string> names;
  // One large file, read before anything else runs: decoded on every core.
  REFLCAP_ASSIGN_OR_RETURN(Image image, ReadExrChannels(path, &names, HardwareThreads()));
  return BrdfMapsFromImage(image, names, atlas, path.string());
}

}  // namespace reflcap
