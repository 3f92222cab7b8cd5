// Height field of a normal-map capture and its cast-shadow march (see height_field.h).
#include "engine/mesh/height_field.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>

#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

namespace reflcap {
namespace {

// Union-find over texel indices (path halving, union by index: the root is the smallest index,
// which makes the pinned texel of a component its first texel in row-major order).
int Find(std::vector<int>& parent, int a) {
  while (parent[size_t(a)] != a) {
    parent[size_t(a)] = parent[size_t(parent[size_t(a)])];
    a = parent[size_t(a)];
  }
  return a;
}
void Union(std::vector<int>& parent, int a, int b) {
  a = Find(parent, a);
  b = Find(parent, b);
  if (a == b) return;
  if (a < b) std::swap(a, b);
  parent[size_t(a)] = b;
}

struct Equation {
  int a, b;   // texels: h_b - h_a = g
  double g;   // pixels of height
};

}  // namespace

const char* HeightFieldIntegrationName(HeightFieldIntegration integration) {
  return integration == HeightFieldIntegration::kL1 ? "l1" : "ls";
}

Status HeightFieldOptions::Validate() const {
  if (!(max_slope > 0) || !std::isfinite(max_slope)) {
    return InvalidArgumentError("HeightFieldOptions::max_slope must be finite and > 0, got ",
                                max_slope);
  }
  if (!(l1_epsilon_px > 0) || !std::isfinite(l1_epsilon_px)) {
    return InvalidArgumentError("HeightFieldOptions::l1_epsilon_px must be finite and > 0, got ",
                                l1_epsilon_px);
  }
  if (!(reweight_tolerance > 0) || max_reweights < 1) {
    return InvalidArgumentError("HeightFieldOptions: reweight_tolerance must be > 0 and "
                                "max_reweights >= 1, got ", reweight_tolerance, " and ",
                                max_reweights);
  }
  return OkStatus();
}

std::string HeightFieldStats::ToString() const {
  std::string l1;
  if (integration == HeightFieldIntegration::kL1) {
    l1 = StrCat("; L1: ", reweights, " reweightings (last weight change ", weight_change, "), ",
                discontinuities, " discontinuity equations");
  }
  return StrCat(texels, " texels, ", components, " component(s), ", equations,
                " gradient equations; residual rms ", rms_residual_px, " px, max ", max_residual_px,
                " px; heights [", min_height_px, ", ", max_height_px, "] px; ", clamped,
                " gradients clamped, ", backfacing, " back-facing normals", l1, "; ", seconds,
                " s");
}

StatusOr<HeightField> IntegrateNormalMap(const TexelAtlas& atlas, const Camera& camera,
                                         const HeightFieldOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  if (camera.model != CameraModel::kOrthographic) {
    return FailedPreconditionError("camera \"", camera.id, "\": a height field is integrated from "
                                   "the normal map of an orthographic camera only");
  }
  if (atlas.width != camera.width || atlas.height != camera.height ||
      atlas.texel_of_pixel.size() != size_t(atlas.width) * size_t(atlas.height)) {
    return InvalidArgumentError("camera \"", camera.id, "\" is ", camera.width, "x",
                                camera.height, " but the normal map is ", atlas.width, "x",
                                atlas.height);
  }
  const size_t n = atlas.TexelCount();
  if (n == 0) return InvalidArgumentError("IntegrateNormalMap: the normal map has no texels");

  HeightField field;
  field.width = atlas.width;
  field.height = atlas.height;
  field.cam_from_world = camera.cam_from_world.rotation;
  field.pixel_size_m = camera.pixel_size_m;
  HeightFieldStats& stats = field.stats;
  stats.texels = n;

  // ---- Gradients (pixels of height per pixel), in the camera frame ------------------------------
  std::vector<double> gu(n), gv(n);
  for (size_t t = 0; t < n; ++t) {
    const Vec3d nc = field.cam_from_world * atlas.shading_normal[t].cast<double>();
    const double towards = -nc.z();  // the normal's component towards the camera
    const double planar = std::hypot(nc.x(), nc.y());
    double p, q;
    if (!(towards > 0)) {
      // Back-facing (see HeightFieldStats::backfacing): the steepest slope allowed, downhill
      // along the normal's image-plane direction; flat when it has none.
      ++stats.backfacing;
      p = planar > 0 ? -nc.x() / planar * options.max_slope : 0;
      q = planar > 0 ? -nc.y() / planar * options.max_slope : 0;
    } else {
      p = -nc.x() / towards;
      q = -nc.y() / towards;
      // planar / towards = |(p, q)|, compared without dividing (towards may be ~1e-30).
      if (planar > options.max_slope * towards) {
        ++stats.clamped;
        p = -nc.x() / planar * options.max_slope;
        q = -nc.y() / planar * options.max_slope;
      }
    }
    gu[t] = p;
    gv[t] = q;
  }

  // ---- Equations between 4-neighbours, components ------------------------------------------------
  std::vector<Equation> equations;
  equations.reserve(2 * n);
  std::vector<int> parent(n);
  std::iota(parent.begin(), parent.end(), 0);
  std::vector<char> boundary(n, 0);
  const int w = atlas.width, h = atlas.height;
  auto texel_at = [&](int x, int y) {
    return (x < 0 || y < 0 || x >= w || y >= h) ? -1 : atlas.TexelAt(x, y);
  };
  for (size_t t = 0; t < n; ++t) {
    int x, y;
    atlas.PixelOf(t, &x, &y);
    const int right = texel_at(x + 1, y), down = texel_at(x, y + 1);
    if (right >= 0) {
      equations.push_back({int(t), right, 0.5 * (gu[t] + gu[size_t(right)])});
      Union(parent, int(t), right);
    }
    if (down >= 0) {
      equations.push_back({int(t), down, 0.5 * (gv[t] + gv[size_t(down)])});
      Union(parent, int(t), down);
    }
    boundary[t] = right < 0 || down < 0 || texel_at(x - 1, y) < 0 || texel_at(x, y - 1) < 0;
  }
  stats.equations = equations.size();

  // ---- Normal equations: weighted graph Laplacian, one pinned texel per component ----------------
  std::vector<int> component(n);
  std::vector<int> roots;
  for (size_t t = 0; t < n; ++t) {
    component[t] = Find(parent, int(t));
    if (component[t] == int(t)) {
      roots.push_back(int(t));
      ++stats.components;
    }
  }
  stats.integration = options.integration;
  const Eigen::Index size = Eigen::Index(n);
  std::vector<double> weight(equations.size(), 1.0);
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver;
  Eigen::VectorXd z;
  // Solves the weighted least squares; the pattern (Laplacian + pins) is the same every time.
  auto solve = [&](bool first) -> Status {
    std::vector<Eigen::Triplet<double>> triplets;
    triplets.reserve(4 * equations.size() + roots.size());
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(size);
    for (size_t k = 0; k < equations.size(); ++k) {
      const Equation& e = equations[k];
      const double wk = weight[k];
      triplets.emplace_back(e.a, e.a, wk);
      triplets.emplace_back(e.b, e.b, wk);
      triplets.emplace_back(e.a, e.b, -wk);
      triplets.emplace_back(e.b, e.a, -wk);
      rhs[e.b] += wk * e.g;
      rhs[e.a] -= wk * e.g;
    }
    // The penalty (h_t - 0)^2: the Laplacian's null space is one constant per component, and
    // the objective does not change along it, so this fixes the constant and leaves the other
    // heights the exact (weighted) least-squares solution.
    for (int t : roots) triplets.emplace_back(t, t, 1.0);
    Eigen::SparseMatrix<double> a(size, size);
    a.setFromTriplets(triplets.begin(), triplets.end());
    if (first) solver.analyzePattern(a);
    solver.factorize(a);
    if (solver.info() != Eigen::Success) {
      return InternalError("IntegrateNormalMap: the sparse factorisation of ", n,
                           " texels failed");
    }
    z = solver.solve(rhs);
    if (solver.info() != Eigen::Success || !z.allFinite()) {
      return InternalError("IntegrateNormalMap: the sparse solve of ", n, " texels failed");
    }
    return OkStatus();
  };
  REFLCAP_RETURN_IF_ERROR(solve(/*first=*/true));
  if (options.integration == HeightFieldIntegration::kL1) {
    const double eps = options.l1_epsilon_px;
    for (int pass = 0; pass < options.max_reweights; ++pass) {
      double change = 0;
      for (size_t k = 0; k < equations.size(); ++k) {
        const Equation& e = equations[k];
        const double r = z[e.b] - z[e.a] - e.g;
        // The Charbonnier penalty's IRLS weight ρ'(r) / r = 1 / √(r² + ε²), times ε so that it
        // lies in (0, 1] (1 at r = 0): a common scale of all weights does not move the solution.
        const double w = eps / std::sqrt(r * r + eps * eps);
        change = std::max(change, std::abs(w - weight[k]));
        weight[k] = w;
      }
      stats.weight_change = change;
      if (change <= options.reweight_tolerance) break;
      REFLCAP_RETURN_IF_ERROR(solve(/*first=*/false));
      ++stats.reweights;
    }
    // Weight < 0.1 <=> |r| > √99 ε ≈ 10 ε: an equation the integration let go (a step).
    for (double w : weight) stats.discontinuities += w < 0.1;
  }

  // ---- Each component's constant: mean boundary height 0 ---------------------------------------
  std::vector<double> sum(n, 0.0);
  std::vector<size_t> count(n, 0);
  for (size_t t = 0; t < n; ++t) {
    if (!boundary[t]) continue;
    sum[size_t(component[t])] += z[Eigen::Index(t)];
    ++count[size_t(component[t])];
  }
  for (size_t t = 0; t < n; ++t) {
    const size_t c = size_t(component[t]);
    // Every component has a boundary texel (its bottom-right-most one lacks a right neighbour).
    if (count[c] > 0) z[Eigen::Index(t)] -= sum[c] / double(count[c]);
  }

  // ---- Residuals, the field -----------------------------------------------------------------------
  double squares = 0;
  for (const Equation& e : equations) {
    const double r = std::abs(z[e.b] - z[e.a] - e.g);
    squares += r * r;
    stats.max_residual_px = std::max(stats.max_residual_px, r);
  }
  stats.rms_residual_px = equations.empty() ? 0 : std::sqrt(squares / double(equations.size()));
  field.heights_px.assign(size_t(w) * size_t(h), kHeightFieldOutside);
  stats.min_height_px = z.minCoeff();
  stats.max_height_px = z.maxCoeff();
  for (size_t t = 0; t < n; ++t) field.heights_px[atlas.pixel_of_texel[t]] = float(z[Eigen::Index(t)]);
  stats.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return field;
}

HeightFieldMarch MakeHeightFieldMarch(const HeightField& field, const Vec3d& light_direction) {
  // A light whose image-plane part is below this lies along the viewing axis: its ray from a
  // visible point runs along the camera ray, which nothing blocks (and the step would divide by
  // ~0).
  constexpr double kMinImagePlaneLight = 1e-6;
  HeightFieldMarch march{};
  march.width = uint32_t(field.width);
  march.height = uint32_t(field.height);
  const Vec3d l = field.cam_from_world * light_direction.normalized();
  // (column, row, height) directions: +x, +y of the camera, and -z (towards the camera).
  const double major = std::max(std::abs(l.x()), std::abs(l.y()));
  if (!(major >= kMinImagePlaneLight) || !l.allFinite() || field.width <= 0 || field.height <= 0) {
    return march;
  }
  float max_height = kHeightFieldOutside;
  for (float v : field.heights_px) max_height = std::max(max_height, v);
  march.step = {float(l.x() / major), float(l.y() / major), float(-l.z() / major), max_height};
  // One step moves one pixel along the major axis: the image's extent along it bounds the march.
  const int extent = std::abs(l.x()) >= std::abs(l.y()) ? field.width : field.height;
  march.steps = std::min<uint32_t>(uint32_t(extent), kMaxHeightFieldMarchSteps);
  return march;
}

bool HeightFieldShadowed(const float* heights, const HeightFieldMarch& march, int x, int y) {
  // Twin of HeightFieldShadowed in shaders/common/height_field.glsl: the same float operations in
  // the same order (the build does not contract a * b + c into fused multiply-adds).
  const int w = int(march.width), h = int(march.height);
  const float h0 = heights[size_t(y) * size_t(w) + size_t(x)];
  const float x0f = float(x), y0f = float(y);
  const float last_x = float(w - 1), last_y = float(h - 1);
  const uint32_t steps = std::min(march.steps, kMaxHeightFieldMarchSteps);
  for (uint32_t i = 1; i <= steps; ++i) {
    const float t = float(i);
    const float ray = h0 + t * march.step.z;
    if (ray > march.step.w) return false;  // above the highest point of the field
    const float u = x0f + t * march.step.x;
    const float v = y0f + t * march.step.y;
    if (!(u >= 0.0f) || !(v >= 0.0f) || u > last_x || v > last_y) return false;  // left the image
    const float fu = std::floor(u), fv = std::floor(v);
    const float ax = u - fu, ay = v - fv;
    const int xa = int(fu), ya = int(fv);
    const int xb = std::min(xa + 1, w - 1), yb = std::min(ya + 1, h - 1);
    const int tx[4] = {xa, xb, xa, xb};
    const int ty[4] = {ya, ya, yb, yb};
    const float tw[4] = {(1.0f - ax) * (1.0f - ay), ax * (1.0f - ay), (1.0f - ax) * ay, ax * ay};
    float weight = 0.0f, weighted = 0.0f;
    for (int k = 0; k < 4; ++k) {
      const float s = heights[size_t(ty[k]) * size_t(w) + size_t(tx[k])];
      if (s > kHeightFieldInsideAbove) {
        weight = weight + tw[k];
        weighted = weighted + tw[k] * s;
      }
    }
    // Blocked when the field's (renormalised) height exceeds the ray by more than the bias:
    // weighted / weight > ray + bias, multiplied out (division is not correctly rounded on
    // every GPU; multiplication is).
    if (weight >= kHeightFieldMinTapWeight &&
        weighted > (ray + kHeightFieldShadowBiasPx) * weight) {
      return true;
    }
  }
  return false;
}

}  // namespace reflcap
