// Per-texel coverage statistics (see coverage.h).
#include "acquire/resample/coverage.h"

#include <algorithm>
#include <bitset>
#include <cstring>
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

template <typename T>
void Append(std::string* out, const std::vector<T>& v) {
  out->append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
}
template <typename T>
bool Take(const std::string& in, size_t* at, std::vector<T>* v) {
  const size_t bytes = v->size() * sizeof(T);
  if (in.size() - *at < bytes) return false;
  std::memcpy(v->data(), in.data() + *at, bytes);
  *at += bytes;
  return true;
}

}  // namespace

Status TexelCoverage::Save(const std::filesystem::path& path) const {
  std::string payload;
  Append(&payload, samples_);
  Append(&payload, views_);
  Append(&payload, last_view_);
  Append(&payload, seen_);
  Append(&payload, observations_);
  Append(&payload, cells_);
  Append(&payload, min_half_deg_);
  std::string file(kCoverageMagic, 8);
  const uint64_t texels = samples_.size();
  const uint32_t crc = Crc32(payload.data(), payload.size());
  file.append(reinterpret_cast<const char*>(&texels), sizeof texels);
  file.append(reinterpret_cast<const char*>(&crc), sizeof crc);
  file += payload;
  return WriteTextFileAtomic(path, file);
}

StatusOr<TexelCoverage> TexelCoverage::Load(const std::filesystem::path& path, size_t texels) {
  REFLCAP_ASSIGN_OR_RETURN(std::string file, ReadTextFile(path));
  const std::string name = path.string();
  constexpr size_t kHeader = 8 + sizeof(uint64_t) + sizeof(uint32_t);
  if (file.size() < kHeader || file.compare(0, 8, kCoverageMagic, 8) != 0) {
    return DataLossError(name, ": not a reflcap coverage file (bad magic or truncated)");
  }
  uint64_t count = 0;
  uint32_t crc = 0;
  std::memcpy(&count, file.data() + 8, sizeof count);
  std::memcpy(&crc, file.data() + 16, sizeof crc);
  if (count != texels) {
    return DataLossError(name, ": texels: holds ", count, " texels, expected ", texels);
  }
  if (Crc32(file.data() + kHeader, file.size() - kHeader) != crc) {
    return DataLossError(name, ": corrupt coverage file (checksum mismatch or truncated)");
  }
  TexelCoverage c(texels);
  size_t at = kHeader;
  const bool ok = Take(file, &at, &c.samples_) && Take(file, &at, &c.views_) &&
                  Take(file, &at, &c.last_view_) && Take(file, &at, &c.seen_) &&
                  Take(file, &at, &c.observations_) && Take(file, &at, &c.cells_) &&
                  Take(file, &at, &c.min_half_deg_);
  if (!ok || at != file.size()) return DataLossError(name, ": coverage file has the wrong size");
  return c;
}

}  // namespace reflcap::resample
