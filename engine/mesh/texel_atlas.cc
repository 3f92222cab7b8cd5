// Texel atlases: which surface points reflectance is fitted on, laid out as an image.
//
// Mesh atlas = conservative rasterisation of the UV triangles. Work happens in pixel space
// (X = u W, Y = (1 - v) H), where pixel (x, y) is the unit square [x, x+1] x [y, y+1]. A pixel
// is covered by a triangle when the square and the triangle overlap with positive area, decided
// by the separating-axis theorem with the five candidate axes of a square and a triangle (x, y
// and the three edge normals): two convex polygons have interior points in common iff no axis
// separates their projections, even by just touching. Everything is in double, where
// u * W of a float u is exact, so a triangle edge lying on a pixel border is recognised as
// touching, not overlapping.
//
// To stay O(triangles + pixels) rather than O(triangles x pixels), triangles are first binned
// into 32 x 32 pixel tiles by their pixel bounding box (a counting sort, so each bin lists its
// triangles in index order); tiles are then processed in parallel, each keeping for every pixel
// the best triangle so far: one containing the pixel centre, else the one nearest to it in UV,
// ties to the lowest triangle index. The result does not depend on the thread schedule. Texels
// are then numbered row-major and their data (surface point at the clamped barycentrics of the
// point nearest the pixel centre, normals, tangent frame) computed in parallel.
//
// Tangents follow dP/du (Lengyel, "Computing tangent space basis vectors for an arbitrary mesh",
// 2001): per triangle dP/du from the UV parameterisation, summed over the corners that share a
// position and a UV (so the field is continuous inside a chart and split at UV seams), weighted
// by UV area, normalised, interpolated at the texel and Gram-Schmidt orthogonalised against the
// shading normal. Degenerate cases fall back to the triangle's own dP/du, then to the frame of
// Duff et al., "Building an Orthonormal Basis, Revisited" (JCGT 2017), which the normal-map atlas
// uses for all its texels.
#include "engine/mesh/texel_atlas.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>
#include <vector>

#include "engine/core/parallel.h"

namespace reflcap {

namespace {

// Side of the square tiles triangles are binned into; 32 x 32 pixels keeps a tile's scratch
// (1024 pixels) in cache and bins short for dense meshes.
constexpr int kTileSize = 32;

// UVs are floats: a chart border meant to lie on a pixel border is off by up to half an ulp of
// u (2^-24 for u <= 1). Overlaps thinner than 8 such half-ulps (in UV units, so W times that in
// pixels) count as touching, which keeps such borders from adding a row of sliver texels.
constexpr double kUvTolerance = 8.0 / double(1 << 24);

// The tolerance never exceeds this fraction of a triangle's own extent along an axis, so a
// triangle smaller than the tolerance still covers the pixel holding its centroid (which is at
// least 1/3 of the extent away from every side).
constexpr double kMaxToleranceFraction = 0.25;

// Interpolated unit tangents shorter than this after removing their normal component are
// nearly parallel to the normal (or cancelled out): use a fallback direction instead.
constexpr double kMinTangentLength = 1e-6;

// Textures of more than 2^31 pixels would overflow the int32 texel ids.
constexpr int64_t kMaxAtlasPixels = std::numeric_limits<int32_t>::max();

double Cross2(const Vec2d& a, const Vec2d& b) { return a.x() * b.y() - a.y() * b.x(); }

// Pixel [x0, x1) x [y0, y1) of a triangle's bounding box, clipped to the layout.
struct PixelRange {
  int32_t x0 = 0, x1 = 0, y0 = 0, y1 = 0;
  bool empty() const { return x0 >= x1 || y0 >= y1; }
};

// One UV triangle in pixel space, set up for the square/triangle separating-axis test.
class PixelTriangle {
 public:
  // False when the triangle has non-finite UVs or zero UV area (then it covers nothing).
  bool Init(const std::array<Vec2f, 3>& uv, int width, int height) {
    for (int c = 0; c < 3; ++c) {
      p_[c] = Vec2d(double(uv[c].x()) * width, (1.0 - double(uv[c].y())) * height);
      if (!std::isfinite(p_[c].x()) || !std::isfinite(p_[c].y())) return false;
    }
    const double area2 = Cross2(p_[1] - p_[0], p_[2] - p_[0]);
    if (area2 == 0.0 || !std::isfinite(area2)) return false;
    min_ = p_[0].cwiseMin(p_[1]).cwiseMin(p_[2]);
    max_ = p_[0].cwiseMax(p_[1]).cwiseMax(p_[2]);
    tol_x_ = std::min(kUvTolerance * width, kMaxToleranceFraction * (max_.x() - min_.x()));
    tol_y_ = std::min(kUvTolerance * height, kMaxToleranceFraction * (max_.y() - min_.y()));
    const double tol_px = kUvTolerance * std::max(width, height);
    for (int e = 0; e < 3; ++e) {
      const Vec2d& a = p_[e];
      const Vec2d& b = p_[(e + 1) % 3];
      const Vec2d& c = p_[(e + 2) % 3];
      Vec2d n(a.y() - b.y(), b.x() - a.x());  // perpendicular to the edge, not normalised
      if (n.dot(c - a) < 0.0) n = -n;         // pointing into the triangle
      normal_[e] = n;
      edge_[e] = n.dot(a);
      apex_[e] = n.dot(c);
      tol_[e] = std::min(tol_px * n.norm(), kMaxToleranceFraction * (apex_[e] - edge_[e]));
    }
    return true;
  }

  PixelRange Range(int width, int height) const {
    auto clip = [](double v, int limit) { return int32_t(std::clamp(v, 0.0, double(limit))); };
    PixelRange r;
    r.x0 = clip(std::floor(min_.x()), width);
    r.x1 = clip(std::ceil(max_.x()), width);
    r.y0 = clip(std::floor(min_.y()), height);
    r.y1 = clip(std::ceil(max_.y()), height);
    return r;
  }

  // Whether pixel (x, y) and the triangle overlap with positive area (beyond the tolerance).
  bool Overlaps(int x, int y) const {
    if (max_.x() <= x + tol_x_ || min_.x() >= x + 1 - tol_x_) return false;
    if (max_.y() <= y + tol_y_ || min_.y() >= y + 1 - tol_y_) return false;
    for (int e = 0; e < 3; ++e) {
      const Vec2d& n = normal_[e];
      const double base = n.x() * x + n.y() * y;
      const double square_min = base + std::min(n.x(), 0.0) + std::min(n.y(), 0.0);
      const double square_max = base + std::max(n.x(), 0.0) + std::max(n.y(), 0.0);
      if (square_max <= edge_[e] + tol_[e] || square_min >= apex_[e] - tol_[e]) return false;
    }
    return true;
  }

 private:
  Vec2d p_[3];
  Vec2d min_, max_;
  double tol_x_ = 0.0, tol_y_ = 0.0;
  Vec2d normal_[3];      // inward edge normals
  double edge_[3] = {};  // normal . (a point on the edge)
  double apex_[3] = {};  // normal . (the opposite vertex)
  double tol_[3] = {};   // tolerance in units of normal_[e]
};

// Squared UV distance from p to triangle t (2D, non-zero area) and the barycentrics of the
// closest point; exactly 0 when p is inside or on the boundary.
double ClosestPoint(const std::array<Vec2d, 3>& t, const Vec2d& p, Vec3d* bary) {
  const double sign = Cross2(t[1] - t[0], t[2] - t[0]) > 0.0 ? 1.0 : -1.0;
  const Vec3d w(sign * Cross2(t[2] - t[1], p - t[1]), sign * Cross2(t[0] - t[2], p - t[2]),
                sign * Cross2(t[1] - t[0], p - t[0]));
  if (w.x() >= 0.0 && w.y() >= 0.0 && w.z() >= 0.0) {
    *bary = w / w.sum();
    return 0.0;
  }
  double best = std::numeric_limits<double>::infinity();
  for (int e = 0; e < 3; ++e) {
    const Vec2d& a = t[e];
    const Vec2d ab = t[(e + 1) % 3] - a;
    const double length_sq = ab.squaredNorm();
    const double s = length_sq > 0.0 ? std::clamp((p - a).dot(ab) / length_sq, 0.0, 1.0) : 0.0;
    const double d = (p - (a + s * ab)).squaredNorm();
    if (d < best) {
      best = d;
      *bary = Vec3d::Zero();
      (*bary)[e] = 1.0 - s;
      (*bary)[(e + 1) % 3] = s;
    }
  }
  return best;
}

std::array<Vec2d, 3> UvTriangle(const TriangleMesh& mesh, size_t t) {
  return {mesh.corner_uvs[t][0].cast<double>(), mesh.corner_uvs[t][1].cast<double>(),
          mesh.corner_uvs[t][2].cast<double>()};
}

// UV coordinates of the centre of pixel (x, y).
Vec2d PixelCentreUv(int x, int y, int width, int height) {
  return Vec2d((x + 0.5) / width, 1.0 - (y + 0.5) / height);
}

Status CheckInputs(const TriangleMesh& mesh, int width, int height, const char* caller) {
  if (width < 1 || height < 1 || int64_t(width) * height > kMaxAtlasPixels) {
    return InvalidArgumentError(caller, ": atlas size ", width, "x", height,
                                " must be at least 1x1 and below 2^31 pixels");
  }
  if (mesh.corner_uvs.size() != mesh.triangles.size() || mesh.triangles.empty()) {
    return FailedPreconditionError(caller, ": mesh has no UV coordinates (", mesh.triangles.size(),
                                   " triangles, ", mesh.corner_uvs.size(), " UV triples)");
  }
  for (const auto& tri : mesh.triangles) {
    for (uint32_t i : tri) {
      if (i >= mesh.positions.size()) {
        return InvalidArgumentError(caller, ": triangle index ", i, " out of range (",
                                    mesh.positions.size(), " positions)");
      }
    }
  }
  return OkStatus();
}

// For each pixel, the triangle its texel belongs to, or -1. With `choose` false any covering
// triangle is recorded (enough for counting, and cheaper).
std::vector<int32_t> AssignPixels(const TriangleMesh& mesh, int width, int height, bool choose) {
  const size_t triangle_count = mesh.triangles.size();
  std::vector<PixelRange> ranges(triangle_count);
  ParallelFor(0, int64_t(triangle_count), 1 << 14, [&](int64_t begin, int64_t end, int) {
    for (int64_t t = begin; t < end; ++t) {
      PixelTriangle tri;
      if (tri.Init(mesh.corner_uvs[size_t(t)], width, height)) {
        ranges[size_t(t)] = tri.Range(width, height);
      }
    }
  });

  // Counting sort of (tile, triangle) pairs: bins list their triangles in increasing index.
  const int tiles_x = (width + kTileSize - 1) / kTileSize;
  const int tiles_y = (height + kTileSize - 1) / kTileSize;
  std::vector<size_t> offsets(size_t(tiles_x) * tiles_y + 1, 0);
  auto for_each_tile = [&](const PixelRange& r, auto&& f) {
    for (int ty = r.y0 / kTileSize; ty <= (r.y1 - 1) / kTileSize; ++ty) {
      for (int tx = r.x0 / kTileSize; tx <= (r.x1 - 1) / kTileSize; ++tx) {
        f(size_t(ty) * tiles_x + tx);
      }
    }
  };
  for (const PixelRange& r : ranges) {
    if (!r.empty()) for_each_tile(r, [&](size_t tile) { ++offsets[tile + 1]; });
  }
  for (size_t i = 1; i < offsets.size(); ++i) offsets[i] += offsets[i - 1];
  std::vector<uint32_t> bins(offsets.back());
  {
    std::vector<size_t> cursor(offsets.begin(), offsets.end() - 1);
    for (size_t t = 0; t < triangle_count; ++t) {
      if (ranges[t].empty()) continue;
      for_each_tile(ranges[t], [&](size_t tile) { bins[cursor[tile]++] = uint32_t(t); });
    }
  }

  std::vector<int32_t> triangle_of_pixel(size_t(width) * height, -1);
  const int64_t tile_count = int64_t(tiles_x) * tiles_y;
  ParallelFor(0, tile_count, 4, [&](int64_t begin, int64_t end, int) {
    std::vector<double> best_distance(kTileSize * kTileSize);
    std::vector<int32_t> best_triangle(kTileSize * kTileSize);
    for (int64_t tile = begin; tile < end; ++tile) {
      if (offsets[size_t(tile)] == offsets[size_t(tile) + 1]) continue;
      const int tile_x0 = int(tile % tiles_x) * kTileSize;
      const int tile_y0 = int(tile / tiles_x) * kTileSize;
      const int tile_x1 = std::min(width, tile_x0 + kTileSize);
      const int tile_y1 = std::min(height, tile_y0 + kTileSize);
      std::fill(best_distance.begin(), best_distance.end(),
                std::numeric_limits<double>::infinity());
      std::fill(best_triangle.begin(), best_triangle.end(), -1);
      for (size_t k = offsets[size_t(tile)]; k < offsets[size_t(tile) + 1]; ++k) {
        const uint32_t t = bins[k];
        PixelTriangle tri;
        tri.Init(mesh.corner_uvs[t], width, height);  // true: binned triangles passed it before
        const PixelRange& r = ranges[t];
        const std::array<Vec2d, 3> uv = UvTriangle(mesh, t);
        for (int y = std::max(r.y0, tile_y0); y < std::min(r.y1, tile_y1); ++y) {
          for (int x = std::max(r.x0, tile_x0); x < std::min(r.x1, tile_x1); ++x) {
            const size_t local = size_t(y - tile_y0) * kTileSize + (x - tile_x0);
            // A pixel already holding a triangle at distance 0 keeps it (ties go to the lower
            // index); when only counting, any covering triangle is recorded at distance 0.
            if (best_distance[local] == 0.0) continue;
            if (!tri.Overlaps(x, y)) continue;
            Vec3d bary;
            const double distance =
                choose ? ClosestPoint(uv, PixelCentreUv(x, y, width, height), &bary) : 0.0;
            // Strictly less: on ties the earlier (lower-index) triangle stays.
            if (distance < best_distance[local]) {
              best_distance[local] = distance;
              best_triangle[local] = int32_t(t);
            }
          }
        }
      }
      for (int y = tile_y0; y < tile_y1; ++y) {
        for (int x = tile_x0; x < tile_x1; ++x) {
          triangle_of_pixel[size_t(y) * width + x] =
              best_triangle[size_t(y - tile_y0) * kTileSize + (x - tile_x0)];
        }
      }
    }
  });
  return triangle_of_pixel;
}

// Duff et al. 2017: a right-handed orthonormal (t, b, n) from a unit n, continuous everywhere
// except across n.z = 0 where the sign switches.
void BasisFromNormal(const Vec3f& n, Vec3f* t, Vec3f* b) {
  const float sign = std::copysign(1.0f, n.z());
  const float a = -1.0f / (sign + n.z());
  const float c = n.x() * n.y() * a;
  *t = Vec3f(1.0f + sign * n.x() * n.x() * a, sign * c, -sign * n.x());
  *b = Vec3f(c, sign + n.y() * n.y() * a, -n.y());
}

// dP/du of triangle t times its UV area (times 2): (e1 dv2 - e2 dv1) sign(det). Zero when the
// UV triangle is degenerate.
Vec3d WeightedFaceTangent(const TriangleMesh& mesh, size_t t) {
  const auto& tri = mesh.triangles[t];
  const auto& uv = mesh.corner_uvs[t];
  const Vec3d p0 = mesh.positions[tri[0]].cast<double>();
  const Vec3d e1 = mesh.positions[tri[1]].cast<double>() - p0;
  const Vec3d e2 = mesh.positions[tri[2]].cast<double>() - p0;
  const Vec2d d1 = (uv[1] - uv[0]).cast<double>();
  const Vec2d d2 = (uv[2] - uv[0]).cast<double>();
  const double det = Cross2(d1, d2);
  if (det == 0.0 || !std::isfinite(det)) return Vec3d::Zero();
  const Vec3d tangent = (e1 * d2.y() - e2 * d1.y()) * (det > 0.0 ? 1.0 : -1.0);
  return tangent.allFinite() ? tangent : Vec3d::Zero();
}

// Unit tangent per triangle corner: the normalised sum of the weighted face tangents of all
// corners sharing the corner's position and UV (zero where they cancel).
std::vector<std::array<Vec3f, 3>> CornerTangents(const TriangleMesh& mesh) {
  const size_t triangle_count = mesh.triangles.size();
  std::vector<Vec3d> face(triangle_count);
  ParallelFor(0, int64_t(triangle_count), 1 << 14, [&](int64_t begin, int64_t end, int) {
    for (int64_t t = begin; t < end; ++t) face[size_t(t)] = WeightedFaceTangent(mesh, size_t(t));
  });
  // Corners grouped by position (CSR), then by UV bit pattern within a position.
  std::vector<uint32_t> start(mesh.positions.size() + 1, 0);
  for (const auto& tri : mesh.triangles) {
    for (uint32_t i : tri) ++start[i + 1];
  }
  for (size_t i = 1; i < start.size(); ++i) start[i] += start[i - 1];
  std::vector<uint32_t> corners(3 * triangle_count);
  {
    std::vector<uint32_t> cursor(start.begin(), start.end() - 1);
    for (size_t t = 0; t < triangle_count; ++t) {
      for (int c = 0; c < 3; ++c) corners[cursor[mesh.triangles[t][c]]++] = uint32_t(3 * t + c);
    }
  }
  auto uv_key = [&](uint32_t corner) {
    uint32_t u, v;
    const Vec2f& uv = mesh.corner_uvs[corner / 3][corner % 3];
    std::memcpy(&u, &uv.x(), sizeof(u));
    std::memcpy(&v, &uv.y(), sizeof(v));
    return (uint64_t(u) << 32) | v;
  };
  std::vector<std::array<Vec3f, 3>> tangents(triangle_count);
  ParallelFor(0, int64_t(mesh.positions.size()), 1 << 13, [&](int64_t begin, int64_t end, int) {
    for (int64_t i = begin; i < end; ++i) {
      uint32_t* first = corners.data() + start[size_t(i)];
      uint32_t* last = corners.data() + start[size_t(i) + 1];
      std::sort(first, last, [&](uint32_t a, uint32_t b) {
        const uint64_t ka = uv_key(a), kb = uv_key(b);
        return ka != kb ? ka < kb : a < b;
      });
      for (uint32_t* group = first; group != last;) {
        uint32_t* group_end = group;
        Vec3d sum = Vec3d::Zero();
        while (group_end != last && uv_key(*group_end) == uv_key(*group)) {
          sum += face[*group_end / 3];
          ++group_end;
        }
        const double length = sum.norm();
        const Vec3f unit = length > 0.0 ? Vec3f((sum / length).cast<float>()) : Vec3f::Zero();
        for (uint32_t* c = group; c != group_end; ++c) tangents[*c / 3][*c % 3] = unit;
        group = group_end;
      }
    }
  });
  return tangents;
}

// Component of `v` orthogonal to unit `n`, normalised; false when too short.
bool OrthogonalUnit(const Vec3d& v, const Vec3d& n, double min_length, Vec3f* out) {
  const Vec3d w = v - n * n.dot(v);
  const double length = w.norm();
  if (!(length > min_length) || !std::isfinite(length)) return false;
  *out = (w / length).cast<float>();
  return true;
}

void ResizeTexels(size_t count, TexelAtlas* atlas) {
  atlas->pixel_of_texel.resize(count);
  atlas->position.resize(count);
  atlas->shading_normal.resize(count);
  atlas->geometric_normal.resize(count);
  atlas->tangent.resize(count);
  atlas->bitangent.resize(count);
  atlas->triangle.resize(count);
}

}  // namespace

void TexelAtlas::PixelOfUv(float u, float v, int* x, int* y) const {
  // Float arithmetic, one rounding per operation, as the GLSL twin (see kTexelTieOffset).
  auto pixel = [](float coordinate, int size) {
    const float scaled = coordinate * float(size);
    const float shifted = scaled + kTexelTieOffset;
    if (!std::isfinite(shifted)) return 0;
    return int(std::clamp(std::floor(shifted), 0.0f, float(size - 1)));
  };
  *x = pixel(u, width);
  *y = pixel(1.0f - v, height);
}

int TexelAtlas::TexelUnderUv(const Vec2f& uv) const {
  int x, y;
  PixelOfUv(uv.x(), uv.y(), &x, &y);
  int t = TexelAt(x, y);
  if (t >= 0) return t;
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      const int nx = x + dx, ny = y + dy;
      if (nx < 0 || ny < 0 || nx >= width || ny >= height) continue;
      if ((t = TexelAt(nx, ny)) >= 0) return t;
    }
  }
  return -1;
}

std::vector<float> TexelSidesM(const TriangleMesh& mesh, const TexelAtlas& atlas) {
  std::vector<float> per_triangle(mesh.TriangleCount(), 0.0f);
  const double pixels = double(atlas.width) * double(atlas.height);
  for (size_t t = 0; t < mesh.TriangleCount() && !mesh.corner_uvs.empty(); ++t) {
    const auto& v = mesh.triangles[t];
    const Vec3d a = mesh.positions[v[0]].cast<double>(), b = mesh.positions[v[1]].cast<double>(),
                c = mesh.positions[v[2]].cast<double>();
    const double area = 0.5 * (b - a).cross(c - a).norm();
    const auto& uv = mesh.corner_uvs[t];
    const Vec2d e1 = (uv[1] - uv[0]).cast<double>(), e2 = (uv[2] - uv[0]).cast<double>();
    const double area_uv = 0.5 * std::abs(e1.x() * e2.y() - e1.y() * e2.x());
    if (area_uv > 0 && std::isfinite(area / area_uv)) {
      per_triangle[t] = float(std::sqrt(area / area_uv / pixels));
    }
  }
  std::vector<float> sides(atlas.TexelCount(), 0.0f);
  for (size_t i = 0; i < sides.size(); ++i) {
    const int32_t t = i < atlas.triangle.size() ? atlas.triangle[i] : -1;
    if (t >= 0 && size_t(t) < per_triangle.size()) sides[i] = per_triangle[size_t(t)];
  }
  return sides;
}

StatusOr<TexelAtlas> BuildTexelAtlas(const TriangleMesh& mesh, int width, int height) {
  REFLCAP_RETURN_IF_ERROR(CheckInputs(mesh, width, height, "BuildTexelAtlas"));
  TexelAtlas atlas;
  atlas.width = width;
  atlas.height = height;
  std::vector<int32_t> triangle_of_pixel = AssignPixels(mesh, width, height, /*choose=*/true);

  atlas.texel_of_pixel.assign(triangle_of_pixel.size(), -1);
  size_t count = 0;
  for (size_t i = 0; i < triangle_of_pixel.size(); ++i) {
    if (triangle_of_pixel[i] >= 0) atlas.texel_of_pixel[i] = int32_t(count++);
  }
  ResizeTexels(count, &atlas);
  for (size_t i = 0; i < triangle_of_pixel.size(); ++i) {
    if (triangle_of_pixel[i] >= 0) {
      const size_t texel = size_t(atlas.texel_of_pixel[i]);
      atlas.pixel_of_texel[texel] = uint32_t(i);
      atlas.triangle[texel] = triangle_of_pixel[i];
    }
  }

  const bool has_normals = mesh.corner_normals.size() == mesh.triangles.size();
  const std::vector<std::array<Vec3f, 3>> corner_tangents = CornerTangents(mesh);
  ParallelFor(0, int64_t(count), 1 << 12, [&](int64_t begin, int64_t end, int) {
    for (int64_t texel = begin; texel < end; ++texel) {
      const size_t i = size_t(texel);
      const size_t t = size_t(atlas.triangle[i]);
      int x, y;
      atlas.PixelOf(i, &x, &y);
      Vec3d bary;
      ClosestPoint(UvTriangle(mesh, t), PixelCentreUv(x, y, width, height), &bary);
      const auto& tri = mesh.triangles[t];
      Vec3d position = Vec3d::Zero();
      for (int c = 0; c < 3; ++c) position += bary[c] * mesh.positions[tri[c]].cast<double>();
      atlas.position[i] = position.cast<float>();

      const Vec3d p0 = mesh.positions[tri[0]].cast<double>();
      const Vec3d cross = (mesh.positions[tri[1]].cast<double>() - p0)
                              .cross(mesh.positions[tri[2]].cast<double>() - p0);
      Vec3d shading = Vec3d::Zero();
      if (has_normals) {
        for (int c = 0; c < 3; ++c) shading += bary[c] * mesh.corner_normals[t][c].cast<double>();
      }
      // Falls back to the geometric normal where the corner normals cancel or are absent, and
      // the other way round for a zero-area triangle (which loaders never produce).
      const double shading_length = shading.norm();
      const double cross_length = cross.norm();
      const bool shading_ok = shading_length > 0.0 && std::isfinite(shading_length);
      const bool cross_ok = cross_length > 0.0 && std::isfinite(cross_length);
      const Vec3d n = shading_ok ? Vec3d(shading / shading_length)
                      : cross_ok ? Vec3d(cross / cross_length)
                                 : Vec3d::UnitZ();
      const Vec3d geometric = cross_ok ? Vec3d(cross / cross_length) : n;
      atlas.shading_normal[i] = n.cast<float>();
      atlas.geometric_normal[i] = geometric.cast<float>();

      Vec3d interpolated = Vec3d::Zero();
      for (int c = 0; c < 3; ++c) interpolated += bary[c] * corner_tangents[t][c].cast<double>();
      Vec3f tangent;
      if (!OrthogonalUnit(interpolated, n, kMinTangentLength, &tangent)) {
        const Vec3d face = WeightedFaceTangent(mesh, t);
        if (!OrthogonalUnit(face, n, kMinTangentLength * face.norm(), &tangent)) {
          Vec3f unused;
          BasisFromNormal(n.cast<float>(), &tangent, &unused);
        }
      }
      atlas.tangent[i] = tangent;
      atlas.bitangent[i] = atlas.shading_normal[i].cross(tangent);
    }
  });
  return atlas;
}

StatusOr<size_t> CountAtlasTexels(const TriangleMesh& mesh, int width, int height) {
  REFLCAP_RETURN_IF_ERROR(CheckInputs(mesh, width, height, "CountAtlasTexels"));
  const std::vector<int32_t> triangle_of_pixel =
      AssignPixels(mesh, width, height, /*choose=*/false);
  return size_t(std::count_if(triangle_of_pixel.begin(), triangle_of_pixel.end(),
                              [](int32_t t) { return t >= 0; }));
}

StatusOr<TexelAtlas> BuildNormalMapAtlas(const Image& normals, const Image& mask) {
  if (normals.empty() || normals.channels != 3) {
    return InvalidArgumentError("BuildNormalMapAtlas: normal map must have 3 channels (has ",
                                normals.channels, ", ", normals.width, "x", normals.height, ")");
  }
  if (mask.channels < 1 || mask.width != normals.width || mask.height != normals.height) {
    return InvalidArgumentError("BuildNormalMapAtlas: mask is ", mask.width, "x", mask.height, "x",
                                mask.channels, ", normal map ", normals.width, "x", normals.height,
                                " (need the same size and >= 1 channel)");
  }
  if (int64_t(normals.width) * normals.height > kMaxAtlasPixels) {
    return InvalidArgumentError("BuildNormalMapAtlas: image of ", normals.width, "x",
                                normals.height, " pixels is too large for an atlas");
  }
  // A masked pixel is a texel when its normal is finite and of length > 0.5: anything shorter
  // is not a unit normal stored with rounding but a hole or a bad estimate.
  constexpr float kMinNormalLength = 0.5f;
  TexelAtlas atlas;
  atlas.width = normals.width;
  atlas.height = normals.height;
  atlas.texel_of_pixel.assign(normals.PixelCount(), -1);
  std::vector<Vec3f> unit;
  std::vector<uint32_t> pixels;
  for (int y = 0; y < normals.height; ++y) {
    for (int x = 0; x < normals.width; ++x) {
      if (!(mask.at(x, y, 0) > 0.5f)) continue;
      const float* p = normals.pixel(x, y);
      const Vec3f n(p[0], p[1], p[2]);
      const float length = n.norm();
      if (!n.allFinite() || !(length > kMinNormalLength) || !std::isfinite(length)) continue;
      const uint32_t pixel = uint32_t(size_t(y) * normals.width + x);
      atlas.texel_of_pixel[pixel] = int32_t(pixels.size());
      pixels.push_back(pixel);
      unit.push_back(n / length);
    }
  }
  ResizeTexels(pixels.size(), &atlas);
  for (size_t i = 0; i < pixels.size(); ++i) {
    atlas.pixel_of_texel[i] = pixels[i];
    atlas.position[i] = Vec3f::Zero();
    atlas.shading_normal[i] = unit[i];
    atlas.geometric_normal[i] = unit[i];
    Vec3f unused;
    BasisFromNormal(unit[i], &atlas.tangent[i], &unused);
    atlas.bitangent[i] = unit[i].cross(atlas.tangent[i]);
    atlas.triangle[i] = -1;
  }
  return atlas;
}

}  // namespace reflcap
