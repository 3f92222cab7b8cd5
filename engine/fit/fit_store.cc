#include "engine/fit/fit_store.h"

#include <algorithm>
#include <system_error>
#include <utility>

#include "engine/core/check.h"
#include "engine/core/parallel.h"
#include "engine/fit/problem.h"

namespace reflcap::fit {
namespace {

// Texels per task of the constructor's initialisation: ~2 MB of parameters at one lobe.
constexpr int64_t kInitTexelsPerTask = 1 << 15;

}  // namespace

void PackParams(const brdf::BrdfParams& p, int lobes, float* out) {
  for (int c = 0; c < brdf::kChannels; ++c) out[c] = p.rho_d[c];
  for (int k = 0; k < lobes; ++k) {
    for (int c = 0; c < brdf::kChannels; ++c) {
      const brdf::LobeParams& l = p.lobes[k][c];
      float* o = out + brdf::kChannels + 4 * (brdf::kChannels * k + c);
      o[0] = l.cx;
      o[1] = l.cy;
      o[2] = l.cz;
      o[3] = l.n;
    }
  }
}

void UnpackParams(const float* in, int lobes, brdf::BrdfParams* p) {
  for (int c = 0; c < brdf::kChannels; ++c) p->rho_d[c] = in[c];
  for (int k = 0; k < lobes; ++k) {
    for (int c = 0; c < brdf::kChannels; ++c) {
      const float* i = in + brdf::kChannels + 4 * (brdf::kChannels * k + c);
      p->lobes[k][c] = brdf::LobeParams{i[0], i[1], i[2], i[3]};
    }
  }
}

FitStore::FitStore(size_t texels, int lobes, int threads)
    : lobes_(lobes), stride_(brdf::kChannels * brdf::ParamsPerChannel(lobes)) {
  REFLCAP_CHECK(texels <= kMaxTexels) << texels << " texels";
  REFLCAP_CHECK(lobes >= 0 && lobes <= brdf::kMaxLobes) << lobes << " lobes";
  // Allocated uninitialised, then every entry written once, on all threads.
  params_.resize(texels * stride_);
  cost_.resize(texels);
  iterations_.resize(texels);
  samples_.resize(texels);
  residuals_.resize(texels);
  donor_.resize(texels);
  status_.resize(texels);
  lambert_only_.resize(texels);
  TexelFit empty;
  BeginTexel(lobes, &empty);
  empty.status = FitStatus::kTooFewSamples;
  ParallelFor(0, int64_t(texels), kInitTexelsPerTask, [&](int64_t begin, int64_t end, int) {
    for (size_t t = size_t(begin); t < size_t(end); ++t) {
      Set(t, empty);
      donor_[t] = int32_t(kNoDonor);
    }
  }, threads);
}

void FitStore::Set(size_t t, const TexelFit& fit) {
  REFLCAP_CHECK(fit.params.num_lobes == lobes_)
      << "texel " << t << ": " << fit.params.num_lobes << " lobes, the store holds " << lobes_;
  PackParams(fit.params, lobes_, &params_[t * stride_]);
  status_[t] = uint8_t(fit.status);
  cost_[t] = fit.cost;
  iterations_[t] = fit.iterations;
  samples_[t] = fit.samples;
  residuals_[t] = fit.residuals;
  lambert_only_[t] = fit.lambert_only;
}

TexelFit FitStore::Get(size_t t) const {
  REFLCAP_CHECK(params_.size() == size() * stride_) << "Get after ReleaseParams";
  TexelFit fit;
  BeginTexel(lobes_, &fit);
  UnpackParams(params(t), lobes_, &fit.params);
  fit.status = status(t);
  fit.cost = cost_[t];
  fit.iterations = iterations_[t];
  fit.samples = samples_[t];
  fit.residuals = residuals_[t];
  fit.lambert_only = lambert_only_[t] != 0;
  return fit;
}

void FitStore::set_donor(size_t t, int64_t donor) {
  REFLCAP_CHECK(donor >= kDiffuseFalloff && donor < int64_t(size())) << "donor " << donor;
  donor_[t] = int32_t(donor);
}

void FitStore::ReleaseParams() { LargeBufferVector<float>().swap(params_); }

namespace {
// Texels per read or write of the scratch file: ~1 MB for one lobe, large enough for sequential
// disk speed, small beside the store.
constexpr size_t kSpillBlockTexels = 16384;
}  // namespace

SigmaSpill::SigmaSpill(std::filesystem::path path, size_t texels, int lobes)
    : path_(std::move(path)),
      texels_(texels),
      lobes_(lobes),
      stride_(brdf::kChannels * brdf::ParamsPerChannel(lobes)) {}

StatusOr<std::unique_ptr<SigmaSpill>> SigmaSpill::Create(const std::filesystem::path& path,
                                                         size_t texels, int lobes) {
  REFLCAP_CHECK(lobes >= 0 && lobes <= brdf::kMaxLobes) << lobes << " lobes";
  std::unique_ptr<SigmaSpill> spill(new SigmaSpill(path, texels, lobes));
  spill->file_.open(path, std::ios::in | std::ios::out | std::ios::binary | std::ios::trunc);
  if (!spill->file_) return InternalError(path.string(), ": cannot create the sigma scratch file");
  // Every texel starts unknown: a texel no chunk holds keeps that.
  const std::vector<float> unknown(kSpillBlockTexels * spill->stride_, -1.0f);
  for (size_t t = 0; t < texels; t += kSpillBlockTexels) {
    const size_t n = std::min(kSpillBlockTexels, texels - t);
    spill->file_.write(reinterpret_cast<const char*>(unknown.data()),
                       std::streamsize(n * spill->stride_ * sizeof(float)));
  }
  if (!spill->file_.flush()) return InternalError(path.string(), ": cannot write the sigma scratch file");
  return spill;
}

SigmaSpill::~SigmaSpill() {
  if (removed_) return;
  file_.close();
  std::error_code ignored;
  std::filesystem::remove(path_, ignored);
}

Status SigmaSpill::Write(size_t first, const std::vector<TexelFit>& fits) {
  REFLCAP_CHECK(first + fits.size() <= texels_ && !removed_);
  std::vector<float> block(fits.size() * stride_);
  for (size_t i = 0; i < fits.size(); ++i) PackParams(fits[i].sigma, lobes_, &block[i * stride_]);
  file_.seekp(std::streamoff(first * stride_ * sizeof(float)));
  file_.write(reinterpret_cast<const char*>(block.data()),
              std::streamsize(block.size() * sizeof(float)));
  if (!file_.flush()) return InternalError(path_.string(), ": cannot write the sigma scratch file");
  return OkStatus();
}

Status SigmaSpill::ReadAll(const std::function<void(size_t t, const float* sigma)>& each) {
  REFLCAP_CHECK(!removed_);
  file_.seekg(0);
  std::vector<float> block(kSpillBlockTexels * stride_);
  for (size_t t = 0; t < texels_; t += kSpillBlockTexels) {
    const size_t n = std::min(kSpillBlockTexels, texels_ - t);
    if (!file_.read(reinterpret_cast<char*>(block.data()),
                    std::streamsize(n * stride_ * sizeof(float)))) {
      return InternalError(path_.string(), ": cannot read the sigma scratch file back (texel ", t,
                           " of ", texels_, ")");
    }
    for (size_t i = 0; i < n; ++i) each(t + i, &block[i * stride_]);
  }
  return OkStatus();
}

Status SigmaSpill::Remove() {
  if (removed_) return OkStatus();
  file_.close();
  removed_ = true;
  std::error_code error;
  if (!std::filesystem::remove(path_, error) || error) {
    return InternalError(path_.string(), ": cannot delete the sigma scratch file: ", error.message());
  }
  return OkStatus();
}

}  // namespace reflcap::fit
