// ColorChecker detection, pose and colour calibration (see chart.h).
#include "acquire/radiometry/chart.h"

#include <algorithm>
#include <cmath>
#include <queue>

#include <Eigen/Eigenvalues>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/mcc.hpp>

#include "engine/core/log.h"

namespace reflcap::radiometry {
namespace {

// Tone mapping for mcc: the 99th luminance percentile of the photograph maps to these levels
// (1 = white) before a 1/2.2 gamma; the brighter one lifts a dark chart above mcc's thresholds.
constexpr double kToneLevels[] = {1.0, 4.0};
// Upscaling factors tried: mcc's contour filters assume patches of tens of pixels.
constexpr double kMccScales[] = {1.0, 2.0};
// Centroid/homography rounds and the edge-profile sampling.
constexpr int kCentroidRounds = 3;
constexpr int kEdgeSamples = 15;             // profiles per edge, spread over its middle 60 %
constexpr double kEdgeProfileStep = 0.25;    // px
// Edge window inside the predicted edge (px): beyond the blur of a photograph's pixel filter and
// the refined homography's error (< 1 px), short enough that the light's gradient does not count.
constexpr double kEdgeInnerPx = 3;
constexpr int kEdgeInnerSamples = 4;         // samples of the local patch level, in [−2 s_in, −s_in]
// A patch's region must cover this fraction of its predicted area (a merged patch or a patch
// broken by a wrong seed falls outside).
constexpr double kMinAreaRatio = 0.5, kMaxAreaRatio = 1.6;
// A seed is accepted when at least this many patches segment (the rest follow from the
// homography of the others).
constexpr int kMinPatchesSegmented = 16;
// Orientation/identity test: RMS of log(measured/reference) after per-channel gains. A correct
// ColorChecker under one light scores below ~0.1 (irradiance varies a few % across the chart; a
// real camera's colour crosstalk adds ~0.05); a wrong order of the patches scores > 0.5.
constexpr double kMaxColourResidual = 0.25;
// Patches with measured corners needed to solve the pose from them alone (16 of 24: the chart's
// extent in both directions stays covered).
constexpr int kMinPatchesForPose = 16;
// PnP residual above which the corners are not a planar ColorChecker seen by this camera (px).
constexpr double kMaxReprojectionPx = 1.5;

double Luminance(const float* p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; }

struct LumaImage {
  int w = 0, h = 0;
  std::vector<double> v;
  double at(int x, int y) const { return v[size_t(y) * size_t(w) + size_t(x)]; }
  // Bilinear at a continuous position (pixel centres at integers); clamps at the border.
  double Sample(double x, double y) const {
    x = std::clamp(x, 0.0, double(w - 1));
    y = std::clamp(y, 0.0, double(h - 1));
    const int x0 = std::min(int(x), w - 2 < 0 ? 0 : w - 2), y0 = std::min(int(y), h - 2 < 0 ? 0 : h - 2);
    const double fx = x - x0, fy = y - y0;
    const int x1 = std::min(x0 + 1, w - 1), y1 = std::min(y0 + 1, h - 1);
    return (1 - fy) * ((1 - fx) * at(x0, y0) + fx * at(x1, y0)) + fy * ((1 - fx) * at(x0, y1) + fx * at(x1, y1));
  }
};

LumaImage ToLuma(const Image& hdr) {
  LumaImage l;
  l.w = hdr.width;
  l.h = hdr.height;
  l.v.resize(hdr.PixelCount());
  for (size_t p = 0; p < l.v.size(); ++p) l.v[p] = std::max(0.0, Luminance(&hdr.data[p * 3]));
  return l;
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, size_t(q * double(v.size())));
  std::nth_element(v.begin(), v.begin() + long(k), v.end());
  return v[k];
}

cv::Mat ToneMapped(const Image& hdr, double level, double scale) {
  std::vector<double> lum;
  for (size_t p = 0; p < hdr.PixelCount(); ++p) lum.push_back(Luminance(&hdr.data[p * 3]));
  const double white = std::max(Percentile(lum, 0.99), 1e-30) / level;
  cv::Mat out(hdr.height, hdr.width, CV_8UC3);
  for (int y = 0; y < hdr.height; ++y) {
    for (int x = 0; x < hdr.width; ++x) {
      const float* p = hdr.pixel(x, y);
      cv::Vec3b& o = out.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) {
        const double v = std::clamp(double(p[c]) / white, 0.0, 1.0);
        o[2 - c] = uint8_t(std::lround(255 * std::pow(v, 1 / 2.2)));  // BGR
      }
    }
  }
  if (scale != 1.0) cv::resize(out, out, cv::Size(), scale, scale, cv::INTER_CUBIC);
  return out;
}

cv::Matx33d Homography(const std::vector<cv::Point2d>& from, const std::vector<cv::Point2d>& to) {
  cv::Mat H = cv::findHomography(from, to, 0);
  if (H.empty()) return cv::Matx33d::zeros();
  return cv::Matx33d(H);
}

Vec2d Apply(const cv::Matx33d& H, const Vec2d& p) {
  const cv::Vec3d q = H * cv::Vec3d(p.x(), p.y(), 1.0);
  return Vec2d(q[0] / q[2], q[1] / q[2]);
}

// Chart-plane outline of the patch grid in the order TL, TR, BR, BL.
std::array<Vec2d, 4> GridOutline(const ChartLayout& layout) {
  return {layout.PatchCorner(0, 0), layout.PatchCorner(kChartColumns - 1, 1),
          layout.PatchCorner(kChartPatches - 1, 2), layout.PatchCorner(kChartPatches - kChartColumns, 3)};
}

// Segments patch i around its predicted centre; returns its membership-weighted centroid.
bool PatchCentroid(const LumaImage& L, const cv::Matx33d& H, const ChartLayout& layout, int patch,
                   double frame_level, Vec2d* centroid) {
  const Vec2d c = Apply(H, layout.PatchPoint(patch, 0.5, 0.5));
  std::array<Vec2d, 4> quad;
  for (int k = 0; k < 4; ++k) quad[size_t(k)] = Apply(H, layout.PatchCorner(patch, k));
  const double side = 0.5 * ((quad[1] - quad[0]).norm() + (quad[2] - quad[1]).norm());
  const double area = std::abs((quad[1] - quad[0]).x() * (quad[3] - quad[0]).y() -
                               (quad[1] - quad[0]).y() * (quad[3] - quad[0]).x());
  if (!(side > 3) || !std::isfinite(side)) return false;
  const double pitch = side * (layout.patch_m + layout.gap_m) / layout.patch_m;
  const int x0 = std::max(0, int(std::floor(c.x() - 0.75 * pitch)));
  const int x1 = std::min(L.w - 1, int(std::ceil(c.x() + 0.75 * pitch)));
  const int y0 = std::max(0, int(std::floor(c.y() - 0.75 * pitch)));
  const int y1 = std::min(L.h - 1, int(std::ceil(c.y() + 0.75 * pitch)));
  if (x1 - x0 < 3 || y1 - y0 < 3) return false;
  // Patch level: median over a disc of a quarter side around the prediction.
  std::vector<double> inner;
  const double r = 0.25 * side;
  for (int y = int(c.y() - r); y <= int(c.y() + r); ++y) {
    for (int x = int(c.x() - r); x <= int(c.x() + r); ++x) {
      if (x >= 0 && y >= 0 && x < L.w && y < L.h) inner.push_back(L.at(x, y));
    }
  }
  const double level = Percentile(inner, 0.5);
  if (!(level > frame_level)) return false;
  const double threshold = frame_level > 0 ? std::sqrt(level * frame_level) : 0.3 * level;
  // Region growing (4-connected) from the above-threshold pixel nearest the prediction.
  const int ww = x1 - x0 + 1, hh = y1 - y0 + 1;
  std::vector<uint8_t> in(size_t(ww) * size_t(hh), 0);
  int seed = -1;
  double best = 1e30;
  for (int y = y0; y <= y1; ++y) {
    for (int x = x0; x <= x1; ++x) {
      if (L.at(x, y) <= threshold) continue;
      const double d = (Vec2d(x, y) - c).squaredNorm();
      if (d < best) {
        best = d;
        seed = (y - y0) * ww + (x - x0);
      }
    }
  }
  if (seed < 0 || best > 0.16 * side * side) return false;
  std::queue<int> q;
  q.push(seed);
  in[size_t(seed)] = 1;
  int count = 0;
  while (!q.empty()) {
    const int i = q.front();
    q.pop();
    ++count;
    const int x = i % ww, y = i / ww;
    const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
    for (int k = 0; k < 4; ++k) {
      if (nx[k] < 0 || ny[k] < 0 || nx[k] >= ww || ny[k] >= hh) continue;
      const int j = ny[k] * ww + nx[k];
      if (in[size_t(j)] || L.at(nx[k] + x0, ny[k] + y0) <= threshold) continue;
      in[size_t(j)] = 1;
      q.push(j);
    }
  }
  if (count < kMinAreaRatio * area || count > kMaxAreaRatio * area) return false;
  // Soft membership over the region dilated by one pixel (its partially covered rim).
  double sw = 0, sx = 0, sy = 0;
  for (int y = 0; y < hh; ++y) {
    for (int x = 0; x < ww; ++x) {
      bool near = in[size_t(y * ww + x)];
      for (int dy = -1; dy <= 1 && !near; ++dy) {
        for (int dx = -1; dx <= 1 && !near; ++dx) {
          const int xx = x + dx, yy = y + dy;
          near = xx >= 0 && yy >= 0 && xx < ww && yy < hh && in[size_t(yy * ww + xx)];
        }
      }
      if (!near) continue;
      const double m = std::clamp((L.at(x + x0, y + y0) - frame_level) / (level - frame_level), 0.0, 1.0);
      sw += m;
      sx += m * (x + x0);
      sy += m * (y + y0);
    }
  }
  if (!(sw > 0)) return false;
  *centroid = Vec2d(sx / sw, sy / sw);
  return true;
}

// The frame level: a low percentile of luminance inside the chart's grid outline (the gaps are
// a quarter of it).
double FrameLevel(const LumaImage& L, const cv::Matx33d& H, const ChartLayout& layout) {
  const auto outline = GridOutline(layout);
  std::vector<cv::Point> poly;
  for (const Vec2d& p : outline) {
    const Vec2d q = Apply(H, p);
    poly.emplace_back(int(std::lround(q.x())), int(std::lround(q.y())));
  }
  const cv::Rect box = cv::boundingRect(poly) & cv::Rect(0, 0, L.w, L.h);
  std::vector<double> values;
  for (int y = box.y; y < box.y + box.height; ++y) {
    for (int x = box.x; x < box.x + box.width; ++x) {
      if (cv::pointPolygonTest(poly, cv::Point2f(float(x), float(y)), false) >= 0) values.push_back(L.at(x, y));
    }
  }
  return Percentile(values, 0.05);
}

// Patch median luminance over the inner half (for edge profiles).
double PatchLevel(const LumaImage& L, const PatchQuad& q) {
  const Vec2d c = 0.25 * (q[0] + q[1] + q[2] + q[3]);
  const double r = 0.2 * (q[1] - q[0]).norm();
  std::vector<double> v;
  for (int y = int(c.y() - r); y <= int(c.y() + r); ++y) {
    for (int x = int(c.x() - r); x <= int(c.x() + r); ++x) {
      if (x >= 0 && y >= 0 && x < L.w && y < L.h) v.push_back(L.at(x, y));
    }
  }
  return Percentile(v, 0.5);
}

struct Line {
  Vec2d point, direction;  // direction unit
};

bool Intersect(const Line& a, const Line& b, Vec2d* p) {
  const double det = a.direction.x() * (-b.direction.y()) - a.direction.y() * (-b.direction.x());
  if (std::abs(det) < 1e-9) return false;
  const Vec2d d = b.point - a.point;
  const double t = (d.x() * (-b.direction.y()) - d.y() * (-b.direction.x())) / det;
  *p = a.point + t * a.direction;
  return true;
}

// Sub-pixel corners of every patch from edge profiles; patches whose edges fail keep the
// homography's prediction. Returns the number of edges refined.
int RefineCorners(const LumaImage& L, const cv::Matx33d& H, const ChartLayout& layout,
                  double frame_level, ChartCorners* corners, std::array<bool, kChartPatches>* measured) {
  int refined = 0;
  measured->fill(false);
  for (int patch = 0; patch < kChartPatches; ++patch) {
    PatchQuad q;
    for (int k = 0; k < 4; ++k) q[size_t(k)] = Apply(H, layout.PatchCorner(patch, k));
    (*corners)[size_t(patch)] = q;
    const double level = PatchLevel(L, q);
    if (!(level > frame_level)) continue;
    const Vec2d centre = 0.25 * (q[0] + q[1] + q[2] + q[3]);
    std::array<Line, 4> lines;
    std::array<bool, 4> ok{};
    for (int e = 0; e < 4; ++e) {
      const Vec2d a = q[size_t(e)], b = q[size_t((e + 1) % 4)];
      const double length = (b - a).norm();
      if (!(length > 4)) continue;
      const Vec2d dir = (b - a) / length;
      Vec2d n(-dir.y(), dir.x());
      if (n.dot(0.5 * (a + b) - centre) < 0) n = -n;  // outward
      const double gap_px = length * layout.gap_m / layout.patch_m;
      // The step is integrated from kEdgeInnerPx inside the predicted edge to the middle of the
      // gap; the patch level is taken locally, just inside that window, because the light's
      // fall-off across a patch (a few % on a chart under a near light) would otherwise bias
      // the area by (level error) × (window length).
      const double s_in = std::min(kEdgeInnerPx, 0.25 * length), s_out = 0.5 * gap_px;
      std::vector<double> outside;
      for (int k = 0; k < kEdgeSamples; ++k) {
        const Vec2d p = a + (0.2 + 0.6 * (k + 0.5) / kEdgeSamples) * (b - a);
        outside.push_back(L.Sample(p.x() + s_out * n.x(), p.y() + s_out * n.y()));
      }
      const double out_level = std::min(Percentile(outside, 0.5), frame_level * 2 + 1e-30);
      std::vector<Vec2d> points;
      for (int k = 0; k < kEdgeSamples; ++k) {
        const Vec2d p = a + (0.2 + 0.6 * (k + 0.5) / kEdgeSamples) * (b - a);
        double inner_level = 0;
        for (int i = 0; i < kEdgeInnerSamples; ++i) {
          const double s = -s_in - (i + 0.5) * (s_in / kEdgeInnerSamples);
          inner_level += L.Sample(p.x() + s * n.x(), p.y() + s * n.y()) / kEdgeInnerSamples;
        }
        if (!(inner_level - out_level > 0.5 * (level - out_level))) continue;
        // Area under the normalised profile from −s_in to +s_out = distance from −s_in to the edge.
        double integral = 0;
        const int steps = int(std::ceil((s_in + s_out) / kEdgeProfileStep));
        const double ds = (s_in + s_out) / steps;
        for (int i = 0; i < steps; ++i) {
          const double s = -s_in + (i + 0.5) * ds;
          const double v = L.Sample(p.x() + s * n.x(), p.y() + s * n.y());
          integral += (v - out_level) / (inner_level - out_level) * ds;
        }
        const double offset = -s_in + integral;
        if (std::abs(offset) < s_out) points.push_back(p + offset * n);
      }
      if (points.size() < size_t(kEdgeSamples / 2)) continue;
      Vec2d mean = Vec2d::Zero();
      for (const Vec2d& p : points) mean += p;
      mean /= double(points.size());
      Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
      for (const Vec2d& p : points) cov += (p - mean) * (p - mean).transpose();
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
      lines[size_t(e)] = {mean, es.eigenvectors().col(1).normalized()};
      ok[size_t(e)] = true;
    }
    if (!(ok[0] && ok[1] && ok[2] && ok[3])) continue;
    PatchQuad refined_quad;
    bool all = true;
    // Corner k joins edge k−1 (ending there) and edge k (starting there).
    for (int k = 0; k < 4 && all; ++k) {
      all = Intersect(lines[size_t((k + 3) % 4)], lines[size_t(k)], &refined_quad[size_t(k)]);
      all = all && (refined_quad[size_t(k)] - q[size_t(k)]).norm() < 0.5 * (q[1] - q[0]).norm();
    }
    if (!all) continue;
    (*corners)[size_t(patch)] = refined_quad;
    (*measured)[size_t(patch)] = true;
    refined += 4;
  }
  return refined;
}

// Mean camera colour of each patch's inner half (for the orientation test).
std::array<Vec3d, kChartPatches> PatchMeans(const Image& hdr, const ChartCorners& corners) {
  std::array<Vec3d, kChartPatches> out;
  for (int i = 0; i < kChartPatches; ++i) {
    const PatchQuad& q = corners[size_t(i)];
    const Vec2d c = 0.25 * (q[0] + q[1] + q[2] + q[3]);
    const double r = 0.2 * (q[1] - q[0]).norm();
    Vec3d sum = Vec3d::Zero();
    int n = 0;
    for (int y = int(c.y() - r); y <= int(c.y() + r); ++y) {
      for (int x = int(c.x() - r); x <= int(c.x() + r); ++x) {
        if (x < 0 || y < 0 || x >= hdr.width || y >= hdr.height) continue;
        const float* p = hdr.pixel(x, y);
        sum += Vec3d(p[0], p[1], p[2]);
        ++n;
      }
    }
    out[size_t(i)] = n > 0 ? Vec3d(sum / n) : Vec3d::Zero();
  }
  return out;
}

// RMS of log(measured / reference) after the best per-channel gain.
double ColourResidual(const std::array<Vec3d, kChartPatches>& means) {
  double sum2 = 0;
  int n = 0;
  for (int c = 0; c < 3; ++c) {
    std::vector<double> d;
    for (int i = 0; i < kChartPatches; ++i) {
      const double m = means[size_t(i)][c], r = PatchAlbedo(i)[c];
      if (!(m > 0)) return 1e9;
      d.push_back(std::log(m / r));
    }
    double mean = 0;
    for (double v : d) mean += v;
    mean /= double(d.size());
    for (double v : d) {
      sum2 += (v - mean) * (v - mean);
      ++n;
    }
  }
  return std::sqrt(sum2 / n);
}

struct Refined {
  ChartCorners corners{};
  std::array<bool, kChartPatches> measured{};  // corners from the patch's own edges
  double residual = 1e9;
  int edges = 0;
  int segmented = 0;
};

// From a coarse homography to refined corners.
Refined Refine(const Image& hdr, const LumaImage& L, cv::Matx33d H, const ChartLayout& layout) {
  Refined r;
  double frame = FrameLevel(L, H, layout);
  for (int round = 0; round < kCentroidRounds; ++round) {
    std::vector<cv::Point2d> from, to;
    for (int i = 0; i < kChartPatches; ++i) {
      Vec2d centroid;
      if (!PatchCentroid(L, H, layout, i, frame, &centroid)) continue;
      const Vec2d c = layout.PatchPoint(i, 0.5, 0.5);
      from.emplace_back(c.x(), c.y());
      to.emplace_back(centroid.x(), centroid.y());
    }
    r.segmented = int(from.size());
    if (r.segmented < kMinPatchesSegmented) return r;
    H = Homography(from, to);
    if (H == cv::Matx33d::zeros()) return r;
    frame = FrameLevel(L, H, layout);
  }
  r.edges = RefineCorners(L, H, layout, frame, &r.corners, &r.measured);
  r.residual = ColourResidual(PatchMeans(hdr, r.corners));
  return r;
}

struct Pose {
  Rigid3 cam_from_chart;
  double rms = 1e9;
  bool ok = false;
};

// PnP on the corners of the patches whose edges were measured (a patch the photograph cuts off or
// hides keeps the homography's prediction, which must not steer the pose), all when too few were.
Pose SolvePose(const ChartCorners& corners, const std::array<bool, kChartPatches>& measured,
               const Camera& camera, const ChartLayout& layout) {
  Pose pose;
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  const bool enough = std::count(measured.begin(), measured.end(), true) >= kMinPatchesForPose;
  for (int i = 0; i < kChartPatches; ++i) {
    if (enough && !measured[size_t(i)]) continue;
    for (int k = 0; k < 4; ++k) {
      const Vec2d o = layout.PatchCorner(i, k);
      object.emplace_back(o.x(), o.y(), 0.0);
      image.emplace_back(corners[size_t(i)][size_t(k)].x(), corners[size_t(i)][size_t(k)].y());
    }
  }
  cv::Matx33d K;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) K(r, c) = camera.K(r, c);
  }
  cv::Mat dist(1, 5, CV_64F);
  for (int k = 0; k < 5; ++k) dist.at<double>(0, k) = camera.dist[size_t(k)];
  cv::Mat rvec, tvec;
  try {
    if (!cv::solvePnP(object, image, K, dist, rvec, tvec, false, cv::SOLVEPNP_IPPE)) return pose;
    cv::solvePnPRefineLM(object, image, K, dist, rvec, tvec);
  } catch (const cv::Exception& e) {
    REFLCAP_LOG(kDebug) << "chart PnP failed: " << e.what();
    return pose;
  }
  std::vector<cv::Point2d> projected;
  cv::projectPoints(object, rvec, tvec, K, dist, projected);
  double sum2 = 0;
  for (size_t i = 0; i < image.size(); ++i) {
    const double dx = projected[i].x - image[i].x, dy = projected[i].y - image[i].y;
    sum2 += dx * dx + dy * dy;
  }
  cv::Matx33d R;
  cv::Rodrigues(rvec, R);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) pose.cam_from_chart.rotation(r, c) = R(r, c);
    pose.cam_from_chart.translation[r] = tvec.at<double>(r);
  }
  pose.rms = std::sqrt(sum2 / double(image.size()));
  // The chart's +z must face the camera (a mirrored corner order cannot).
  const Vec3d normal_in_cam = pose.cam_from_chart.rotation.col(2);
  const Vec3d to_camera = -pose.cam_from_chart.translation;
  pose.ok = normal_in_cam.dot(to_camera) > 0 && std::isfinite(pose.rms);
  return pose;
}

}  // namespace

Status ChartLayout::Validate() const {
  if (!(patch_m > 0) || !std::isfinite(patch_m)) return InvalidArgumentError("chart patch size must be positive");
  if (!(gap_m > 0) || !std::isfinite(gap_m)) return InvalidArgumentError("chart gap must be positive");
  return OkStatus();
}

Vec2d ChartLayout::PatchPoint(int patch, double u, double v) const {
  const int row = patch / kChartColumns, col = patch % kChartColumns;
  const double pitch = patch_m + gap_m;
  const double width = kChartColumns * patch_m + (kChartColumns - 1) * gap_m;
  const double height = kChartRows * patch_m + (kChartRows - 1) * gap_m;
  const double left = -0.5 * width + col * pitch, top = 0.5 * height - row * pitch;
  return Vec2d(left + u * patch_m, top - v * patch_m);
}

Vec2d ChartLayout::PatchCorner(int patch, int corner) const {
  static const double kU[4] = {0, 1, 1, 0}, kV[4] = {0, 0, 1, 1};
  return PatchPoint(patch, kU[corner], kV[corner]);
}

StatusOr<ChartDetection> DetectChart(const Image& camera_hdr, const Camera& camera,
                                     const ChartLayout& layout,
                                     const std::optional<ChartCorners>& declared, bool use_mcc) {
  REFLCAP_RETURN_IF_ERROR(layout.Validate());
  const LumaImage L = ToLuma(camera_hdr);
  const auto outline = GridOutline(layout);
  struct Candidate {
    Refined refined;
    std::string seed;
    std::vector<Vec2d> box;
    Pose pose;
  };
  std::optional<Candidate> best;
  auto consider = [&](const cv::Matx33d& H, const std::string& seed, const std::vector<Vec2d>& box) {
    Candidate c;
    c.refined = Refine(camera_hdr, L, H, layout);
    if (c.refined.residual > kMaxColourResidual) return;
    c.pose = SolvePose(c.refined.corners, c.refined.measured, camera, layout);
    if (!c.pose.ok || c.pose.rms > kMaxReprojectionPx) return;
    c.seed = seed;
    c.box = box;
    if (!best || c.refined.residual < best->refined.residual) best = c;
  };

  // mcc on several renditions; every cyclic order and winding of its outline.
  for (double level : kToneLevels) {
    for (double scale : kMccScales) {
      if (!use_mcc) continue;
      const cv::Mat bgr = ToneMapped(camera_hdr, level, scale);
      std::vector<Vec2d> box;
      try {
        cv::Ptr<cv::mcc::CCheckerDetector> detector = cv::mcc::CCheckerDetector::create();
        if (!detector->process(bgr, cv::mcc::MCC24, 1)) continue;
        cv::Ptr<cv::mcc::CChecker> checker = detector->getBestColorChecker();
        if (checker.empty()) continue;
        for (const cv::Point2f& p : checker->getBox()) box.emplace_back(p.x / scale, p.y / scale);
      } catch (const cv::Exception& e) {
        REFLCAP_LOG(kDebug) << "mcc failed on a rendition: " << e.what();
        continue;
      }
      if (box.size() != 4) continue;
      for (int winding = 0; winding < 2; ++winding) {
        for (int shift = 0; shift < 4; ++shift) {
          std::vector<cv::Point2d> from, to;
          for (int k = 0; k < 4; ++k) {
            const int j = winding == 0 ? (k + shift) % 4 : (shift - k + 4) % 4;
            from.emplace_back(outline[size_t(k)].x(), outline[size_t(k)].y());
            to.emplace_back(box[size_t(j)].x(), box[size_t(j)].y());
          }
          const cv::Matx33d H = Homography(from, to);
          if (H == cv::Matx33d::zeros()) continue;
          consider(H, StrCat("mcc (tone level ", level, ", scale ", scale, ", corner order ",
                             winding == 0 ? "+" : "-", shift, ")"),
                   box);
        }
      }
    }
  }
  std::string method = "mcc";
  if (!best && declared) {
    std::vector<cv::Point2d> from, to;
    for (int i = 0; i < kChartPatches; ++i) {
      for (int k = 0; k < 4; ++k) {
        const Vec2d o = layout.PatchCorner(i, k);
        from.emplace_back(o.x(), o.y());
        to.emplace_back((*declared)[size_t(i)][size_t(k)].x(), (*declared)[size_t(i)][size_t(k)].y());
      }
    }
    const cv::Matx33d H = Homography(from, to);
    if (H != cv::Matx33d::zeros()) consider(H, "declared corners_px", {});
    method = "declared";
  }
  if (!best) {
    return NotFoundError(
        "no ColorChecker found: ",
        use_mcc ? "OpenCV mcc found no 24-patch chart whose patches match the reference colours"
                : "mcc not used",
        declared ? ", and the declared corners did not refine to one"
                 : ", and no chart geometry declares its corners (photos[].chart: a file with "
                   "patches[].corners_px)");
  }
  ChartDetection d;
  d.method = method;
  d.seed = best->seed;
  d.mcc_box = best->box;
  d.corners_px = best->refined.corners;
  d.cam_from_chart = best->pose.cam_from_chart;
  d.world_from_chart = camera.cam_from_world.Inverse() * d.cam_from_chart;
  d.reprojection_rms_px = best->pose.rms;
  d.colour_residual = best->refined.residual;
  d.edges_refined = best->refined.edges;
  return d;
}

std::vector<ChartPixel> ChartInnerPixels(const ChartDetection& detection, const Camera& camera,
                                         const ChartLayout& layout, const Light& light, double inner) {
  std::vector<ChartPixel> out;
  const Rigid3 chart_from_cam = detection.cam_from_chart.Inverse();
  const Vec3d normal_world = detection.world_from_chart.rotation.col(2);
  const double lo = 0.5 - 0.5 * inner, hi = 0.5 + 0.5 * inner;
  for (int patch = 0; patch < kChartPatches; ++patch) {
    double x0 = 1e30, x1 = -1e30, y0 = 1e30, y1 = -1e30;
    for (int k = 0; k < 4; ++k) {
      const Vec2d p = detection.corners_px[size_t(patch)][size_t(k)];
      x0 = std::min(x0, p.x());
      x1 = std::max(x1, p.x());
      y0 = std::min(y0, p.y());
      y1 = std::max(y1, p.y());
    }
    const Vec2d tl = layout.PatchPoint(patch, 0, 0);
    for (int y = std::max(0, int(std::floor(y0))); y <= std::min(camera.height - 1, int(std::ceil(y1))); ++y) {
      for (int x = std::max(0, int(std::floor(x0))); x <= std::min(camera.width - 1, int(std::ceil(x1))); ++x) {
        Vec3d origin, dir;
        camera.PixelRay(Vec2d(x, y), &origin, &dir);
        const Vec3d o = chart_from_cam * origin;
        const Vec3d d = chart_from_cam.rotation * dir;
        if (!(std::abs(d.z()) > 1e-12)) continue;
        const double t = -o.z() / d.z();
        if (!(t > 0)) continue;
        const Vec3d hit = o + t * d;
        const double u = (hit.x() - tl.x()) / layout.patch_m, v = (tl.y() - hit.y()) / layout.patch_m;
        if (u < lo || u > hi || v < lo || v > hi) continue;
        const Vec3d point_world = detection.world_from_chart * Vec3d(hit.x(), hit.y(), 0);
        double geometry = 0;
        if (light.type == LightType::kPoint) {
          const Vec3d to_light = light.position - point_world;
          const double d2 = to_light.squaredNorm();
          geometry = std::max(0.0, normal_world.dot(to_light) / std::sqrt(d2)) / d2;
        } else {
          geometry = std::max(0.0, normal_world.dot(light.direction));
        }
        out.push_back({x, y, patch, geometry});
      }
    }
  }
  return out;
}

Mat3d ColourCalibration::Correction() const {
  if (matrix_applied) return matrix;
  return Vec3d(1 / gains[0], 1 / gains[1], 1 / gains[2]).asDiagonal();
}

StatusOr<ColourCalibration> CalibrateColour(const MergedBracket& chart,
                                            const std::vector<ChartPixel>& pixels,
                                            const Light& light, bool apply_matrix) {
  ColourCalibration cal;
  const int w = chart.value.width;
  std::array<Vec3d, kChartPatches> sum_albedo;
  std::array<int, kChartPatches> count{}, clipped{};
  for (auto& s : sum_albedo) s = Vec3d::Zero();
  Vec3d num = Vec3d::Zero(), den = Vec3d::Zero();
  std::array<std::vector<double>, 3> neutral_ratios;
  std::array<Vec3d, kChartPatches> patch_num, patch_den;
  for (int i = 0; i < kChartPatches; ++i) {
    patch_num[size_t(i)] = patch_den[size_t(i)] = Vec3d::Zero();
  }
  for (const ChartPixel& px : pixels) {
    const size_t p = size_t(px.y) * size_t(w) + size_t(px.x);
    bool ok = px.geometry > 0;
    for (int c = 0; c < 3 && ok; ++c) ok = chart.flags[p * 3 + size_t(c)] == uint8_t(MergeFlag::kMeasured);
    if (!ok) {
      ++clipped[size_t(px.patch)];
      continue;
    }
    const Vec3d albedo = PatchAlbedo(px.patch);
    for (int c = 0; c < 3; ++c) {
      const double E = light.intensity[c] * px.geometry;
      const double m = chart.value.data[p * 3 + size_t(c)];
      const double var = std::max(double(chart.variance.data[p * 3 + size_t(c)]), 1e-30);
      const double ref = albedo[c] * kInvPi * E;
      sum_albedo[size_t(px.patch)][c] += m * kPi / E;
      patch_num[size_t(px.patch)][c] += m * ref / var;
      patch_den[size_t(px.patch)][c] += ref * ref / var;
      if (px.patch >= kFirstNeutralPatch) {
        num[c] += m * ref / var;
        den[c] += ref * ref / var;
      }
    }
    ++count[size_t(px.patch)];
  }
  for (int i = kFirstNeutralPatch; i < kChartPatches; ++i) {
    if (count[size_t(i)] == 0) {
      return FailedPreconditionError("chart patch ", i + 1, " (", ColorCheckerClassic()[size_t(i)].name,
                                     "): no pixel measured in every channel (clipped or black in "
                                     "every exposure)");
    }
    for (int c = 0; c < 3; ++c) {
      neutral_ratios[size_t(c)].push_back(patch_num[size_t(i)][c] / patch_den[size_t(i)][c]);
    }
  }
  for (int c = 0; c < 3; ++c) {
    cal.gains[c] = num[c] / den[c];
    double mean = 0, m2 = 0;
    for (double r : neutral_ratios[size_t(c)]) mean += r;
    mean /= double(neutral_ratios[size_t(c)].size());
    for (double r : neutral_ratios[size_t(c)]) m2 += (r - mean) * (r - mean);
    cal.neutral_ratio_spread[c] = std::sqrt(m2 / double(neutral_ratios[size_t(c)].size())) / mean;
  }
  // 3×3 matrix: true = M camera, per row weighted LS with relative weights 1/|ρ|².
  Eigen::Matrix<double, Eigen::Dynamic, 3> X(kChartPatches, 3);
  Eigen::Matrix<double, Eigen::Dynamic, 3> Y(kChartPatches, 3);
  int rows = 0;
  for (int i = 0; i < kChartPatches; ++i) {
    if (count[size_t(i)] == 0) continue;
    const Vec3d camera_albedo = sum_albedo[size_t(i)] / count[size_t(i)];
    const Vec3d reference = PatchAlbedo(i);
    const double wgt = 1 / reference.norm();
    X.row(rows) = wgt * camera_albedo.transpose();
    Y.row(rows) = wgt * reference.transpose();
    ++rows;
  }
  X.conservativeResize(rows, 3);
  Y.conservativeResize(rows, 3);
  if (rows >= 3) {
    const Eigen::Matrix3d Mt = X.colPivHouseholderQr().solve(Y);
    cal.matrix = Mt.transpose();
  }
  cal.matrix_applied = apply_matrix;
  const Mat3d correction = cal.Correction();
  const Mat3d gains_inv = Vec3d(1 / cal.gains[0], 1 / cal.gains[1], 1 / cal.gains[2]).asDiagonal();
  int n = 0;
  for (int i = 0; i < kChartPatches; ++i) {
    PatchColour& pc = cal.patches[size_t(i)];
    pc.name = ColorCheckerClassic()[size_t(i)].name;
    pc.reference_albedo = PatchAlbedo(i);
    pc.pixels = count[size_t(i)];
    pc.clipped = clipped[size_t(i)];
    if (count[size_t(i)] == 0) continue;
    pc.camera_albedo = sum_albedo[size_t(i)] / count[size_t(i)];
    pc.corrected_albedo = correction * pc.camera_albedo;
    const Vec3d ref_lab = LinearRgbToLab(pc.reference_albedo);
    pc.delta_e_before = DeltaE2000(LinearRgbToLab(pc.camera_albedo), ref_lab);
    pc.delta_e_gains = DeltaE2000(LinearRgbToLab(gains_inv * pc.camera_albedo), ref_lab);
    pc.delta_e_matrix = DeltaE2000(LinearRgbToLab(cal.matrix * pc.camera_albedo), ref_lab);
    cal.mean_delta_e_before += pc.delta_e_before;
    cal.mean_delta_e_gains += pc.delta_e_gains;
    cal.mean_delta_e_matrix += pc.delta_e_matrix;
    cal.max_delta_e_gains = std::max(cal.max_delta_e_gains, pc.delta_e_gains);
    ++n;
  }
  if (n > 0) {
    cal.mean_delta_e_before /= n;
    cal.mean_delta_e_gains /= n;
    cal.mean_delta_e_matrix /= n;
  }
  return cal;
}

}  // namespace reflcap::radiometry
