#include "engine/fit/material_clusters.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <numeric>
#include <utility>

#include <Eigen/Eigenvalues>
#include <ceres/ceres.h>

#include "engine/core/check.h"
#include "engine/core/large_buffer.h"
#include "engine/core/parallel.h"
#include "engine/fit/problem.h"
#include "engine/fit/fitter.h"

namespace reflcap::fit {

Status MaterialClusterOptions::Validate() const {
  if (!(chroma_scale > 0 && std::isfinite(chroma_scale)) ||
      !(level_scale > 0 && std::isfinite(level_scale))) {
    return InvalidArgumentError("material cluster scales (chroma ", chroma_scale, ", level ",
                                level_scale, ") must be finite and > 0");
  }
  if (max_clusters < 1 || max_clusters > 4096) {
    return InvalidArgumentError("material clusters ", max_clusters, " outside [1, 4096]");
  }
  if (min_cluster_texels < 1) {
    return InvalidArgumentError("material cluster minimum size ", min_cluster_texels, " < 1");
  }
  if (pool_texels < 1 || pool_texels > 65536) {
    return InvalidArgumentError("material cluster pool ", pool_texels, " outside [1, 65536]");
  }
  if (folds < 2 || folds > kMaxModelFolds) {
    return InvalidArgumentError("model-choice folds ", folds, " outside [2, ", kMaxModelFolds, "]");
  }
  if (lobes_per_cluster < 1 || lobes_per_cluster > kClusterLobeCandidates) {
    return InvalidArgumentError("lobes per material cluster ", lobes_per_cluster,
                                " outside [1, ", kClusterLobeCandidates, "]");
  }
  return OkStatus();
}

int PhotographFold(uint32_t image, int folds) {
  const uint32_t scattered = image * 2654435761u;  // 2^32 / golden ratio, odd: a bijection
  return int((uint64_t(scattered) * uint64_t(folds)) >> 32);
}

const char* ModelChoiceName(ModelChoice choice) {
  return choice == ModelChoice::kKFold ? "kfold" : "bic";
}

StatusOr<ModelChoice> ParseModelChoice(const std::string& name) {
  if (name == "kfold") return ModelChoice::kKFold;
  if (name == "bic") return ModelChoice::kBic;
  return InvalidArgumentError("--model-choice: \"", name, "\" is not kfold or bic");
}

namespace {

// Below this summed albedo (three 0.1 % reflectances) a texel is black: its chromaticity is
// noise, so the level is floored here and the chromaticity taken against the floor.
constexpr double kBlackLevel = 3e-3;
// Lloyd iterations of one 2-means split: the principal-axis start is already close; a few
// iterations settle the boundary.
constexpr int kLloydIterations = 8;

using Feature = Eigen::Vector3d;
using FeatureList = LargeBufferVector<Feature>;

bool HasOwnLobe(const FitStore& fits, size_t t) {
  return fits.status(t) == FitStatus::kConverged && !fits.lambert_only(t) && fits.donor(t) < 0;
}

// Saw its mirror configuration and showed no lobe: evidence of matte.
bool LobeAbsent(const FitStore& fits, size_t t) {
  return fits.status(t) == FitStatus::kConverged && fits.lambert_only(t);
}

Feature AlbedoFeature(const float* rho, const MaterialClusterOptions& options) {
  double r[brdf::kChannels];
  double sum = 0;
  for (int c = 0; c < brdf::kChannels; ++c) {
    // A fit never stores a negative or non-finite albedo; guarded anyway, the features must be
    // finite for the split to be.
    r[c] = std::isfinite(rho[c]) ? std::max(0.0, double(rho[c])) : 0.0;
    sum += r[c];
  }
  const double level = std::max(sum, kBlackLevel);
  return Feature(r[0] / level / options.chroma_scale, r[1] / level / options.chroma_scale,
                 std::log(level) / options.level_scale);
}

struct Node {
  std::vector<uint32_t> items;  // indices into the feature list, ascending
  double sse = 0;               // sum of squared distances to the mean
  bool final = false;
};

// Items per block of the build's per-item passes. Sums are taken per block and the blocks'
// partial sums added in block order: the blocks depend on the item count only, so the clusters
// do not depend on the thread count, and the passes run on every thread (the serial sums over
// the million preset's ~700,000 clustered texels, ~20 of them a split, took ~0.1 s whatever the
// threads).
constexpr int64_t kItemsPerTask = 16384;

int64_t BlockCount(size_t items) { return (int64_t(items) + kItemsPerTask - 1) / kItemsPerTask; }

// body(first, end, block) over the items' blocks on `threads` threads (0: all).
template <typename Body>
void ForEachBlock(size_t items, int threads, const Body& body) {
  ParallelFor(0, int64_t(items), kItemsPerTask, [&](int64_t begin, int64_t end, int) {
    body(size_t(begin), size_t(end), size_t(begin / kItemsPerTask));
  }, threads);
}

// The two sides' feature sums and counts (a split's partial sums).
struct SideSums {
  Feature sum[2] = {Feature::Zero(), Feature::Zero()};
  size_t n[2] = {0, 0};
  void Add(const SideSums& o) {
    for (int s = 0; s < 2; ++s) {
      sum[s] += o.sum[s];
      n[s] += o.n[s];
    }
  }
};

SideSums AddInOrder(const std::vector<SideSums>& blocks) {
  SideSums total;
  for (const SideSums& b : blocks) total.Add(b);
  return total;
}

Feature MeanOf(const FeatureList& f, const std::vector<uint32_t>& items, int threads) {
  std::vector<Feature> blocks(size_t(BlockCount(items.size())));
  ForEachBlock(items.size(), threads, [&](size_t begin, size_t end, size_t block) {
    Feature sum = Feature::Zero();
    for (size_t k = begin; k < end; ++k) sum += f[items[k]];
    blocks[block] = sum;
  });
  Feature total = Feature::Zero();
  for (const Feature& b : blocks) total += b;
  return total / double(std::max<size_t>(items.size(), 1));
}

// Sum of squared distances to the mean, side by side: side[k] picks item k's mean (null: all
// items on side 0).
std::array<double, 2> SumSquares(const FeatureList& f, const std::vector<uint32_t>& items,
                                 const uint8_t* side, const Feature mean[2], int threads) {
  std::vector<std::array<double, 2>> blocks(size_t(BlockCount(items.size())), {0.0, 0.0});
  ForEachBlock(items.size(), threads, [&](size_t begin, size_t end, size_t block) {
    std::array<double, 2> sse = {0.0, 0.0};
    for (size_t k = begin; k < end; ++k) {
      const int s = side == nullptr ? 0 : side[k];
      sse[size_t(s)] += (f[items[k]] - mean[s]).squaredNorm();
    }
    blocks[block] = sse;
  });
  std::array<double, 2> total = {0.0, 0.0};
  for (const auto& b : blocks) {
    total[0] += b[0];
    total[1] += b[1];
  }
  return total;
}

double SumSquares(const FeatureList& f, const std::vector<uint32_t>& items, int threads) {
  const Feature mean[2] = {MeanOf(f, items, threads), Feature::Zero()};
  return SumSquares(f, items, nullptr, mean, threads)[0];
}

// Splits `items` in two by 2-means from the principal axis, into a (side 0) and b (side 1)
// with their sums of squared distances; false when a side would be empty.
bool Split(const FeatureList& f, const std::vector<uint32_t>& items,
           std::vector<uint32_t>* a, std::vector<uint32_t>* b, double* sse_a, double* sse_b,
           int threads) {
  const size_t count = items.size();
  const size_t blocks = size_t(BlockCount(count));
  const Feature mean = MeanOf(f, items, threads);
  std::vector<Eigen::Matrix3d> cov_blocks(blocks, Eigen::Matrix3d::Zero());
  ForEachBlock(count, threads, [&](size_t begin, size_t end, size_t block) {
    Eigen::Matrix3d c = Eigen::Matrix3d::Zero();
    for (size_t k = begin; k < end; ++k) {
      const Feature d = f[items[k]] - mean;
      c += d * d.transpose();
    }
    cov_blocks[block] = c;
  });
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Eigen::Matrix3d& c : cov_blocks) cov += c;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  const Feature axis = eig.eigenvectors().col(2);  // largest eigenvalue last
  // Each pass assigns the sides and sums them for the next pass's means.
  std::vector<uint8_t> side(count);
  std::vector<SideSums> sums(blocks);
  ForEachBlock(count, threads, [&](size_t begin, size_t end, size_t block) {
    SideSums s;
    for (size_t k = begin; k < end; ++k) {
      const Feature& x = f[items[k]];
      const uint8_t v = (x - mean).dot(axis) > 0;
      side[k] = v;
      s.sum[v] += x;
      ++s.n[v];
    }
    sums[block] = s;
  });
  SideSums total = AddInOrder(sums);
  for (int it = 0; it < kLloydIterations; ++it) {
    if (total.n[0] == 0 || total.n[1] == 0) return false;
    const Feature m[2] = {total.sum[0] / double(total.n[0]), total.sum[1] / double(total.n[1])};
    std::atomic<bool> changed{false};
    ForEachBlock(count, threads, [&](size_t begin, size_t end, size_t block) {
      SideSums s;
      bool block_changed = false;
      for (size_t k = begin; k < end; ++k) {
        const Feature& x = f[items[k]];
        const uint8_t v = (x - m[1]).squaredNorm() < (x - m[0]).squaredNorm();
        block_changed = block_changed || v != side[k];
        side[k] = v;
        s.sum[v] += x;
        ++s.n[v];
      }
      sums[block] = s;
      if (block_changed) changed = true;
    });
    total = AddInOrder(sums);
    if (!changed) break;
  }
  if (total.n[0] == 0 || total.n[1] == 0) return false;
  // The sides in item order: each block's items go after the earlier blocks' of their side.
  a->resize(total.n[0]);
  b->resize(total.n[1]);
  std::vector<size_t> at_a(blocks), at_b(blocks);
  for (size_t k = 0, na = 0, nb = 0; k < blocks; ++k) {
    at_a[k] = na;
    at_b[k] = nb;
    na += sums[k].n[0];
    nb += sums[k].n[1];
  }
  ForEachBlock(count, threads, [&](size_t begin, size_t end, size_t block) {
    uint32_t* to[2] = {a->data() + at_a[block], b->data() + at_b[block]};
    for (size_t k = begin; k < end; ++k) *to[side[k]]++ = items[k];
  });
  const Feature means[2] = {total.sum[0] / double(total.n[0]), total.sum[1] / double(total.n[1])};
  const std::array<double, 2> sse = SumSquares(f, items, side.data(), means, threads);
  *sse_a = sse[0];
  *sse_b = sse[1];
  return true;
}

}  // namespace

bool MaterialClusters::PoolIn(uint64_t first, uint64_t end) const {
  const auto it = std::lower_bound(all_pool.begin(), all_pool.end(), first,
                                   [](uint32_t t, uint64_t v) { return uint64_t(t) < v; });
  return it != all_pool.end() && uint64_t(*it) < end;
}

bool MaterialClusters::KeptIn(uint64_t first, uint64_t end) const {
  for (uint64_t t = first; t < end && t < cluster_of.size(); ++t) {
    if (LenderOf(t) >= 0) return true;
  }
  return false;
}

MaterialClusters BuildMaterialClusters(const FitStore& fits, const MaterialClusterOptions& options,
                                       MaterialClusterStats* stats, int threads) {
  MaterialClusters out;
  out.cluster_of.assign(fits.size(), -1);
  if (!options.enabled || fits.lobes() == 0) return out;
  // The clustered texels (feature index -> texel, ascending): counted per block of texels, then
  // listed with their features.
  std::vector<size_t> first_of_block(size_t(BlockCount(fits.size())) + 1, 0);
  ForEachBlock(fits.size(), threads, [&](size_t begin, size_t end, size_t block) {
    size_t n = 0;
    for (size_t t = begin; t < end; ++t) n += fits.samples(t) >= kMinTransferSamples;
    first_of_block[block + 1] = n;
  });
  std::partial_sum(first_of_block.begin(), first_of_block.end(), first_of_block.begin());
  if (first_of_block.back() == 0) return out;
  std::vector<uint32_t> texel(first_of_block.back());
  LargeBufferVector<Feature> f(texel.size());
  ForEachBlock(fits.size(), threads, [&](size_t begin, size_t end, size_t block) {
    size_t i = first_of_block[block];
    for (size_t t = begin; t < end; ++t) {
      if (fits.samples(t) < kMinTransferSamples) continue;
      texel[i] = uint32_t(t);
      f[i++] = AlbedoFeature(fits.params(t), options);
    }
  });

  // Bisecting 2-means: split the node with the largest spread while its mean squared spread
  // exceeds 1 unit^2 and both halves keep min_cluster_texels.
  std::vector<Node> nodes(1);
  nodes[0].items.resize(texel.size());
  std::iota(nodes[0].items.begin(), nodes[0].items.end(), 0u);
  nodes[0].sse = SumSquares(f, nodes[0].items, threads);
  const size_t min_size = size_t(options.min_cluster_texels);
  std::vector<uint32_t> a, b;
  while (int(nodes.size()) < options.max_clusters) {
    int pick = -1;
    for (size_t i = 0; i < nodes.size(); ++i) {
      const Node& n = nodes[i];
      if (n.final || n.items.size() < 2 * min_size || n.sse <= double(n.items.size())) continue;
      if (pick < 0 || n.sse > nodes[size_t(pick)].sse) pick = int(i);
    }
    if (pick < 0) break;
    Node& node = nodes[size_t(pick)];
    double sse_a = 0, sse_b = 0;
    if (!Split(f, node.items, &a, &b, &sse_a, &sse_b, threads) || a.size() < min_size ||
        b.size() < min_size) {
      node.final = true;
      continue;
    }
    node.items.swap(a);
    node.sse = sse_a;
    Node other;
    other.items.swap(b);
    other.sse = sse_b;
    nodes.push_back(std::move(other));
  }
  // Cluster ids in order of each cluster's first texel: the ids do not depend on split order.
  std::sort(nodes.begin(), nodes.end(),
            [](const Node& x, const Node& y) { return x.items.front() < y.items.front(); });

  const size_t k_count = nodes.size();
  out.count = int(k_count);
  out.candidate_params.resize(k_count);
  out.pool.resize(k_count);
  out.stash.resize(k_count);
  out.usable.resize(k_count);
  out.stash_offsets.assign(k_count, std::vector<uint32_t>{0});
  out.brightest.assign(k_count, {});
  out.kept.resize(k_count);
  out.centroid.assign(k_count, {0, 0, 0});
  out.absent.assign(k_count, 0);
  out.lend_from.assign(k_count, -1);
  // Cluster by cluster, in parallel (each writes its own entries and its own texels'
  // cluster_of); the pools are gathered in cluster order after.
  ParallelFor(0, int64_t(k_count), 1, [&](int64_t k_begin, int64_t k_end, int) {
    for (size_t k = size_t(k_begin); k < size_t(k_end); ++k) {
      const Feature mean = MeanOf(f, nodes[k].items, threads);
      out.centroid[k] = {mean[0], mean[1], mean[2]};
      std::vector<uint32_t> own, evidenced;
      for (uint32_t i : nodes[k].items) {
        const uint32_t t = texel[i];
        out.cluster_of[t] = int32_t(k);
        if (HasOwnLobe(fits, t)) own.push_back(t);
        if (HasOwnLobe(fits, t) || LobeAbsent(fits, t)) evidenced.push_back(t);
        out.absent[k] += LobeAbsent(fits, t);
      }
      // Candidates: the best-sampled own lobes (ties: lower texel first).
      std::stable_sort(own.begin(), own.end(),
                       [&](uint32_t x, uint32_t y) { return fits.samples(x) > fits.samples(y); });
      own.resize(std::min(own.size(), size_t(kClusterLobeCandidates)));
      for (uint32_t d : own) out.candidate_params[k].push_back(fits.Get(d).params);
      if (own.empty()) continue;  // nothing to lend: no pool needed
      // Pool: an even stride through the evidenced members (ascending texels).
      const size_t n = evidenced.size(), want = std::min(n, size_t(options.pool_texels));
      for (size_t i = 0; i < want; ++i) out.pool[k].push_back(evidenced[i * n / want]);
    }
  }, threads);
  for (size_t k = 0; k < k_count; ++k) {
    stats->clustered_texels += nodes[k].items.size();
    out.all_pool.insert(out.all_pool.end(), out.pool[k].begin(), out.pool[k].end());
  }
  std::sort(out.all_pool.begin(), out.all_pool.end());
  stats->clusters = out.count;
  return out;
}

void AssignSparseTexels(const FitStore& fits, const std::vector<uint8_t>& albedo_filled,
                        const MaterialClusterOptions& options, MaterialClusters* clusters,
                        MaterialClusterStats* stats, int threads) {
  if (clusters->count == 0) return;
  REFLCAP_CHECK(albedo_filled.empty() || albedo_filled.size() == fits.size());
  std::atomic<size_t> assigned{0};
  ParallelFor(0, int64_t(fits.size()), kItemsPerTask, [&](int64_t begin, int64_t end, int) {
    size_t task_assigned = 0;
    for (int64_t tt = begin; tt < end; ++tt) {
      const size_t t = size_t(tt);
      const int samples = fits.samples(t);
      const bool filled = !albedo_filled.empty() && albedo_filled[t];
      if (clusters->cluster_of[t] >= 0 || samples >= kMinTransferSamples ||
          (samples == 0 && !filled)) {
        continue;
      }
      const Feature x = AlbedoFeature(fits.params(t), options);
      int best = -1;
      double best_d2 = kSparseAssignRadius * kSparseAssignRadius;
      for (int k = 0; k < clusters->count; ++k) {
        const auto& c = clusters->centroid[size_t(k)];
        const double d2 = (x - Feature(c[0], c[1], c[2])).squaredNorm();
        if (d2 <= best_d2) {
          best_d2 = d2;
          best = k;
        }
      }
      if (best < 0) continue;
      clusters->cluster_of[t] = best;
      ++task_assigned;
    }
    assigned += task_assigned;
  }, threads);
  stats->sparse_assigned += assigned;
}

void StashClusterSamples(const TexelSampleChunk& chunk, double min_cos_theta,
                         MaterialClusters* clusters) {
  const auto& pool = clusters->all_pool;
  const uint64_t first = chunk.first_texel, end = first + chunk.texel_count;
  const auto less = [](uint32_t t, uint64_t v) { return uint64_t(t) < v; };
  const auto begin = std::lower_bound(pool.begin(), pool.end(), first, less);
  const auto stop = std::lower_bound(pool.begin(), pool.end(), end, less);
  for (auto it = begin; it != stop; ++it) {
    const uint32_t t = *it;
    const size_t k = size_t(clusters->cluster_of[t]);
    const uint32_t i = uint32_t(t - first);
    const size_t count = chunk.SampleCount(i);
    const BrdfSample* samples = chunk.SamplesOf(i);
    std::vector<size_t> ok;
    std::vector<UsableSample> prepared(count);
    for (size_t s = 0; s < count; ++s) {
      prepared[s] = PrepareUsableSample(samples[s], min_cos_theta);
      if (prepared[s].usable) ok.push_back(s);
    }
    const size_t keep = std::min(ok.size(), size_t(kMaxPooledSamplesPerTexel));
    for (size_t j = 0; j < keep; ++j) {
      const size_t s = ok[j * ok.size() / keep];
      clusters->stash[k].push_back(samples[s]);
      clusters->usable[k].push_back(prepared[s]);
      for (int c = 0; c < brdf::kChannels; ++c) {
        const float w = samples[s].weight[c], y = samples[s].value[c];
        if (w > 0 && std::isfinite(w) && std::isfinite(y)) {
          clusters->brightest[k][c] = std::max(clusters->brightest[k][c], double(y));
        }
      }
    }
    clusters->stash_offsets[k].push_back(uint32_t(clusters->stash[k].size()));
  }
}

namespace {

// One pool texel's samples in one channel of the refinement: residuals
// sqrt(w) (y - rho/pi - lobe(wi, wo)), the lobe (Cx, Cy, Cz, n) shared by the pool, rho the
// texel's albedo; analytic Jacobians (brdf::EvalChannelWithGradient). `iso` ties Cy to Cx (the
// lobe block's Cy is then unused: its Jacobian column is 0 and it stays at its start).
class PooledTexelCost : public ceres::CostFunction {
 public:
  PooledTexelCost(std::vector<std::array<float, 8>> rows, bool iso) : rows_(std::move(rows)), iso_(iso) {
    set_num_residuals(int(rows_.size()));
    mutable_parameter_block_sizes()->push_back(4);
    mutable_parameter_block_sizes()->push_back(1);
  }
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const double* lobe = parameters[0];
    const double rho = parameters[1][0];
    const double p[5] = {rho, lobe[0], iso_ ? lobe[0] : lobe[1], lobe[2], lobe[3]};
    double grad[5];
    for (size_t i = 0; i < rows_.size(); ++i) {
      const auto& r = rows_[i];  // wi[3], wo[3], y, sqrt_w
      const double wi[3] = {r[0], r[1], r[2]}, wo[3] = {r[3], r[4], r[5]};
      const double f = brdf::EvalChannelWithGradient(wi, wo, p, 1, grad);
      residuals[i] = double(r[7]) * (double(r[6]) - f);
      if (jacobians && jacobians[0]) {
        double* j = jacobians[0] + 4 * i;
        j[0] = -double(r[7]) * (iso_ ? grad[1] + grad[2] : grad[1]);
        j[1] = iso_ ? 0.0 : -double(r[7]) * grad[2];
        j[2] = -double(r[7]) * grad[3];
        j[3] = -double(r[7]) * grad[4];
      }
      if (jacobians && jacobians[1]) jacobians[1][i] = -double(r[7]) * grad[0];
    }
    return true;
  }

 private:
  std::vector<std::array<float, 8>> rows_;
  bool iso_;
};

// Refines `start`'s single lobe on cluster k's pool, channel by channel; false when a solve fails
// or leaves a non-finite parameter.
bool RefineClusterLobe(const MaterialClusters& clusters, size_t k, LobeModel model,
                       const brdf::BrdfParams& start, brdf::BrdfParams* refined) {
  *refined = start;
  const auto& offsets = clusters.stash_offsets[k];
  const auto& stash = clusters.stash[k];
  const auto& usable = clusters.usable[k];
  const size_t texels = offsets.size() - 1;
  for (int c = 0; c < brdf::kChannels; ++c) {
    const brdf::LobeParams& l = start.lobes[0][c];
    double lobe[4] = {l.cx, model == LobeModel::kIso ? 0.5 * (double(l.cx) + l.cy) : l.cy, l.cz,
                      std::clamp(double(l.n), brdf::kMinExponent, brdf::kMaxExponent)};
    std::vector<double> rho(texels, 0.0);
    // Start each texel's albedo at its re-fit under the start lobe.
    for (size_t i = 0; i < texels; ++i) {
      std::array<float, brdf::kChannels> r{};
      RefitAlbedoCost(&stash[offsets[i]], offsets[i + 1] - offsets[i], &usable[offsets[i]], &start,
                      &r);
      rho[i] = r[c];
    }
    ceres::Problem problem;
    size_t residuals = 0;
    for (size_t i = 0; i < texels; ++i) {
      std::vector<std::array<float, 8>> rows;
      for (uint32_t s = offsets[i]; s < offsets[i + 1]; ++s) {
        const float w = stash[s].weight[c], y = stash[s].value[c];
        if (!(w > 0) || !std::isfinite(w) || !std::isfinite(y)) continue;
        rows.push_back({usable[s].wi[0], usable[s].wi[1], usable[s].wi[2], usable[s].wo[0],
                        usable[s].wo[1], usable[s].wo[2], y, std::sqrt(w)});
      }
      if (rows.empty()) continue;
      residuals += rows.size();
      problem.AddResidualBlock(new PooledTexelCost(std::move(rows), model == LobeModel::kIso),
                               nullptr, lobe, &rho[i]);
    }
    if (residuals == 0) continue;  // nothing measured in this channel: the start stays
    problem.SetParameterLowerBound(lobe, 3, brdf::kMinExponent);
    problem.SetParameterUpperBound(lobe, 3, brdf::kMaxExponent);
    for (size_t i = 0; i < texels; ++i) {
      if (problem.HasParameterBlock(&rho[i])) problem.SetParameterLowerBound(&rho[i], 0, 0.0);
    }
    ceres::Solver::Options solver;
    solver.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
    // The albedos are independent given the lobe: the Schur complement eliminates them, leaving
    // a 4x4 system per step.
    solver.linear_solver_type = ceres::DENSE_SCHUR;
    // It starts from the best candidate, already near the pooled optimum: a few dozen steps settle
    // four parameters (and the fitter's own LM caps a stage at 100).
    solver.max_num_iterations = 50;
    solver.num_threads = 1;  // clusters run in parallel instead
    solver.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    if (!summary.IsSolutionUsable()) return false;
    for (double v : lobe) {
      if (!std::isfinite(v)) return false;
    }
    brdf::LobeParams& out = refined->lobes[0][c];
    out.cx = float(lobe[0]);
    out.cy = float(model == LobeModel::kIso ? lobe[0] : lobe[1]);
    out.cz = float(lobe[2]);
    out.n = float(lobe[3]);
  }
  return true;
}

struct Score {
  double cost = 0;
  size_t contradicted = 0;
};

// A lobe's pooled cost and contradictions on cluster k's pool (albedos re-fitted per texel).
Score ScoreOnPool(const MaterialClusters& clusters, size_t k, const brdf::BrdfParams& params,
                  const std::vector<double>& lambert, double max_cost_increase) {
  const auto& offsets = clusters.stash_offsets[k];
  Score score;
  std::array<float, brdf::kChannels> rho{};
  for (size_t i = 0; i + 1 < offsets.size(); ++i) {
    const double cost = RefitAlbedoCost(&clusters.stash[k][offsets[i]], offsets[i + 1] - offsets[i],
                                        &clusters.usable[k][offsets[i]], &params, &rho);
    if (!std::isfinite(cost)) return {std::numeric_limits<double>::infinity(), offsets.size()};
    score.cost += cost;
    score.contradicted += cost > lambert[i] + max_cost_increase;
  }
  return score;
}

}  // namespace

void ChooseClusterLobes(const FitOptions& options, MaterialClusters* clusters,
                        MaterialClusterStats* stats) {
  const double max_increase = options.lobe_transfer.max_cost_increase;
  const bool refine = options.lobes == 1 && options.lobe_model != LobeModel::kShared;
  std::vector<uint8_t> kept_any(size_t(clusters->count), 0), refined_kept(size_t(clusters->count), 0);
  // One cluster per task: a refinement is one small Ceres solve per channel.
  ParallelFor(0, clusters->count, 1, [&](int64_t begin, int64_t end, int) {
    for (int64_t kk = begin; kk < end; ++kk) {
      const size_t k = size_t(kk);
      const auto& offsets = clusters->stash_offsets[k];
      const size_t texels = offsets.size() - 1;
      if (texels == 0 || clusters->candidate_params[k].empty()) continue;
      std::vector<double> lambert(texels);
      double lambert_total = 0;
      std::array<float, brdf::kChannels> rho{};
      for (size_t i = 0; i < texels; ++i) {
        lambert[i] = RefitAlbedoCost(&clusters->stash[k][offsets[i]], offsets[i + 1] - offsets[i],
                                     &clusters->usable[k][offsets[i]], nullptr, &rho);
        lambert_total += lambert[i];
      }
      struct Scored {
        double cost;
        size_t index;  // candidates, then the refined lobe last
        brdf::BrdfParams params;
      };
      std::vector<Scored> all;
      for (size_t j = 0; j < clusters->candidate_params[k].size(); ++j) {
        const Score s = ScoreOnPool(*clusters, k, clusters->candidate_params[k][j], lambert, max_increase);
        all.push_back({s.cost, j, clusters->candidate_params[k][j]});
        all.back().cost = s.contradicted > kMaxContradictedShare * double(texels)
                              ? std::numeric_limits<double>::infinity()
                              : s.cost;
      }
      const auto best = std::min_element(all.begin(), all.end(), [](const Scored& x, const Scored& y) {
        return x.cost < y.cost || (x.cost == y.cost && x.index < y.index);
      });
      if (refine && std::isfinite(best->cost)) {
        brdf::BrdfParams refined;
        if (RefineClusterLobe(*clusters, k, options.lobe_model, best->params, &refined)) {
          const Score s = ScoreOnPool(*clusters, k, refined, lambert, max_increase);
          all.push_back({s.contradicted > kMaxContradictedShare * double(texels)
                             ? std::numeric_limits<double>::infinity()
                             : s.cost,
                         clusters->candidate_params[k].size(), refined});
        }
      }
      std::vector<Scored> ok;
      for (const Scored& s : all) {
        if (!std::isfinite(s.cost) || !(s.cost < lambert_total)) continue;
        bool within = true;
        for (int c = 0; c < brdf::kChannels; ++c) {
          within = within && LobeSupremum(s.params, c) <= kMaxLobeSupremum * clusters->brightest[k][c];
        }
        if (within) ok.push_back(s);
      }
      std::sort(ok.begin(), ok.end(), [](const Scored& x, const Scored& y) {
        return x.cost < y.cost || (x.cost == y.cost && x.index < y.index);
      });
      ok.resize(std::min(ok.size(), size_t(options.clusters.lobes_per_cluster)));
      for (const Scored& s : ok) {
        clusters->kept[k].push_back(s.params);
        if (s.index == clusters->candidate_params[k].size()) refined_kept[k] = 1;
      }
      kept_any[k] = !ok.empty();
    }
  }, options.threads);
  for (int k = 0; k < clusters->count; ++k) {
    stats->clusters_with_lobe += kept_any[size_t(k)];
    stats->refined += refined_kept[size_t(k)];
  }
  // Lenders. A cluster with evidence (lobes of its own members, or lobes measured absent) lends
  // what it kept, possibly nothing. One without any takes the verdict of the nearest cluster by
  // centroid that has evidence: its kept lobes, or nothing when that material is matte.
  const auto has_evidence = [&](size_t k) {
    return !clusters->candidate_params[k].empty() || clusters->absent[k] > 0;
  };
  for (size_t k = 0; k < size_t(clusters->count); ++k) {
    int32_t& from = clusters->lend_from[k];
    from = kept_any[k] ? int32_t(k) : -1;
    if (has_evidence(k)) continue;
    double best_d2 = std::numeric_limits<double>::infinity();
    size_t nearest = k;
    for (size_t j = 0; j < size_t(clusters->count); ++j) {
      if (j == k || !has_evidence(j)) continue;
      double d2 = 0;
      for (int i = 0; i < 3; ++i) {
        const double d = clusters->centroid[k][size_t(i)] - clusters->centroid[j][size_t(i)];
        d2 += d * d;
      }
      if (d2 < best_d2) {  // strictly: ties go to the lower id
        best_d2 = d2;
        nearest = j;
      }
    }
    if (nearest != k && kept_any[nearest]) from = int32_t(nearest);
    stats->borrowing += from >= 0;
  }
  clusters->stash = {};
  clusters->usable = {};
  clusters->stash_offsets = {};
}

namespace {

// Step 4's k-fold comparison: a fold holds whole photographs (a light and view seen together), as
// a held-out photograph would be. The photograph index is scattered by Fibonacci hashing before
// it is cut into `folds` ranges: with the index modulo the fold count, a capture whose held-out
// photographs recur with the same period (every 8th held out, 8 folds) left a fold empty in every
// texel, and the comparison fell back to the criterion everywhere.
int FoldOf(const BrdfSample& s, int folds) { return PhotographFold(s.image, folds); }

// True when every fold holds a usable sample (and so every training set lacks one): with fewer
// photographs than folds the comparison has nothing to hold out, and the criterion decides.
// `r` prepared with the folds.
bool EveryFoldHeld(const TexelResiduals& r, int folds) {
  std::array<bool, kMaxModelFolds> held{};
  int distinct = 0;
  for (size_t i = 0; i < r.usable() && distinct < folds; ++i) {
    bool& h = held[size_t(r.fold()[i])];
    distinct += !h;
    h = true;
  }
  return distinct == folds;
}

// A held-out cost lower by less than this (half of one residual's squared standard deviation)
// is no evidence either way; costs are 1/2 sum w r^2 with w the inverse variance.
constexpr double kKFoldMargin = 0.5;

// Another cluster's lobe for a Lambert-only recipient (ApplyClusterLobes): offered only when its
// own cluster's best lobe leaves a reduced chi-square above kForeignLobeTrigger (cost above
// kForeignLobeTrigger / 2 per residual: the texel's samples contradict that lobe's shape, as a
// texture patch whose albedo matches another material's does), and taken only when it at least
// halves that cost (kForeignLobeGain). A margin relative to the cost holds on real photographs,
// whose model error puts every reduced chi-square well above 1.
constexpr double kForeignLobeTrigger = 2.0;
constexpr double kForeignLobeGain = 0.5;

// A Lambert-only recipient takes a cluster lobe that costs it at most max(max_cost_increase, this
// share of its Lambert cost) more. The tail of a sharp lobe depends on directions to a fraction
// of a degree (n = 250 at 15 degrees from the mirror direction: +-0.5 degrees moves it +-75 %),
// so where a texel's samples only touch that tail even the true lobe can cost a few noise units
// more than Lambert: on the million preset the truth itself cost 113.7 against Lambert's 111.0
// (216 residuals) and was refused at the absolute bar of 2, and held-out views lost the
// highlight (photograph 42, render 0.34). 5 %: seed-11 capture rel. RMSE 0.0324 -> 0.0184, the
// million preset 0.0292 -> 0.0183, DiLiGenT, suzanne and the demo unchanged.
constexpr double kRelativeCostIncrease = 0.05;

// The held-out cost of `params`' lobes (none when null) with the albedo re-fitted per fold on
// the other folds: sum over folds of 1/2 sum w (y - rho_f / pi - lobe)^2 over the fold's samples.
double CrossValidatedLobeCost(TexelResiduals* r, const brdf::BrdfParams* params, int folds) {
  double cost = 0;
  for (int c = 0; c < brdf::kChannels; ++c) {
    const float* lobe = r->Lobes(params, c);
    const float* y = r->y(c);
    const float* w = r->w(c);
    const uint8_t* fold = r->fold();
    std::array<double, kMaxModelFolds> s0{}, s1{}, s2{};
    for (size_t i = 0; i < r->padded(); ++i) {
      const double e = double(y[i]) - double(lobe[i]);
      const size_t f = fold[i];
      s0[f] += w[i];
      s1[f] += w[i] * e;
      s2[f] += w[i] * e * e;
    }
    double t0 = 0, t1 = 0;
    for (int f = 0; f < folds; ++f) {
      t0 += s0[size_t(f)];
      t1 += s1[size_t(f)];
    }
    for (int f = 0; f < folds; ++f) {
      const double train0 = t0 - s0[size_t(f)], train1 = t1 - s1[size_t(f)];
      // No training residual (every sample of the channel in this fold): albedo 0.
      const double d = train0 > 0 ? std::max(0.0, train1 / train0) : 0.0;
      // Rounding can leave a tiny negative where the prediction is exact; a cost is never < 0.
      cost += std::max(0.0, 0.5 * (s2[size_t(f)] - 2 * d * s1[size_t(f)] + d * d * s0[size_t(f)]));
    }
  }
  return cost;
}

// Fold f's held-out cost under `fit` (a fit made without fold f): 1/2 sum w (y - f)^2 over the
// fold's samples and every channel.
double FoldHeldOutCost(TexelResiduals* r, const brdf::BrdfParams& fit, int f) {
  double cost = 0;
  for (int c = 0; c < brdf::kChannels; ++c) {
    const float* model = r->Model(fit, c);
    const float* y = r->y(c);
    const float* w = r->w(c);
    for (size_t i = 0; i < r->padded(); ++i) {
      if (r->fold()[i] != f) continue;
      const double e = double(y[i]) - double(model[i]);
      cost += 0.5 * w[i] * e * e;
    }
  }
  return cost;
}

}  // namespace

KFoldScores::KFoldScores(size_t texels, const FitOptions& options, uint64_t batch_samples)
    : folds_(options.clusters.model_choice == ModelChoice::kKFold ? options.clusters.folds : 0),
      batch_samples_(std::max<uint64_t>(batch_samples, 1)) {
  if (folds_ == 0) return;
  // Allocated uninitialised (on huge pages: 18 MB for a million texels), filled on all threads.
  best_cv_.resize(texels);
  best_lobe_.resize(texels);
  own_cv_.resize(texels);
  ParallelFill(&best_cv_, std::numeric_limits<double>::infinity(), options.threads);
  ParallelFill(&best_lobe_, int16_t(-1), options.threads);
  ParallelFill(&own_cv_, 0.0, options.threads);
  waiting_samples_.offsets.assign(1, 0);
}

void ScoreClusterLobes(const TexelSampleChunk& chunk, const MaterialClusters& clusters,
                       const FitOptions& options, const FitStore& fits, KFoldScores* scores,
                       MaterialClusterStats* stats) {
  const int folds = scores->folds_;
  if (folds == 0) return;
  REFLCAP_CHECK(chunk.texel_count == 0 ||
                uint64_t(chunk.first_texel) + chunk.texel_count <= scores->best_cv_.size());
  REFLCAP_CHECK(scores->waiting_.empty() || scores->waiting_.back() < chunk.first_texel)
      << "chunks must be scored in ascending order";
  // The cluster lobes' scores first (in parallel), and which texels need the refits.
  std::vector<uint8_t> needs_refit(chunk.texel_count, 0);
  ParallelFor(0, int64_t(chunk.texel_count), 64, [&](int64_t begin, int64_t end, int) {
    TexelResiduals residuals;
    for (int64_t ii = begin; ii < end; ++ii) {
      const uint32_t i = uint32_t(ii);
      const size_t t = size_t(chunk.first_texel) + i;
      const int32_t k = clusters.LenderOf(t);
      // The texels that take the k-fold branch of ApplyClusterLobes: with a lobe (own or
      // borrowed), enough samples, a cluster that kept lobes.
      if (k < 0 || clusters.kept[size_t(k)].empty() ||
          fits.status(t) == FitStatus::kNonFiniteInput || fits.lambert_only(t) ||
          fits.donor(t) == FitStore::kClusterLobe || fits.samples(t) < kMinTransferSamples) {
        continue;
      }
      residuals.Prepare(chunk.SamplesOf(i), chunk.SampleCount(i), options.min_cos_theta, folds);
      if (!EveryFoldHeld(residuals, folds)) continue;
      double best = std::numeric_limits<double>::infinity();
      const auto& kept = clusters.kept[size_t(k)];
      for (size_t j = 0; j < kept.size(); ++j) {
        const double cv = CrossValidatedLobeCost(&residuals, &kept[j], folds);
        if (std::isfinite(cv) && cv < best) {
          best = cv;
          scores->best_lobe_[t] = int16_t(j);
        }
      }
      scores->best_cv_[t] = best;
      // An own lobe is refitted without each fold (a borrowed one is scored when applied, with
      // its albedo re-fitted); with no kept lobe scored the own lobe stays, and needs no refit.
      needs_refit[i] = fits.donor(t) == FitStore::kNoDonor && scores->best_lobe_[t] >= 0;
    }
  }, options.threads);
  // The texels needing refits wait with a copy of their samples (the chunk may not be kept):
  // offsets first, then the copies in parallel.
  TexelSampleChunk& waiting = scores->waiting_samples_;
  std::vector<uint32_t> appended;
  for (uint32_t i = 0; i < chunk.texel_count; ++i) {
    if (!needs_refit[i]) continue;
    appended.push_back(i);
    scores->waiting_.push_back(chunk.first_texel + i);
    waiting.offsets.push_back(waiting.offsets.back() + chunk.SampleCount(i));
  }
  const size_t first_appended = waiting.texel_count;
  waiting.texel_count = uint32_t(scores->waiting_.size());
  waiting.samples.resize(waiting.offsets.back());
  ParallelFor(0, int64_t(appended.size()), 64, [&](int64_t begin, int64_t end, int) {
    for (int64_t j = begin; j < end; ++j) {
      const uint32_t i = appended[size_t(j)];
      std::copy(chunk.SamplesOf(i), chunk.SamplesOf(i) + chunk.SampleCount(i),
                waiting.samples.data() + waiting.offsets[first_appended + size_t(j)]);
    }
  }, options.threads);
  if (waiting.samples.size() >= scores->batch_samples_) {
    RefitOwnLobes(options, scores, stats);
  }
}

void RefitOwnLobes(const FitOptions& options, KFoldScores* scores, MaterialClusterStats* stats) {
  const int folds = scores->folds_;
  if (folds == 0 || scores->waiting_.empty()) return;
  const auto refit_start = std::chrono::steady_clock::now();
  const TexelSampleChunk& waiting = scores->waiting_samples_;
  // Indices into waiting_: the texels still refitted.
  std::vector<uint32_t> refit(scores->waiting_.size());
  for (size_t j = 0; j < refit.size(); ++j) refit[j] = uint32_t(j);
  stats->kfold_refit += refit.size();
  ++stats->kfold_batches;
  // Fold by fold. Each fold adds a cost >= 0 to the texel's own score, so once the sum so far
  // exceeds the cluster lobe's score by the margin the cluster lobe wins whatever the other
  // folds add: such texels are not refitted for them (the same choice, in ~half the refits).
  if (scores->fitter_ == nullptr) {
    auto fitter = CreateFitter(Backend::kCpu, options.threads);
    REFLCAP_CHECK(fitter.ok()) << fitter.status().ToString();  // the CPU backend always exists
    scores->fitter_ = std::move(fitter).value();
  }
  std::vector<TexelFit>& fold_fit = scores->fold_fit_;
  for (int f = 0; f < folds && !refit.empty(); ++f) {
    // The refitted texels' samples outside fold f: counted, then copied, in parallel.
    TexelSampleChunk& train = scores->train_;  // its buffers reused: no fresh pages per fold
    train.first_texel = 0;
    train.texel_count = uint32_t(refit.size());
    train.offsets.assign(refit.size() + 1, 0);
    ParallelFor(0, int64_t(refit.size()), 256, [&](int64_t begin, int64_t end, int) {
      for (int64_t j = begin; j < end; ++j) {
        const uint32_t i = refit[size_t(j)];
        const BrdfSample* samples = waiting.SamplesOf(i);
        uint64_t n = 0;
        for (size_t s = 0; s < waiting.SampleCount(i); ++s) n += FoldOf(samples[s], folds) != f;
        train.offsets[size_t(j) + 1] = n;
      }
    }, options.threads);
    for (size_t j = 0; j < refit.size(); ++j) train.offsets[j + 1] += train.offsets[j];
    train.samples.resize(train.offsets.back());
    ParallelFor(0, int64_t(refit.size()), 256, [&](int64_t begin, int64_t end, int) {
      for (int64_t j = begin; j < end; ++j) {
        const uint32_t i = refit[size_t(j)];
        const BrdfSample* samples = waiting.SamplesOf(i);
        BrdfSample* out = train.samples.data() + train.offsets[size_t(j)];
        for (size_t s = 0; s < waiting.SampleCount(i); ++s) {
          if (FoldOf(samples[s], folds) != f) *out++ = samples[s];
        }
      }
    }, options.threads);
    const Status fitted = scores->fitter_->Fit(train, options, &fold_fit);
    REFLCAP_CHECK(fitted.ok()) << fitted.ToString();  // options were validated by the caller
    stats->kfold_refits += refit.size();
    ParallelFor(0, int64_t(refit.size()), 64, [&](int64_t begin, int64_t end, int) {
      TexelResiduals residuals;
      for (int64_t j = begin; j < end; ++j) {
        const uint32_t i = refit[size_t(j)];
        residuals.Prepare(waiting.SamplesOf(i), waiting.SampleCount(i), options.min_cos_theta,
                          folds);
        scores->own_cv_[scores->waiting_[i]] +=
            FoldHeldOutCost(&residuals, fold_fit[size_t(j)].params, f);
      }
    }, options.threads);
    if (!options.clusters.stop_decided_refits) continue;
    size_t kept_refits = 0;
    for (uint32_t i : refit) {
      const uint32_t t = scores->waiting_[i];
      if (!(scores->best_cv_[t] < scores->own_cv_[t] - kKFoldMargin)) refit[kept_refits++] = i;
    }
    refit.resize(kept_refits);
  }
  // Emptied, their buffers kept for the next batch.
  scores->waiting_.clear();
  scores->waiting_samples_.samples.clear();
  scores->waiting_samples_.offsets.assign(1, 0);
  scores->waiting_samples_.texel_count = 0;
  stats->refit_seconds +=
      std::chrono::duration<double>(std::chrono::steady_clock::now() - refit_start).count();
}

void ApplyClusterLobes(const TexelSampleChunk& chunk, const MaterialClusters& clusters,
                       const FitOptions& options, FitStore* fits, MaterialClusterStats* stats) {
  KFoldScores scores(fits->size(), options);
  ScoreClusterLobes(chunk, clusters, options, *fits, &scores, stats);
  RefitOwnLobes(options, &scores, stats);
  ApplyClusterLobes(chunk, clusters, options, scores, fits, stats);
}

void ApplyClusterLobes(const TexelSampleChunk& chunk, const MaterialClusters& clusters,
                       const FitOptions& options, const KFoldScores& scores, FitStore* fits,
                       MaterialClusterStats* stats) {
  const double max_increase = options.lobe_transfer.max_cost_increase;
  const int own_params = NumParams(options.lobe_model, fits->lobes()) *
                         ProblemsPerTexel(options.lobe_model);
  // Counted per task (in a MaterialClusterStats of its own), added to *stats once a task: an
  // atomic add per texel on one shared line costs more than the texel's test on a 16-core host.
  std::mutex stats_mutex;
  const int folds = scores.folds_;
  REFLCAP_CHECK(scores.waiting_.empty()) << "RefitOwnLobes before ApplyClusterLobes";
  REFLCAP_CHECK(folds == 0 || chunk.texel_count == 0 ||
                uint64_t(chunk.first_texel) + chunk.texel_count <= scores.best_cv_.size());
  // Every cluster's kept lobes, with their cluster: the foreign offers below.
  std::vector<std::pair<int32_t, const brdf::BrdfParams*>> all_kept;
  for (size_t j = 0; j < clusters.kept.size(); ++j) {
    for (const brdf::BrdfParams& lobe : clusters.kept[j]) all_kept.push_back({int32_t(j), &lobe});
  }
  // 16 texels per task: each tests up to lobes_per_cluster lobes on all its samples.
  ParallelFor(0, int64_t(chunk.texel_count), 16, [&](int64_t begin, int64_t end, int) {
    TexelResiduals prepared;
    MaterialClusterStats n;
    for (int64_t i = begin; i < end; ++i) {
      const size_t t = size_t(chunk.first_texel) + size_t(i);
      const FitStatus status = fits->status(t);
      // The cluster whose lobes it is offered (its own, or the lender of one without evidence).
      const int32_t k = clusters.LenderOf(t);
      if (status == FitStatus::kNonFiniteInput || fits->donor(t) == FitStore::kClusterLobe) continue;
      const bool sparse = fits->samples(t) < kMinTransferSamples;
      if (sparse) {
        // Step 1b's texels: only those AssignSparseTexels placed, and only if still Lambert-only.
        if (k < 0 || clusters.kept[size_t(k)].empty() || !fits->lambert_only(t)) continue;
        if (fits->samples(t) == 0) {
          TexelFit fit = fits->Get(t);
          fit.params.lobes = clusters.kept[size_t(k)].front().lobes;
          fit.lambert_only = false;
          fits->Set(t, fit);
          fits->set_donor(t, FitStore::kClusterLobe);
          ++n.sparse_lent;
          continue;
        }
      }
      const bool lambert_only = fits->lambert_only(t);
      const bool recipient = !sparse && lambert_only && (status == FitStatus::kUnidentifiableLobe ||
                                                         status == FitStatus::kTooFewSamples);
      n.recipients += recipient;
      if (k < 0 || clusters.kept[size_t(k)].empty()) {
        n.no_lobe += recipient;
        continue;
      }
      prepared.Prepare(chunk.SamplesOf(uint32_t(i)), chunk.SampleCount(uint32_t(i)),
                       options.min_cos_theta, folds);
      size_t residuals = 0;
      for (int c = 0; c < brdf::kChannels; ++c) {
        for (size_t s = 0; s < prepared.usable(); ++s) residuals += prepared.w(c)[s] > 0;
      }
      TexelFit fit = fits->Get(t);
      std::array<float, brdf::kChannels> rho{};
      const double own_cost =
          RefitAlbedoCost(&prepared, lambert_only ? nullptr : &fit.params, &rho);
      if (folds > 0 && !lambert_only && EveryFoldHeld(prepared, folds)) {
        // A texel with a lobe: the cluster's lobe replaces it when it predicts the texel's
        // held-out photographs better (k-fold), the texel's own lobe fitted without each fold.
        if (scores.best_lobe_[t] < 0) continue;  // no kept lobe scored: the lobe stays
        const brdf::BrdfParams* best = &clusters.kept[size_t(k)][size_t(scores.best_lobe_[t])];
        // An own lobe's score comes from the refits above; a neighbour's lobe was not fitted to
        // these samples, so only its albedo is re-fitted per fold.
        const double own_score =
            fits->donor(t) == FitStore::kNoDonor
                ? scores.own_cv_[t]
                : CrossValidatedLobeCost(&prepared, &fit.params, folds);
        // Ties (both predictions exact to rounding) keep the texel's own measurement.
        if (!(scores.best_cv_[t] < own_score - kKFoldMargin)) continue;
        const double cost = RefitAlbedoCost(&prepared, best, &rho);
        fit.params.lobes = best->lobes;
        fit.params.rho_d = rho;
        fit.cost = float(cost);
        fits->Set(t, fit);
        fits->set_donor(t, FitStore::kClusterLobe);
        ++n.replaced;
        continue;
      }
      // What the cluster lobe must beat: a Lambert-only texel's cost plus the allowed increase
      // (its samples do not contradict the lobe); a texel with a lobe, its BIC.
      const double k_own = fits->borrowed(t) ? 3.0 : double(own_params);
      const double bar =
          lambert_only ? own_cost + std::max(max_increase, kRelativeCostIncrease * own_cost)
                       : own_cost - 0.5 * (k_own - 3.0) *
                                        std::log(double(std::max<size_t>(residuals, 1)));
      double best_cost = std::numeric_limits<double>::infinity();
      const brdf::BrdfParams* best = nullptr;
      std::array<float, brdf::kChannels> best_rho{};
      for (const brdf::BrdfParams& lobe : clusters.kept[size_t(k)]) {
        const double cost = RefitAlbedoCost(&prepared, &lobe, &rho);
        if (std::isfinite(cost) && cost < best_cost) {
          best_cost = cost;
          best = &lobe;
          best_rho = rho;
        }
      }
      if (recipient && best != nullptr && all_kept.size() > clusters.kept[size_t(k)].size() &&
          best_cost > kForeignLobeTrigger * 0.5 * double(residuals)) {
        // Its own cluster's lobe misfits the texel's samples: another cluster's lobe may fit
        // them (its material's albedo overlapping this cluster's). Held to the texel's own
        // evidence bound, as a neighbour's lobe is (lobe_transfer.h).
        const std::array<double, brdf::kChannels> brightest = prepared.Brightest();
        double foreign_cost = std::numeric_limits<double>::infinity();
        const brdf::BrdfParams* foreign = nullptr;
        std::array<float, brdf::kChannels> foreign_rho{};
        for (const auto& [j, lobe] : all_kept) {
          if (j == k || !WithinEvidence(*lobe, brightest)) continue;
          const double cost = RefitAlbedoCost(&prepared, lobe, &rho);
          if (std::isfinite(cost) && cost < foreign_cost) {
            foreign_cost = cost;
            foreign = lobe;
            foreign_rho = rho;
          }
        }
        if (foreign != nullptr && foreign_cost <= kForeignLobeGain * best_cost) {
          best = foreign;
          best_cost = foreign_cost;
          best_rho = foreign_rho;
          ++n.foreign_lent;
        }
      }
      const bool take = best != nullptr && (lambert_only ? best_cost <= bar : best_cost < bar);
      if (!take) {
        n.rejected += recipient;
        continue;
      }
      fit.params.lobes = best->lobes;
      fit.params.rho_d = best_rho;
      fit.cost = float(best_cost);
      fit.lambert_only = false;
      fits->Set(t, fit);
      fits->set_donor(t, FitStore::kClusterLobe);
      if (sparse) {
        ++n.sparse_lent;
      } else {
        (lambert_only ? n.transferred : n.replaced) += 1;
      }
    }
    const std::lock_guard<std::mutex> lock(stats_mutex);
    stats->recipients += n.recipients;
    stats->no_lobe += n.no_lobe;
    stats->rejected += n.rejected;
    stats->transferred += n.transferred;
    stats->replaced += n.replaced;
    stats->sparse_lent += n.sparse_lent;
    stats->foreign_lent += n.foreign_lent;
  }, options.threads);
}

}  // namespace reflcap::fit
