// Chart growing, orthographic chart projection and bitmap packing (see uv_atlas.h).
#include "acquire/scan/uv_atlas.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <map>
#include <queue>
#include <vector>

#include <Eigen/Eigenvalues>

#include "engine/core/log.h"
#include "engine/core/parallel.h"

namespace reflcap::scan {

namespace {

// Charts filling less than this share of their bounding box are split (and merges that would
// fall below it are refused): arcs and combs leave holes that no packing fills.
constexpr double kMinFill = 0.5;  // measured on suzanne: 0.6 / 0.7 split more and pack worse
constexpr int kMaxSplitDepth = 4;
// Merging passes: each pass tries every chart once; later passes find few merges (measured on
// suzanne: the third pass merges < 1 % of what the first does).
constexpr int kMergePasses = 3;
// Bisection steps for the packing scale: 2^-10 of the bracket, well below one texel of change.
constexpr int kScaleBisections = 10;
// A pixel centre counts as inside a triangle only this far (relative to the edge length) inside
// every edge, so triangles that share an edge never both claim a centre on it.
constexpr double kInsideEpsilon = 1e-7;

struct Chart {
  std::vector<int> faces;
  Vec3d axis, e1, e2;
};

Vec3d FaceNormal(const TriangleMesh& m, int f) {
  const auto& t = m.triangles[f];
  const Vec3d a = m.positions[t[0]].cast<double>(), b = m.positions[t[1]].cast<double>(),
              c = m.positions[t[2]].cast<double>();
  return (b - a).cross(c - a);
}

// Strictly-inside test of a point against a 2-D triangle (any orientation).
bool InsideStrict(const Vec2d& p, const Vec2d& a, const Vec2d& b, const Vec2d& c) {
  auto edge = [](const Vec2d& u, const Vec2d& v, const Vec2d& q) {
    return (v.x() - u.x()) * (q.y() - u.y()) - (v.y() - u.y()) * (q.x() - u.x());
  };
  const double area = edge(a, b, c);
  if (area == 0) return false;
  const double s = area > 0 ? 1.0 : -1.0;
  const double eps = kInsideEpsilon * std::abs(area);
  return s * edge(a, b, p) > eps && s * edge(b, c, p) > eps && s * edge(c, a, p) > eps;
}

// Counts pixel centres inside two triangles of a 2-D triangle soup on a res x res raster spanning
// [0,1]^2 (triangles given in unit coordinates).
int64_t CountOverlaps(const std::vector<std::array<Vec2d, 3>>& tris, int res) {
  std::vector<uint8_t> hits(size_t(res) * res, 0);
  int64_t overlaps = 0;
  for (const auto& t : tris) {
    double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
    for (const auto& p : t) {
      x0 = std::min(x0, p.x()); x1 = std::max(x1, p.x());
      y0 = std::min(y0, p.y()); y1 = std::max(y1, p.y());
    }
    const int ix0 = std::max(0, int(std::floor(x0 * res - 0.5))), ix1 = std::min(res - 1, int(std::ceil(x1 * res)));
    const int iy0 = std::max(0, int(std::floor(y0 * res - 0.5))), iy1 = std::min(res - 1, int(std::ceil(y1 * res)));
    for (int y = iy0; y <= iy1; ++y) {
      for (int x = ix0; x <= ix1; ++x) {
        const Vec2d c((x + 0.5) / res, (y + 0.5) / res);
        if (!InsideStrict(c, t[0], t[1], t[2])) continue;
        uint8_t& h = hits[size_t(y) * res + x];
        if (h == 1) ++overlaps;
        if (h < 2) ++h;
      }
    }
  }
  return overlaps;
}

// Conservative overlap of the pixel square [x, x+1] x [y, y+1] with a 2-D triangle (separating
// axes: the square's axes are covered by the caller's bounding box, the triangle's edge normals
// here; touching counts as overlap, which only widens the gutter).
bool SquareTouchesTriangle(double x, double y, const std::array<Vec2d, 3>& t) {
  for (int k = 0; k < 3; ++k) {
    const Vec2d& a = t[k];
    const Vec2d& b = t[(k + 1) % 3];
    const Vec2d& c = t[(k + 2) % 3];
    const Vec2d n(-(b.y() - a.y()), b.x() - a.x());
    const double side = n.dot(c - a);
    if (side == 0) continue;
    // The square is separated when all its corners lie strictly on the far side of edge ab.
    const double corners[4] = {n.dot(Vec2d(x, y) - a), n.dot(Vec2d(x + 1, y) - a),
                               n.dot(Vec2d(x, y + 1) - a), n.dot(Vec2d(x + 1, y + 1) - a)};
    bool all_out = true;
    for (double d : corners) all_out = all_out && (side > 0 ? d < 0 : d > 0);
    if (all_out) return false;
  }
  return true;
}

// `p` rotated by quarter_turns x 90 degrees (counter-clockwise; orientation-preserving).
Vec2d QuarterTurn(const Vec2d& p, int quarter_turns) {
  switch (quarter_turns & 3) {
    case 1: return Vec2d(-p.y(), p.x());
    case 2: return Vec2d(-p.x(), -p.y());
    case 3: return Vec2d(p.y(), -p.x());
    default: return p;
  }
}

class Bitmap {
 public:
  Bitmap(int w, int h)
      : w_(w), h_(h), words_((w + 63) / 64), bits_(size_t(words_) * h, 0), set_in_row_(h, 0) {}
  int w() const { return w_; }
  int h() const { return h_; }
  bool Get(int x, int y) const { return (bits_[size_t(y) * words_ + x / 64] >> (x % 64)) & 1u; }
  void Set(int x, int y) {
    uint64_t& word = bits_[size_t(y) * words_ + x / 64];
    const uint64_t bit = uint64_t(1) << (x % 64);
    set_in_row_[y] += (word & bit) ? 0 : 1;
    word |= bit;
  }
  int SetInRow(int y) const { return set_in_row_[y]; }
  // 64 bits of row y starting at bit x (bits past the width read as 0).
  uint64_t Bits64(int x, int y) const {
    const int word = x / 64, shift = x % 64;
    const uint64_t* row = &bits_[size_t(y) * words_];
    uint64_t lo = word < words_ ? row[word] : 0;
    if (shift == 0) return lo;
    const uint64_t hi = word + 1 < words_ ? row[word + 1] : 0;
    return (lo >> shift) | (hi << (64 - shift));
  }
  int words() const { return words_; }
  const uint64_t* Row(int y) const { return &bits_[size_t(y) * words_]; }

 private:
  int w_, h_, words_;
  std::vector<uint64_t> bits_;
  std::vector<int> set_in_row_;
};

// A chart rasterised at a given scale and rotation: core (texels it covers) and the core dilated
// by the gutter; both in a local frame whose (0,0) is the placement offset.
struct ChartRaster {
  Bitmap core{1, 1}, dilated{1, 1};
  int anchor_x = 0;  // first set bit of dilated's row 0
  Vec2d origin = Vec2d::Zero();  // local 2-D point mapped to raster (0, 0) before scaling
  int quarter_turns = 0;
};

ChartRaster RasterizeChart(const std::vector<std::array<Vec2d, 3>>& tris2d, double scale, int gutter,
                           int quarter_turns) {
  ChartRaster r;
  r.quarter_turns = quarter_turns;
  auto map = [&](const Vec2d& p) { return QuarterTurn(p, quarter_turns); };
  Vec2d lo(1e300, 1e300), hi(-1e300, -1e300);
  for (const auto& t : tris2d) {
    for (const auto& p : t) {
      lo = lo.cwiseMin(map(p));
      hi = hi.cwiseMax(map(p));
    }
  }
  r.origin = lo;
  // Raster x = (q.x - lo.x) * scale + gutter; raster y = (hi.y - q.y) * scale + gutter (v up).
  const int w = int(std::ceil((hi.x() - lo.x()) * scale)) + 2 * gutter + 1;
  const int h = int(std::ceil((hi.y() - lo.y()) * scale)) + 2 * gutter + 1;
  r.core = Bitmap(w, h);
  for (const auto& t : tris2d) {
    std::array<Vec2d, 3> q;
    for (int k = 0; k < 3; ++k) {
      const Vec2d m = map(t[k]);
      q[k] = Vec2d((m.x() - lo.x()) * scale + gutter, (hi.y() - m.y()) * scale + gutter);
    }
    const int x0 = std::max(0, int(std::floor(std::min({q[0].x(), q[1].x(), q[2].x()}))));
    const int x1 = std::min(w - 1, int(std::floor(std::max({q[0].x(), q[1].x(), q[2].x()}))));
    const int y0 = std::max(0, int(std::floor(std::min({q[0].y(), q[1].y(), q[2].y()}))));
    const int y1 = std::min(h - 1, int(std::floor(std::max({q[0].y(), q[1].y(), q[2].y()}))));
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        if (!r.core.Get(x, y) && SquareTouchesTriangle(x, y, q)) r.core.Set(x, y);
      }
    }
  }
  r.dilated = Bitmap(w, h);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!r.core.Get(x, y)) continue;
      for (int dy = -gutter; dy <= gutter; ++dy) {
        for (int dx = -gutter; dx <= gutter; ++dx) {
          const int xx = x + dx, yy = y + dy;
          if (xx >= 0 && yy >= 0 && xx < w && yy < h) r.dilated.Set(xx, yy);
        }
      }
    }
  }
  r.anchor_x = 0;
  while (r.anchor_x < w && !r.dilated.Get(r.anchor_x, 0)) ++r.anchor_x;
  return r;
}

bool Fits(const Bitmap& occ, const Bitmap& mask, int ox, int oy) {
  for (int y = 0; y < mask.h(); ++y) {
    const uint64_t* row = mask.Row(y);
    for (int k = 0; k < mask.words(); ++k) {
      if (row[k] && (occ.Bits64(ox + 64 * k, oy + y) & row[k])) return false;
    }
  }
  return true;
}

// First free position (scan-line order) for `r` in `occ`; false when none.
bool FindPlace(const Bitmap& occ, const ChartRaster& r, int* ox, int* oy) {
  const int mw = r.dilated.w(), mh = r.dilated.h();
  if (mw > occ.w() || mh > occ.h() || r.anchor_x >= mw) return false;
  for (int y = 0; y + mh <= occ.h(); ++y) {
    // A row of the atlas with fewer free texels than the chart's row needs cannot hold it.
    bool room = true;
    for (int my = 0; my < mh && room; ++my) room = occ.w() - occ.SetInRow(y + my) >= r.dilated.SetInRow(my);
    if (!room) continue;
    const uint64_t* row = occ.Row(y);
    for (int k = 0; k < occ.words(); ++k) {
      uint64_t free_bits = ~row[k];
      while (free_bits) {
        const int bit = __builtin_ctzll(free_bits);
        free_bits &= free_bits - 1;
        const int x = 64 * k + bit - r.anchor_x;
        if (x < 0) continue;
        if (x + mw > occ.w()) break;
        if (Fits(occ, r.dilated, x, y)) {
          *ox = x;
          *oy = y;
          return true;
        }
      }
    }
  }
  return false;
}

void Place(Bitmap* occ, const ChartRaster& r, int ox, int oy) {
  for (int y = 0; y < r.core.h(); ++y) {
    for (int x = 0; x < r.core.w(); ++x) {
      if (r.core.Get(x, y)) occ->Set(ox + x, oy + y);
    }
  }
}

class ChartBuilder {
 public:
  ChartBuilder(const TriangleMesh& mesh) : mesh_(mesh) {
    const size_t nf = mesh.triangles.size();
    normal_.resize(nf);
    centroid_.resize(nf);
    area_.resize(nf);
    for (size_t f = 0; f < nf; ++f) {
      const Vec3d n = FaceNormal(mesh, int(f));
      area_[f] = 0.5 * n.norm();
      normal_[f] = n.norm() > 0 ? Vec3d(n.normalized()) : Vec3d::UnitZ();
      const auto& t = mesh.triangles[f];
      centroid_[f] = (mesh.positions[t[0]] + mesh.positions[t[1]] + mesh.positions[t[2]]).cast<double>() / 3;
      total_area_ += area_[f];
    }
    std::map<std::pair<uint32_t, uint32_t>, std::vector<int>> edges;
    for (size_t f = 0; f < nf; ++f) {
      const auto& t = mesh.triangles[f];
      for (int k = 0; k < 3; ++k) {
        const auto e = std::minmax(t[k], t[(k + 1) % 3]);
        edges[{e.first, e.second}].push_back(int(f));
      }
    }
    adjacency_.resize(nf);
    for (const auto& [e, faces] : edges) {
      if (faces.size() != 2) continue;  // boundary or non-manifold edges do not join charts
      adjacency_[faces[0]].push_back(faces[1]);
      adjacency_[faces[1]].push_back(faces[0]);
    }
  }

  // Grows charts over `faces` with cone angle `angle_deg`. A chart whose projection overlaps
  // itself (a fold or a double layer of the mesh) loses each face that overlaps an earlier one;
  // those faces become one-face charts (Merge may attach them elsewhere).
  void Build(const std::vector<int>& faces, double angle_deg, std::vector<Chart>* out, int64_t* splits) {
    for (Chart& c : Grow(faces, angle_deg)) {
      const std::vector<int> bad = c.faces.size() > 1 ? OverlappingFaces(c, false) : std::vector<int>();
      if (bad.empty()) {
        out->push_back(std::move(c));
        continue;
      }
      ++*splits;
      std::vector<char> drop(c.faces.size(), 0);
      for (int i : bad) drop[i] = 1;
      Chart kept;
      for (size_t i = 0; i < c.faces.size(); ++i) {
        if (drop[i]) {
          Chart single;
          single.faces = {c.faces[i]};  // one face never overlaps itself
          Finish(&single, normal_[c.faces[i]]);
          out->push_back(std::move(single));
        } else {
          kept.faces.push_back(c.faces[i]);
        }
      }
      Finish(&kept, c.axis);
      out->push_back(std::move(kept));
    }
  }

  // The chart's faces projected to 2-D (metres in the chart plane).
  std::vector<std::array<Vec2d, 3>> Project(const Chart& c) const {
    std::vector<std::array<Vec2d, 3>> tris;
    tris.reserve(c.faces.size());
    for (int f : c.faces) {
      std::array<Vec2d, 3> t;
      for (int k = 0; k < 3; ++k) {
        const Vec3d p = mesh_.positions[mesh_.triangles[f][k]].cast<double>();
        t[k] = Vec2d(p.dot(c.e1), p.dot(c.e2));
      }
      tris.push_back(t);
    }
    return tris;
  }
  double MaxStretch(const Chart& c) const {
    double worst = 1;
    for (int f : c.faces) worst = std::max(worst, 1.0 / std::max(1e-6, normal_[f].dot(c.axis)));
    return worst;
  }

 private:
  std::vector<Chart> Grow(const std::vector<int>& faces, double angle_deg) {
    const double cos_max = std::cos(DegToRad(angle_deg));
    std::vector<int> owner_local;
    std::map<int, int> slot;
    for (size_t i = 0; i < faces.size(); ++i) slot[faces[i]] = int(i);
    std::vector<char> assigned(faces.size(), 0);
    std::vector<Chart> charts;
    // Distance scale of the growth cost: a chart of this radius costs as much as a 57-degree tilt.
    const double length = std::sqrt(total_area_) / 4;
    std::deque<int> seeds;
    size_t cursor = 0;
    for (;;) {
      int seed = -1;
      while (!seeds.empty()) {
        const int f = seeds.front();
        seeds.pop_front();
        if (!assigned[slot[f]]) {
          seed = f;
          break;
        }
      }
      while (seed < 0 && cursor < faces.size()) {
        if (!assigned[cursor]) seed = faces[cursor];
        ++cursor;
      }
      if (seed < 0) break;
      Chart chart;
      const Vec3d axis = normal_[seed];
      using Item = std::pair<double, int>;
      std::priority_queue<Item, std::vector<Item>, std::greater<Item>> heap;
      heap.push({0.0, seed});
      while (!heap.empty()) {
        const int f = heap.top().second;
        heap.pop();
        const int s = slot[f];
        if (assigned[s]) continue;
        assigned[s] = 1;
        chart.faces.push_back(f);
        for (int g : adjacency_[f]) {
          auto it = slot.find(g);
          if (it == slot.end() || assigned[it->second]) continue;
          const double d = normal_[g].dot(axis);
          if (d >= cos_max) {
            heap.push({(1 - d) + (centroid_[g] - centroid_[seed]).norm() / length, g});
          } else {
            seeds.push_back(g);
          }
        }
      }
      Finish(&chart, axis);
      charts.push_back(std::move(chart));
    }
    return charts;
  }

public:
  // Projection axis of a chart: the area-weighted mean normal when it keeps every face farther
  // from grazing than `seed_axis` does, else `seed_axis`; e1 along the longer principal extent of
  // the projected vertices (tighter packing). Returns min(n·axis) over the faces.
  double Finish(Chart* chart, const Vec3d& seed_axis, bool force_seed_axis = false) const {
    Vec3d mean = Vec3d::Zero();
    double min_seed = 1, min_mean = 1;
    for (int f : chart->faces) mean += area_[f] * normal_[f];
    if (mean.norm() > 0) mean.normalize();
    for (int f : chart->faces) {
      min_seed = std::min(min_seed, normal_[f].dot(seed_axis));
      min_mean = std::min(min_mean, normal_[f].dot(mean));
    }
    const bool use_mean = !force_seed_axis && mean.norm() > 0 && min_mean >= min_seed;
    chart->axis = use_mean ? mean : seed_axis;
    const Vec3d helper = std::abs(chart->axis.x()) < 0.9 ? Vec3d::UnitX() : Vec3d::UnitY();
    chart->e1 = helper.cross(chart->axis).normalized();
    chart->e2 = chart->axis.cross(chart->e1);
    const auto tris = Project(*chart);
    Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
    Vec2d mean2 = Vec2d::Zero();
    int count = 0;
    for (const auto& t : tris) for (const auto& p : t) { mean2 += p; ++count; }
    mean2 /= std::max(count, 1);
    for (const auto& t : tris) for (const auto& p : t) cov += (p - mean2) * (p - mean2).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(cov);
    const Vec2d major = eig.eigenvectors().col(1);
    const Vec3d e1 = (major.x() * chart->e1 + major.y() * chart->e2).normalized();
    if (e1.allFinite() && e1.norm() > 0.5) {
      chart->e2 = chart->axis.cross(e1);
      chart->e1 = e1;
    }
    return use_mean ? min_mean : min_seed;
  }

  // Chart area / area of its bounding box in the (e1, e2) frame: 1 for a rectangle, ~0.5 for a
  // triangle, small for arcs and combs that leave holes in any packing.
  double Fill(const Chart& c) const {
    const auto tris = Project(c);
    Eigen::AlignedBox2d box;
    double area = 0;
    for (const auto& t : tris) {
      for (const auto& p : t) box.extend(p);
      area += 0.5 * std::abs((t[1] - t[0]).x() * (t[2] - t[0]).y() - (t[1] - t[0]).y() * (t[2] - t[0]).x());
    }
    const double box_area = box.sizes().prod();
    return box_area > 0 ? area / box_area : 1.0;
  }

  // Splits charts whose fill is below kMinFill in two halves across their longer axis (by face
  // centroid), recursively up to kMaxSplitDepth: halves of an arc are straighter and pack better.
  void SplitPoor(std::vector<Chart>* charts) const {
    std::vector<Chart> out;
    std::vector<std::pair<Chart, int>> stack;
    for (Chart& c : *charts) stack.push_back({std::move(c), 0});
    while (!stack.empty()) {
      auto [c, depth] = std::move(stack.back());
      stack.pop_back();
      if (c.faces.size() < 2 || depth >= kMaxSplitDepth || Fill(c) >= kMinFill) {
        out.push_back(std::move(c));
        continue;
      }
      std::vector<std::pair<double, int>> key;
      for (int f : c.faces) key.push_back({centroid_[f].dot(c.e1), f});
      std::sort(key.begin(), key.end());
      Chart halves[2];
      for (size_t i = 0; i < key.size(); ++i) halves[i < key.size() / 2 ? 0 : 1].faces.push_back(key[i].second);
      for (Chart& h : halves) {
        // A half keeps its own axis unless that projection overlaps itself; with the parent's
        // axis it is a subset of an overlap-free projection.
        Finish(&h, c.axis);
        if (SelfOverlaps(h)) Finish(&h, c.axis, /*force_seed_axis=*/true);
        stack.push_back({std::move(h), depth + 1});
      }
    }
    *charts = std::move(out);
  }

  // Greedy merging of neighbouring charts, smallest first, while the union keeps every normal
  // within the cone of its mean normal and does not overlap itself: growth leaves slivers between
  // the big charts, each of which would otherwise be a chart with a border of its own.
  void Merge(std::vector<Chart>* charts, double angle_deg) const {
    const double cos_max = std::cos(DegToRad(angle_deg));
    std::vector<int> chart_of(mesh_.triangles.size(), -1);
    for (size_t c = 0; c < charts->size(); ++c) for (int f : (*charts)[c].faces) chart_of[f] = int(c);
    std::vector<double> area(charts->size(), 0);
    for (size_t c = 0; c < charts->size(); ++c) for (int f : (*charts)[c].faces) area[c] += area_[f];
    std::vector<char> alive(charts->size(), 1);
    bool changed = true;
    for (int pass = 0; pass < kMergePasses && changed; ++pass) {
      changed = false;
      std::vector<size_t> order;
      for (size_t c = 0; c < charts->size(); ++c) if (alive[c]) order.push_back(c);
      std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return area[a] < area[b]; });
      for (size_t c : order) {
        if (!alive[c]) continue;
        // Neighbours by shared edge count, longest border first.
        std::map<int, int> shared;
        for (int f : (*charts)[c].faces) {
          for (int g : adjacency_[f]) {
            if (chart_of[g] >= 0 && chart_of[g] != int(c)) ++shared[chart_of[g]];
          }
        }
        std::vector<std::pair<int, int>> candidates;
        for (const auto& [other, count] : shared) candidates.push_back({-count, other});
        std::sort(candidates.begin(), candidates.end());
        for (const auto& [neg, other] : candidates) {
          Chart merged;
          merged.faces = (*charts)[other].faces;
          merged.faces.insert(merged.faces.end(), (*charts)[c].faces.begin(), (*charts)[c].faces.end());
          if (Finish(&merged, (*charts)[other].axis) < cos_max || Fill(merged) < kMinFill ||
              SelfOverlaps(merged)) {
            continue;
          }
          for (int f : (*charts)[c].faces) chart_of[f] = other;
          (*charts)[other] = std::move(merged);
          area[other] += area[c];
          alive[c] = 0;
          (*charts)[c].faces.clear();
          changed = true;
          break;
        }
      }
    }
    std::vector<Chart> kept;
    for (size_t c = 0; c < charts->size(); ++c) if (alive[c]) kept.push_back(std::move((*charts)[c]));
    *charts = std::move(kept);
  }

private:
  // Exact test: two of the chart's projected triangles whose interiors intersect (separating
  // axis theorem over the six edge normals, with a tolerance so that shared edges and vertices
  // do not count). Candidate pairs come from a uniform grid over the chart.
  bool SelfOverlaps(const Chart& c) const { return !OverlappingFaces(c, true).empty(); }

  // Faces of `c` (indices into c.faces) whose projection overlaps an earlier face of the chart;
  // with `first_only`, stops at the first.
  std::vector<int> OverlappingFaces(const Chart& c, bool first_only) const {
    std::vector<int> out;
    const auto tris = Project(c);
    Vec2d lo(1e300, 1e300), hi(-1e300, -1e300);
    std::vector<Eigen::AlignedBox2d> boxes(tris.size());
    for (size_t i = 0; i < tris.size(); ++i) {
      for (const auto& p : tris[i]) boxes[i].extend(p);
      lo = lo.cwiseMin(boxes[i].min());
      hi = hi.cwiseMax(boxes[i].max());
    }
    const double span = std::max(hi.x() - lo.x(), hi.y() - lo.y());
    if (!(span > 0)) return out;
    const double tolerance = kInsideEpsilon * span;
    const int cells = std::clamp(int(std::sqrt(double(tris.size()))), 1, 256);
    const double cell = span / cells * (1 + 1e-9);
    std::vector<std::vector<int>> grid(size_t(cells) * cells);
    auto cell_of = [&](double v, double origin) { return std::clamp(int((v - origin) / cell), 0, cells - 1); };
    // Cells a face's bounding box covers.
    auto for_cells = [&](size_t i, const std::function<bool(std::vector<int>&)>& visit) {
      for (int y = cell_of(boxes[i].min().y(), lo.y()); y <= cell_of(boxes[i].max().y(), lo.y()); ++y) {
        for (int x = cell_of(boxes[i].min().x(), lo.x()); x <= cell_of(boxes[i].max().x(), lo.x()); ++x) {
          if (!visit(grid[size_t(y) * cells + x])) return;
        }
      }
    };
    for (size_t i = 0; i < tris.size(); ++i) {
      bool hit = false;
      for_cells(i, [&](std::vector<int>& cell_faces) {
        for (int j : cell_faces) {
          if (boxes[i].intersects(boxes[j]) && Intersect(tris[i], tris[j], tolerance)) {
            hit = true;
            return false;
          }
        }
        return true;
      });
      if (hit) {
        out.push_back(int(i));
        if (first_only) return out;
        continue;  // i stays out of the grid: later faces are tested without it
      }
      for_cells(i, [&](std::vector<int>& cell_faces) {
        cell_faces.push_back(int(i));
        return true;
      });
    }
    return out;
  }

  static bool Intersect(const std::array<Vec2d, 3>& a, const std::array<Vec2d, 3>& b, double tolerance) {
    for (const auto* t : {&a, &b}) {
      for (int k = 0; k < 3; ++k) {
        const Vec2d e = (*t)[(k + 1) % 3] - (*t)[k];
        const double len = e.norm();
        if (!(len > 0)) continue;
        const Vec2d n(-e.y() / len, e.x() / len);
        double amin = 1e300, amax = -1e300, bmin = 1e300, bmax = -1e300;
        for (const auto& p : a) { amin = std::min(amin, n.dot(p)); amax = std::max(amax, n.dot(p)); }
        for (const auto& p : b) { bmin = std::min(bmin, n.dot(p)); bmax = std::max(bmax, n.dot(p)); }
        if (amax <= bmin + tolerance || bmax <= amin + tolerance) return false;
      }
    }
    return true;
  }

  const TriangleMesh& mesh_;
  std::vector<Vec3d> normal_, centroid_;
  std::vector<double> area_;
  std::vector<std::vector<int>> adjacency_;
  double total_area_ = 0;
};

}  // namespace

Status UvAtlasOptions::Validate() const {
  if (resolution < 64 || resolution > 16384) {
    return InvalidArgumentError("atlas resolution must be in [64, 16384], got ", resolution);
  }
  if (gutter_texels < 0 || gutter_texels > 8) {
    return InvalidArgumentError("gutter must be in [0, 8] texels, got ", gutter_texels);
  }
  if (!(max_chart_angle_deg >= 10 && max_chart_angle_deg <= 80)) {
    return InvalidArgumentError("chart angle must be in [10, 80] degrees, got ", max_chart_angle_deg);
  }
  return OkStatus();
}

int64_t CountUvOverlaps(const TriangleMesh& mesh, int resolution) {
  std::vector<std::array<Vec2d, 3>> tris;
  tris.reserve(mesh.corner_uvs.size());
  for (const auto& uv : mesh.corner_uvs) {
    std::array<Vec2d, 3> t;
    for (int k = 0; k < 3; ++k) t[k] = uv[k].cast<double>();
    tris.push_back(t);
  }
  return CountOverlaps(tris, resolution);
}

Status ComputeUvAtlas(TriangleMesh* mesh, const UvAtlasOptions& options, UvAtlasStats* stats) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  UvAtlasStats local;
  UvAtlasStats& st = stats ? *stats : local;
  st = UvAtlasStats();
  if (mesh->triangles.empty()) return FailedPreconditionError("the mesh has no triangles to unwrap");
  ChartBuilder builder(*mesh);
  std::vector<int> all(mesh->triangles.size());
  for (size_t f = 0; f < all.size(); ++f) all[f] = int(f);
  std::vector<Chart> charts;
  builder.Build(all, options.max_chart_angle_deg, &charts, &st.split_charts);
  const int64_t grown = int64_t(charts.size());
  builder.SplitPoor(&charts);
  builder.Merge(&charts, options.max_chart_angle_deg);
  REFLCAP_LOG(kDebug) << "uv atlas: " << grown << " charts grown, " << charts.size() << " after merging";
  st.charts = int64_t(charts.size());

  std::vector<std::vector<std::array<Vec2d, 3>>> projected(charts.size());
  double area_2d = 0;
  for (size_t c = 0; c < charts.size(); ++c) {
    projected[c] = builder.Project(charts[c]);
    st.max_stretch = std::max(st.max_stretch, builder.MaxStretch(charts[c]));
    for (const auto& t : projected[c]) {
      area_2d += 0.5 * std::abs((t[1] - t[0]).x() * (t[2] - t[0]).y() - (t[1] - t[0]).y() * (t[2] - t[0]).x());
    }
  }
  if (!(area_2d > 0)) return FailedPreconditionError("the mesh has zero area");
  // Largest charts first: small ones fill the gaps the big ones leave.
  std::vector<size_t> order(charts.size());
  for (size_t c = 0; c < order.size(); ++c) order[c] = c;
  std::vector<double> chart_area(charts.size(), 0);
  for (size_t c = 0; c < charts.size(); ++c) {
    for (const auto& t : projected[c]) {
      chart_area[c] += std::abs((t[1] - t[0]).x() * (t[2] - t[0]).y() - (t[1] - t[0]).y() * (t[2] - t[0]).x());
    }
  }
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return chart_area[a] > chart_area[b]; });

  const int res = options.resolution;
  struct Placement { ChartRaster raster; int ox = 0, oy = 0; };
  auto try_pack = [&](double scale, std::vector<Placement>* placements) {
    Bitmap occ(res, res);
    placements->assign(charts.size(), Placement());
    for (size_t c : order) {
      // Both orientations are rasterised; the one placed higher (then further left) wins.
      bool found = false;
      Placement best;
      for (int turns = 0; turns < 4; ++turns) {
        ChartRaster r = RasterizeChart(projected[c], scale, options.gutter_texels, turns);
        int ox, oy;
        if (!FindPlace(occ, r, &ox, &oy)) continue;
        const int bottom = oy + r.dilated.h(), best_bottom = best.oy + best.raster.dilated.h();
        if (!found || bottom < best_bottom || (bottom == best_bottom && ox < best.ox)) {
          best.raster = std::move(r);
          best.ox = ox;
          best.oy = oy;
          found = true;
        }
      }
      if (!found) return false;
      Place(&occ, best.raster, best.ox, best.oy);
      (*placements)[c] = std::move(best);
    }
    return true;
  };
  // Scale (texels per metre) at which the charts' area would fill the square exactly.
  const double full = std::sqrt(double(res) * res / area_2d);
  double lo = 0, hi = full;
  std::vector<Placement> best_placements, trial;
  double s = 0.5 * full;
  while (!try_pack(s, &trial)) {
    s *= 0.7;
    if (s < full * 1e-3) return FailedPreconditionError("UV packing failed: the charts do not fit");
  }
  lo = s;
  best_placements = trial;
  for (int it = 0; it < kScaleBisections; ++it) {
    const double mid = 0.5 * (lo + hi);
    if (try_pack(mid, &trial)) {
      lo = mid;
      best_placements = trial;
    } else {
      hi = mid;
    }
  }
  const double scale = lo;
  st.scale_texels_per_m = scale;

  // UVs: raster x = (q.x - origin.x) * scale + gutter + ox; u = x / res. Raster y likewise with
  // (origin_hi.y - q.y); v = 1 - y / res. origin_hi.y is recovered from the raster height.
  mesh->corner_uvs.assign(mesh->triangles.size(), {Vec2f::Zero(), Vec2f::Zero(), Vec2f::Zero()});
  const int g = options.gutter_texels;
  for (size_t c = 0; c < charts.size(); ++c) {
    const Placement& p = best_placements[c];
    auto map = [&](const Vec2d& q) { return QuarterTurn(q, p.raster.quarter_turns); };
    double hi_y = -1e300;
    for (const auto& t : projected[c]) for (const auto& q : t) hi_y = std::max(hi_y, map(q).y());
    for (size_t i = 0; i < charts[c].faces.size(); ++i) {
      const int f = charts[c].faces[i];
      for (int k = 0; k < 3; ++k) {
        const Vec2d m = map(projected[c][i][k]);
        const double x = (m.x() - p.raster.origin.x()) * scale + g + p.ox;
        const double y = (hi_y - m.y()) * scale + g + p.oy;
        mesh->corner_uvs[f][k] = Vec2f(float(x / res), float(1.0 - y / res));
      }
    }
  }
  double uv_area = 0;
  for (const auto& uv : mesh->corner_uvs) {
    const Vec2d a = uv[0].cast<double>(), b = uv[1].cast<double>(), c = uv[2].cast<double>();
    uv_area += 0.5 * std::abs((b - a).x() * (c - a).y() - (b - a).y() * (c - a).x());
  }
  st.area_use = uv_area;
  Bitmap occ(res, res);
  int64_t texels = 0;
  for (size_t c = 0; c < charts.size(); ++c) {
    const Placement& p = best_placements[c];
    for (int y = 0; y < p.raster.core.h(); ++y) {
      for (int x = 0; x < p.raster.core.w(); ++x) {
        if (p.raster.core.Get(x, y) && !occ.Get(p.ox + x, p.oy + y)) {
          occ.Set(p.ox + x, p.oy + y);
          ++texels;
        }
      }
    }
  }
  st.texel_use = double(texels) / (double(res) * res);
  st.overlap_pixels = CountUvOverlaps(*mesh, kOverlapCheckResolution);
  st.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return OkStatus();
}

}  // namespace reflcap::scan
