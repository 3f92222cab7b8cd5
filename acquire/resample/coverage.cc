// Per-texel coverage statistics (see coverage.h).
#include "acquire/resample/coverage.h"

#include <algorithm>
#include <bitset>
#include <cstdio>
#include <cstring>
#include <memory>
#include <type_traits>
#include <utility>
#include <cmath>
#include <limits>

#include "engine/core/atomic_file.h"
#include "engine/core/parallel.h"
#include "engine/texel/sample_store.h"
#include "engine/math/safe_math.h"
#include "engine/math/types.h"

namespace reflcap::resample {
namespace {

int ThetaBin(float cos_theta) {
  const double theta_deg = RadToDeg(SafeAcos(double(cos_theta)));
  return std::clamp(int(theta_deg / (90.0 / kThetaBins)), 0, kThetaBins - 1);
}

// A tangent-plane projection shorter than this (sin θ < 1e-6, θ < 0.2") has no usable azimuth:
// the sample sits at normal incidence and every azimuth bin describes it equally; it goes to 0.
constexpr double kMinProjection = 1e-6;

}  // namespace

int DomainCell(const float wi[3], const float wo[3]) {
  int a = ThetaBin(wi[2]), b = ThetaBin(wo[2]);
  if (a > b) std::swap(a, b);
  const int pair = a * kThetaBins - a * (a - 1) / 2 + (b - a);
  const double li = std::hypot(double(wi[0]), double(wi[1]));
  const double lo = std::hypot(double(wo[0]), double(wo[1]));
  int phi_bin = 0;
  if (li > kMinProjection && lo > kMinProjection) {
    const double c = (double(wi[0]) * wo[0] + double(wi[1]) * wo[1]) / (li * lo);
    const double phi_deg = RadToDeg(SafeAcos(std::clamp(c, -1.0, 1.0)));
    phi_bin = std::clamp(int(phi_deg / (180.0 / kPhiBins)), 0, kPhiBins - 1);
  }
  return pair * kPhiBins + phi_bin;
}

float HalfAngleDeg(const float wi[3], const float wo[3]) {
  const Vec3d h(double(wi[0]) + wo[0], double(wi[1]) + wo[1], double(wi[2]) + wo[2]);
  const double n = h.norm();
  if (!(n > 0)) return 90.0f;  // wi = -wo: no half vector; as far from specular as it gets
  return float(RadToDeg(SafeAcos(std::clamp(h.z() / n, -1.0, 1.0))));
}

TexelCoverage::TexelCoverage(size_t texels)
    : samples_(texels, 0),
      views_(texels, 0),
      last_view_(texels, -1),
      seen_(texels, 0),
      observations_(texels, 0),
      cells_(texels, {0, 0}),
      min_half_deg_(texels, 90.0f) {}

void TexelCoverage::AddImage(const std::vector<uint8_t>& outcome,
                             const std::vector<TexelSample>& kept, int view, int threads) {
  REFLCAP_CHECK(outcome.size() == seen_.size());
  ParallelFor(
      0, int64_t(outcome.size()), 1 << 16,
      [&](int64_t b, int64_t e, int) {
        for (int64_t t = b; t < e; ++t) {
          seen_[t] |= uint8_t(Seen(Outcome(outcome[t])));
          observations_[t] += Observed(Outcome(outcome[t]));
        }
      },
      threads);
  ParallelFor(
      0, int64_t(kept.size()), 4096,
      [&](int64_t b, int64_t e, int) {
        for (int64_t i = b; i < e; ++i) {
          const uint32_t t = kept[i].texel;
          const BrdfSample& s = kept[i].sample;
          ++samples_[t];
          if (last_view_[t] != view) {
            last_view_[t] = view;
            if (views_[t] < std::numeric_limits<uint16_t>::max()) ++views_[t];
          }
          const int cell = DomainCell(s.wi, s.wo);
          cells_[t][cell / 64] |= uint64_t(1) << (cell % 64);
          min_half_deg_[t] = std::min(min_half_deg_[t], HalfAngleDeg(s.wi, s.wo));
        }
      },
      threads);
}

int TexelCoverage::cells(size_t t) const {
  return int(std::bitset<64>(cells_[t][0]).count() + std::bitset<64>(cells_[t][1]).count());
}

void TexelCoverage::Merge(const TexelCoverage& other) {
  REFLCAP_CHECK(other.texels() == texels()) << other.texels() << " vs " << texels() << " texels";
  for (size_t t = 0; t < texels(); ++t) {
    samples_[t] += other.samples_[t];
    views_[t] = uint16_t(std::min<uint32_t>(std::numeric_limits<uint16_t>::max(),
                                            uint32_t(views_[t]) + other.views_[t]));
    if (other.last_view_[t] >= 0) last_view_[t] = other.last_view_[t];
    seen_[t] |= other.seen_[t];
    observations_[t] += other.observations_[t];
    cells_[t][0] |= other.cells_[t][0];
    cells_[t][1] |= other.cells_[t][1];
    min_half_deg_[t] = std::min(min_half_deg_[t], other.min_half_deg_[t]);
  }
}

namespace {

// coverage file: magic, texel count, payload CRC-32, then the arrays in declaration order.
constexpr char kCoverageMagic[8] = {'R', 'F', 'L', 'C', 'C', 'O', 'V', '1'};

}  // namespace

// The arrays in file order, as byte ranges (Save and Load stream them without a staging copy:
// a part's 35 MB coverage.bin at 10^6 texels took 0.12 s when concatenated into one string).
template <typename Self>
auto TexelCoverage::Pieces(Self& c) {
  auto piece = [](auto& v) {
    using Byte = std::conditional_t<std::is_const_v<std::remove_reference_t<decltype(v)>>,
                                    const char, char>;
    return std::pair<Byte*, size_t>(reinterpret_cast<Byte*>(v.data()),
                                    v.size() * sizeof(v[0]));
  };
  return std::array{piece(c.samples_), piece(c.views_), piece(c.last_view_), piece(c.seen_),
                    piece(c.observations_), piece(c.cells_), piece(c.min_half_deg_)};
}

Status TexelCoverage::Save(const std::filesystem::path& path) const {
  const auto pieces = Pieces(*this);
  uint32_t crc = 0;
  for (const auto& [data, bytes] : pieces) crc = Crc32(data, bytes, crc);
  const uint64_t texels = samples_.size();
  return WriteFileAtomic(path, [&](const std::filesystem::path& tmp) -> Status {
    std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(tmp.c_str(), "wb"), &std::fclose);
    if (!f) return InternalError(path.string(), ": cannot create file");
    bool ok = std::fwrite(kCoverageMagic, 1, 8, f.get()) == 8 &&
              std::fwrite(&texels, sizeof texels, 1, f.get()) == 1 &&
              std::fwrite(&crc, sizeof crc, 1, f.get()) == 1;
    for (const auto& [data, bytes] : pieces) {
      ok = ok && std::fwrite(data, 1, bytes, f.get()) == bytes;
    }
    ok = std::fclose(f.release()) == 0 && ok;
    if (!ok) return InternalError(path.string(), ": write failed");
    return OkStatus();
  });
}

StatusOr<TexelCoverage> TexelCoverage::Load(const std::filesystem::path& path, size_t texels) {
  const std::string name = path.string();
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return NotFoundError(name, ": cannot open file");
  char magic[8];
  uint64_t count = 0;
  uint32_t crc = 0;
  if (std::fread(magic, 1, 8, f.get()) != 8 || std::memcmp(magic, kCoverageMagic, 8) != 0) {
    return DataLossError(name, ": not a reflcap coverage file (bad magic or truncated)");
  }
  if (std::fread(&count, sizeof count, 1, f.get()) != 1 ||
      std::fread(&crc, sizeof crc, 1, f.get()) != 1) {
    return DataLossError(name, ": not a reflcap coverage file (bad magic or truncated)");
  }
  if (count != texels) {
    return DataLossError(name, ": texels: holds ", count, " texels, expected ", texels);
  }
  TexelCoverage c(texels);
  uint32_t actual = 0;
  bool whole = true;
  for (const auto& [data, bytes] : Pieces(c)) {
    whole = whole && std::fread(data, 1, bytes, f.get()) == bytes;
    if (whole) actual = Crc32(data, bytes, actual);
  }
  char extra;
  if (!whole || std::fread(&extra, 1, 1, f.get()) != 0) {
    return DataLossError(name, ": coverage file has the wrong size");
  }
  if (std::ferror(f.get())) return DataLossError(name, ": read failed");
  if (actual != crc) {
    return DataLossError(name, ": corrupt coverage file (checksum mismatch or truncated)");
  }
  return c;
}

}  // namespace reflcap::resample
