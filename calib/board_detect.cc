#include "calib/board_detect.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/image/image_io.h"
#include "engine/image/png_io.h"
#include "engine/image/srgb.h"

namespace reflcap::calib {
namespace {

// SB calls per board before a full-image search gives up: every refused grid is masked and the
// search repeated, so a photo full of look-alike grids cannot loop for long.
constexpr int kMaxSearchesPerBoard = 3;
// Colour samples are the mean of five taps, the square centre and four points this far towards
// its corners (in squares): far enough to average noise, well inside the square.
constexpr double kColourTapOffset = 0.2;
// Fraction of a board's margin where the margin test samples: half-way, clear of the board's
// printed edge and of the face's edge.
constexpr double kMarginSampleFraction = 0.5;
// A found grid must lie within this fraction of the median corner spacing of its prediction:
// below one half, a grid shifted by a whole square can never pass.
constexpr double kPredictionTolerance = 0.35;

// Symmetry refinement: at most this many Levenberg-Marquardt steps (it settles in 3-6 from a
// detector's corner), and "settled" once a step moves the corner by less than this (pixels),
// far below the corners' noise of a few hundredths of a pixel.
constexpr int kSymmetryMaxIterations = 30;
constexpr double kSymmetrySettledPx = 1e-4;
// Symmetry refinement passes (RefineCorners): the second one starts from refined neighbours.
constexpr int kSymmetryPasses = 2;
// Symmetry refinement with shading: the odd monomials of the light up to cubic (RefineBySymmetry).
constexpr int kShadingTerms = 6;
// Samples from a window's centre to its edge, at most: 48 keeps one corner's evaluation near
// 10^4 bicubic taps pairs; at 0.7 px spacing only squares beyond 56 px reach it.
constexpr int kSymmetryMaxSamplesPerSide = 48;

cv::Mat ToGrey8(const Image& grey) {
  cv::Mat out(grey.height, grey.width, CV_8U);
  for (int y = 0; y < grey.height; ++y) {
    auto* row = out.ptr<uint8_t>(y);
    for (int x = 0; x < grey.width; ++x) {
      const float v = grey.at(x, y);
      row[x] = uint8_t(std::clamp(std::lround(double(v) * 255.0), 0L, 255L));
    }
  }
  return out;
}

cv::Mat ToGrey32(const Image& grey) {
  cv::Mat out(grey.height, grey.width, CV_32F);
  for (int y = 0; y < grey.height; ++y) {
    auto* row = out.ptr<float>(y);
    for (int x = 0; x < grey.width; ++x) row[x] = 255.0f * grey.at(x, y);
  }
  return out;
}

// Bilinear sample; nullopt outside the image. The 0.001-pixel inset keeps x0 + 1 inside the
// image for a point on its last column or row.
std::optional<double> Sample(const Image& grey, const Vec2d& p) {
  if (!(p.x() >= 0 && p.y() >= 0 && p.x() <= grey.width - 1.001 && p.y() <= grey.height - 1.001)) {
    return std::nullopt;
  }
  const int x0 = int(p.x()), y0 = int(p.y());
  const double fx = p.x() - x0, fy = p.y() - y0;
  return (1 - fy) * ((1 - fx) * grey.at(x0, y0) + fx * grey.at(x0 + 1, y0)) +
         fy * ((1 - fx) * grey.at(x0, y0 + 1) + fx * grey.at(x0 + 1, y0 + 1));
}

Vec2d ApplyHomography(const cv::Matx33d& h, const Vec2d& p) {
  const cv::Vec3d q = h * cv::Vec3d(p.x(), p.y(), 1.0);
  return {q[0] / q[2], q[1] / q[2]};
}

// Homography from board coordinates (squares from inner corner (0,0)) to pixels.
std::optional<cv::Matx33d> BoardHomography(const BoardSpec& board, const std::vector<Vec2d>& corners) {
  std::vector<cv::Point2f> src, dst;
  for (int k = 0; k < board.CornerCount(); ++k) {
    src.emplace_back(float(k % board.corners_x), float(k / board.corners_x));
    dst.emplace_back(float(corners[k].x()), float(corners[k].y()));
  }
  cv::Mat h;
  try {
    h = cv::findHomography(src, dst, 0);
  } catch (const cv::Exception&) {
    return std::nullopt;
  }
  if (h.empty()) return std::nullopt;
  return cv::Matx33d(h);
}

struct ColourCheck {
  bool pass = false;
  double contrast = 0;
  std::string why;
};

// Square colours and white margin through the homography of the ordered corners.
ColourCheck CheckColours(const Image& grey, const BoardSpec& board, const std::vector<Vec2d>& corners,
                         const DetectOptions& options) {
  ColourCheck out;
  const auto h = BoardHomography(board, corners);
  if (!h) {
    out.why = "no homography";
    return out;
  }
  auto tap_mean = [&](double i, double j) -> std::optional<double> {
    double sum = 0;
    int n = 0;
    const double o = kColourTapOffset;
    for (const Vec2d& d : {Vec2d(0, 0), Vec2d(o, o), Vec2d(-o, o), Vec2d(o, -o), Vec2d(-o, -o)}) {
      if (auto v = Sample(grey, ApplyHomography(*h, Vec2d(i + d.x(), j + d.y())))) {
        sum += *v;
        ++n;
      }
    }
    if (n == 0) return std::nullopt;
    return sum / n;
  };
  std::vector<double> black, white;
  for (int b = 0; b < board.squares_y; ++b) {
    for (int a = 0; a < board.squares_x; ++a) {
      auto v = tap_mean(a - 0.5, b - 0.5);
      if (!v) continue;
      ((a + b) % 2 == 0 ? black : white).push_back(*v);
    }
  }
  if (black.empty() || white.empty()) {
    out.why = "squares outside the photo";
    return out;
  }
  const double mb = std::accumulate(black.begin(), black.end(), 0.0) / black.size();
  const double mw = std::accumulate(white.begin(), white.end(), 0.0) / white.size();
  out.contrast = mw - mb;
  if (out.contrast < options.min_contrast) {
    out.why = StrCat("square colours do not match (white - black = ", out.contrast, ")");
    return out;
  }
  const double mid = 0.5 * (mb + mw);
  const int wrong = int(std::count_if(black.begin(), black.end(), [&](double v) { return v >= mid; }) +
                        std::count_if(white.begin(), white.end(), [&](double v) { return v <= mid; }));
  if (wrong > 0) {
    out.why = StrCat(wrong, " squares have the wrong colour");
    return out;
  }
  // Margin: half-way into the declared white border on all four sides.
  const double mu = board.margin_u_m / board.square_m, mv = board.margin_v_m / board.square_m;
  if (mu > 0 && mv > 0) {
    const double left = -1 - kMarginSampleFraction * mu;
    const double right = board.squares_x - 1 + kMarginSampleFraction * mu;
    const double top = -1 - kMarginSampleFraction * mv;
    const double bottom = board.squares_y - 1 + kMarginSampleFraction * mv;
    int dark = 0, seen = 0;
    auto test = [&](double i, double j) {
      if (auto v = Sample(grey, ApplyHomography(*h, Vec2d(i, j)))) {
        ++seen;
        dark += *v <= mid;
      }
    };
    for (int b = 0; b < board.squares_y; ++b) {
      test(left, b - 0.5);
      test(right, b - 0.5);
    }
    for (int a = 0; a < board.squares_x; ++a) {
      test(a - 0.5, top);
      test(a - 0.5, bottom);
    }
    if (dark > 0) {
      out.why = StrCat(dark, " of ", seen, " margin samples are dark (a part of a larger grid?)");
      return out;
    }
  }
  out.pass = true;
  return out;
}

struct RawGrid {
  std::vector<Vec2d> corners;  // row-major, w per row
  int w = 0, h = 0;
};

std::optional<RawGrid> RunSb(const cv::Mat& grey8, int cx, int cy, int flags) {
  std::vector<cv::Point2f> corners;
  cv::Mat meta;
  bool found = false;
  try {
    found = cv::findChessboardCornersSB(grey8, cv::Size(cx, cy), corners, flags, meta);
  } catch (const cv::Exception&) {
    return std::nullopt;
  }
  if (!found || corners.empty()) return std::nullopt;
  RawGrid g;
  if (!meta.empty() && size_t(meta.rows) * size_t(meta.cols) == corners.size()) {
    g.w = meta.cols;
    g.h = meta.rows;
  } else if (int(corners.size()) == cx * cy) {
    g.w = cx;
    g.h = cy;
  } else {
    return std::nullopt;
  }
  for (const auto& p : corners) g.corners.emplace_back(p.x, p.y);
  return g;
}

// The raw grid's index of board corner (i, j) under symmetry `s` (0..7): bit 2 transposes, bit 0
// flips the raw column, bit 1 the raw row. False when the board's grid does not fit.
bool MapSymmetry(const RawGrid& g, const BoardSpec& b, int s, std::vector<int>* raw_index) {
  const bool transpose = s & 4;
  const int bw = transpose ? g.h : g.w, bh = transpose ? g.w : g.h;
  if (b.corners_x != bw || b.corners_y != bh) return false;
  raw_index->resize(b.CornerCount());
  for (int j = 0; j < b.corners_y; ++j) {
    for (int i = 0; i < b.corners_x; ++i) {
      int c = transpose ? j : i, r = transpose ? i : j;
      if (s & 1) c = g.w - 1 - c;
      if (s & 2) r = g.h - 1 - r;
      (*raw_index)[j * b.corners_x + i] = r * g.w + c;
    }
  }
  return true;
}

// Image-space handedness of an ordered grid: > 0 when u (i) and v (j) turn like the image's x
// and y, as for a board seen from its printed side.
double Handedness(const BoardSpec& b, const std::vector<Vec2d>& c) {
  const Vec2d o = c[0];
  const Vec2d du = c[b.corners_x - 1] - o;
  const Vec2d dv = c[(b.corners_y - 1) * b.corners_x] - o;
  return du.x() * dv.y() - du.y() * dv.x();
}

struct Identified {
  int board = -1;
  std::vector<Vec2d> corners;
  std::vector<std::vector<int>> alternatives;  // see BoardDetection
  double contrast = 0;
};

// Identifies a raw grid among `allowed` boards; nullopt with `why` when none fits. Numberings of
// one board that pass equally (a symmetric board) are kept as alternatives.
std::optional<Identified> Identify(const Image& grey, const RawGrid& g, const std::vector<BoardSpec>& boards,
                                   const std::vector<int>& allowed, const DetectOptions& options,
                                   std::string* why) {
  std::vector<std::vector<int>> passing;
  int passing_board = -1;
  double contrast = 0;
  std::string last_reason = StrCat("a ", g.w, "x", g.h, " grid matches no board searched");
  for (int index : allowed) {
    const BoardSpec& b = boards[index];
    for (int s = 0; s < 8; ++s) {
      std::vector<int> raw_index;
      if (!MapSymmetry(g, b, s, &raw_index)) continue;
      if (std::find(passing.begin(), passing.end(), raw_index) != passing.end()) continue;
      std::vector<Vec2d> ordered(raw_index.size());
      for (size_t k = 0; k < raw_index.size(); ++k) ordered[k] = g.corners[raw_index[k]];
      if (Handedness(b, ordered) <= 0) continue;
      const ColourCheck check = CheckColours(grey, b, ordered, options);
      if (!check.pass) {
        last_reason = StrCat("a ", g.w, "x", g.h, " grid as board \"", b.name, "\": ", check.why);
        continue;
      }
      if (passing_board >= 0 && passing_board != index) {
        *why = StrCat("a ", g.w, "x", g.h, " grid fits two boards");
        return std::nullopt;
      }
      passing_board = index;
      contrast = check.contrast;
      passing.push_back(std::move(raw_index));
    }
  }
  if (passing.empty()) {
    *why = last_reason;
    return std::nullopt;
  }
  Identified out;
  out.board = passing_board;
  out.contrast = contrast;
  const std::vector<int>& first = passing.front();
  for (int raw : first) out.corners.push_back(g.corners[raw]);
  std::vector<int> position_of_raw(g.corners.size(), -1);
  for (size_t k = 0; k < first.size(); ++k) position_of_raw[first[k]] = int(k);
  for (size_t a = 1; a < passing.size(); ++a) {
    std::vector<int> alt(first.size());
    for (size_t k = 0; k < first.size(); ++k) alt[k] = position_of_raw[passing[a][k]];
    out.alternatives.push_back(std::move(alt));
  }
  return out;
}

// Identify, and when the grid is larger than every board it could be (SB with CALIB_CB_LARGER
// sometimes grows a grid by a row of spurious corners along a board's edge), every sub-grid of a
// board's size too: the margin test picks the true board among them.
std::optional<Identified> IdentifyWithSubgrids(const Image& grey, const RawGrid& g,
                                               const std::vector<BoardSpec>& boards,
                                               const std::vector<int>& allowed,
                                               const DetectOptions& options, std::string* why) {
  if (auto id = Identify(grey, g, boards, allowed, options, why)) return id;
  const std::string first_why = *why;
  std::vector<Identified> found;
  for (int index : allowed) {
    const BoardSpec& b = boards[index];
    for (const auto& [sw, sh] : {std::pair{b.corners_x, b.corners_y}, {b.corners_y, b.corners_x}}) {
      if (sw > g.w || sh > g.h || (sw == g.w && sh == g.h)) continue;
      for (int r0 = 0; r0 + sh <= g.h; ++r0) {
        for (int c0 = 0; c0 + sw <= g.w; ++c0) {
          RawGrid sub;
          sub.w = sw;
          sub.h = sh;
          for (int r = 0; r < sh; ++r) {
            for (int c = 0; c < sw; ++c) sub.corners.push_back(g.corners[(r0 + r) * g.w + c0 + c]);
          }
          std::string sub_why;
          if (auto id = Identify(grey, sub, boards, {index}, options, &sub_why)) found.push_back(std::move(*id));
        }
      }
    }
  }
  if (found.size() == 1) return std::move(found.front());
  *why = found.empty() ? first_why : StrCat(first_why, "; ", found.size(), " of its sub-grids fit");
  return std::nullopt;
}

// Fills the polygon (pixels) of the 8-bit work image with `value`.
void FillPolygon(cv::Mat* img, const std::vector<Vec2d>& polygon, uint8_t value) {
  std::vector<cv::Point> pts;
  for (const Vec2d& p : polygon) pts.emplace_back(int(std::lround(p.x())), int(std::lround(p.y())));
  cv::fillConvexPoly(*img, pts, cv::Scalar(value));
}

// The pixel outline of a raw grid grown by one square plus a little: what to hide once handled.
std::vector<Vec2d> RawGridCover(const RawGrid& g) {
  std::vector<cv::Point2f> src, dst;
  for (int k = 0; k < g.w * g.h; ++k) {
    src.emplace_back(float(k % g.w), float(k / g.w));
    dst.emplace_back(float(g.corners[k].x()), float(g.corners[k].y()));
  }
  cv::Mat hm = cv::findHomography(src, dst, 0);
  std::vector<Vec2d> out;
  if (hm.empty()) {
    std::vector<cv::Point2f> hull;
    cv::convexHull(dst, hull);
    for (const auto& p : hull) out.emplace_back(p.x, p.y);
    return out;
  }
  const cv::Matx33d h(hm);
  // One square beyond the outer corners covers the outer ring of squares; 0.3 more the edge.
  const double e = 1.3;
  for (const Vec2d& p : {Vec2d(-e, -e), Vec2d(g.w - 1 + e, -e), Vec2d(g.w - 1 + e, g.h - 1 + e),
                         Vec2d(-e, g.h - 1 + e)}) {
    out.push_back(ApplyHomography(h, p));
  }
  return out;
}

double MedianSpacing(const BoardSpec& b, const std::vector<Vec2d>& c) {
  std::vector<double> d;
  for (int j = 0; j < b.corners_y; ++j) {
    for (int i = 0; i + 1 < b.corners_x; ++i) d.push_back((c[j * b.corners_x + i + 1] - c[j * b.corners_x + i]).norm());
  }
  for (int j = 0; j + 1 < b.corners_y; ++j) {
    for (int i = 0; i < b.corners_x; ++i) d.push_back((c[(j + 1) * b.corners_x + i] - c[j * b.corners_x + i]).norm());
  }
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return d[d.size() / 2];
}

// --- Symmetry refinement (header comment) ---------------------------------------------------------

// The photo as the refinement samples it: one float per pixel, row-major, sRGB decoded if asked.
struct Plane {
  int width = 0;
  int height = 0;
  std::vector<float> values;
};

Plane MakePlane(const Image& grey, bool srgb, double blur_sigma_px) {
  Plane p{grey.width, grey.height, std::vector<float>(grey.PixelCount())};
  for (int y = 0; y < grey.height; ++y) {
    for (int x = 0; x < grey.width; ++x) {
      // Clamped to [0, 1] first: the curve is defined there, and a photo's codes are.
      const double v = std::clamp(double(grey.at(x, y)), 0.0, 1.0);
      p.values[size_t(y) * grey.width + x] = float(srgb ? SrgbToLinear(v) : v);
    }
  }
  if (blur_sigma_px > 0) {
    cv::Mat m(p.height, p.width, CV_32F, p.values.data());
    cv::GaussianBlur(m, m, cv::Size(0, 0), blur_sigma_px, blur_sigma_px, cv::BORDER_REPLICATE);
  }
  return p;
}

// Keys' cubic convolution kernel (a = -1/2, the one that reproduces quadratics) and its derivative.
double CubicWeight(double t) {
  t = std::abs(t);
  if (t <= 1) return (1.5 * t - 2.5) * t * t + 1;
  if (t < 2) return ((-0.5 * t + 2.5) * t - 4) * t + 2;
  return 0;
}
double CubicSlope(double t) {
  const double sign = t < 0 ? -1 : 1;
  t = std::abs(t);
  if (t <= 1) return sign * (4.5 * t - 5) * t;
  if (t < 2) return sign * ((-1.5 * t + 5) * t - 4);
  return 0;
}

// Bicubic value and gradient at (x, y), pixel centres at integers; false where the 4x4 taps leave
// the photo.
bool SampleBicubic(const Plane& p, double x, double y, double* value, double* dx, double* dy) {
  if (!(x >= 1 && y >= 1 && x < p.width - 2 && y < p.height - 2)) return false;  // also NaN
  const int ix = int(std::floor(x)), iy = int(std::floor(y));
  const double fx = x - ix, fy = y - iy;
  double wx[4], sx[4], wy[4], sy[4];
  for (int i = 0; i < 4; ++i) {
    wx[i] = CubicWeight(fx - (i - 1));
    sx[i] = CubicSlope(fx - (i - 1));
    wy[i] = CubicWeight(fy - (i - 1));
    sy[i] = CubicSlope(fy - (i - 1));
  }
  double v = 0, gx = 0, gy = 0;
  for (int j = 0; j < 4; ++j) {
    const float* row = &p.values[size_t(iy - 1 + j) * p.width + (ix - 1)];
    double r = 0, rs = 0;
    for (int i = 0; i < 4; ++i) {
      r += wx[i] * row[i];
      rs += sx[i] * row[i];
    }
    v += wy[j] * r;
    gx += wy[j] * rs;
    gy += sy[j] * r;
  }
  *value = v;
  *dx = gx;
  *dy = gy;
  return true;
}

// The local map of a corner: board coordinates s (squares, the corner at 0) -> pixels,
// pixel = H(s + t), with H a homography through the corner's grid neighbours (held) and the
// translation t estimated. On a planar board H is the projection itself up to lens distortion,
// which bends an edge across the window by hundredths of a pixel at most (at the frame's edge),
// and alike on both sides of the corner.
struct CornerFrame {
  Eigen::Matrix3d H;
  double square_px = 0;  // pixels per square at the corner, sqrt |det dH/ds|

  Vec2d Map(const Vec2d& s, Eigen::Matrix2d* jacobian) const {
    const Eigen::Vector3d h = H * Eigen::Vector3d(s.x(), s.y(), 1);
    const Vec2d p = h.head<2>() / h.z();
    if (jacobian) {
      for (int c = 0; c < 2; ++c) jacobian->col(c) = (H.block<2, 1>(0, c) - p * H(2, c)) / h.z();
    }
    return p;
  }
};

// Homography through the corner's start and its (up to 8) grid neighbours, a lost neighbour left
// out (RANSAC). False when fewer than four points or a degenerate fit remain.
bool FitCornerFrame(const BoardSpec& board, const std::vector<Vec2d>& start, int i, int j,
                    CornerFrame* frame) {
  const Vec2d centre = start[size_t(j) * board.corners_x + i];
  if (!std::isfinite(centre.x()) || !std::isfinite(centre.y())) return false;
  std::vector<std::pair<Vec2d, Vec2d>> pairs = {{Vec2d::Zero(), Vec2d::Zero()}};  // (board, pixel - centre)
  std::vector<double> spacings;  // pixels per square to each neighbour
  for (int dj = -1; dj <= 1; ++dj) {
    for (int di = -1; di <= 1; ++di) {
      const int ii = i + di, jj = j + dj;
      if ((di == 0 && dj == 0) || ii < 0 || jj < 0 || ii >= board.corners_x || jj >= board.corners_y) continue;
      const Vec2d q = start[size_t(jj) * board.corners_x + ii] - centre;
      if (!std::isfinite(q.x()) || !std::isfinite(q.y())) continue;
      pairs.emplace_back(Vec2d(di, dj), q);
      spacings.push_back(q.norm() / std::hypot(di, dj));
    }
  }
  if (spacings.empty()) return false;
  // The median: a lost neighbour (far off) must not set the scale.
  std::nth_element(spacings.begin(), spacings.begin() + spacings.size() / 2, spacings.end());
  const double spacing = spacings[spacings.size() / 2];
  if (pairs.size() < 4) return false;
  std::vector<cv::Point2d> from, to;
  for (const auto& [b, q] : pairs) {
    from.emplace_back(b.x(), b.y());
    to.emplace_back(q.x(), q.y());
  }
  // RANSAC (OpenCV's, seeded the same on every call) with a quarter of a square as the inlier
  // bound, then least squares over the inliers; the corner itself must be one.
  cv::Mat h, inliers;
  try {
    h = cv::findHomography(from, to, cv::RANSAC, spacing / 4, inliers);
  } catch (const cv::Exception&) {
    return false;
  }
  if (h.empty() || inliers.empty() || inliers.at<uint8_t>(0) == 0 || cv::countNonZero(inliers) < 4) return false;
  Eigen::Matrix3d H;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) H(r, c) = h.at<double>(r, c);
  }
  // Back from offsets to pixels: H, then translate by the corner's start.
  Eigen::Matrix3d shift = Eigen::Matrix3d::Identity();
  shift.block<2, 1>(0, 2) = centre;
  frame->H = shift * H;
  Eigen::Matrix2d jacobian;
  frame->Map(Vec2d::Zero(), &jacobian);
  frame->square_px = std::sqrt(std::abs(jacobian.determinant()));
  // Below 2 px per square there is no pattern left to fit; a square size far from the neighbours'
  // spacing says the fit folded.
  return frame->square_px > 2 && frame->square_px > spacing / 3 && frame->square_px < 3 * spacing;
}

// Gauss-Newton (Levenberg-Marquardt damped) on the symmetry residual over t; false when the window
// leaves the photo or the solve does not settle. `corner` receives H(t).
bool RefineBySymmetry(const Plane& photo, const CornerFrame& frame, const DetectOptions& options,
                      Vec2d* corner) {
  // Sample spacing in squares: symmetry_step_px in the photo, coarser on squares so large that
  // the window would need more than kSymmetryMaxSamplesPerSide samples from centre to edge.
  const double step_px =
      std::max(options.symmetry_step_px, options.symmetry_radius * frame.square_px / kSymmetryMaxSamplesPerSide);
  const double h = step_px / frame.square_px;
  const int n = std::max(2, int(std::ceil(options.symmetry_radius / h)));
  // Unknowns x = (t, c): the translation and, with symmetry_shading, the odd part of the light
  // across the window, l(s) - l(-s) = 2 sum_k c_k m_k(s) relative to its mean, over the odd
  // monomials m = (a, b, a^3, a^2 b, a b^2, b^3) of s = (a, b) in squares (the even part cancels in
  // the residual). Residual per pair s, -s:
  //   I(H(s + t)) - I(H(-s + t)) - (c . m(s)) (I(H(s + t)) + I(H(-s + t))),
  // zero at the corner when the light is a cubic across the window. One sample of each pair: the
  // upper half of the window (and the positive half of its middle row).
  using VecP = Eigen::Matrix<double, 2 + kShadingTerms, 1>;
  using MatP = Eigen::Matrix<double, 2 + kShadingTerms, 2 + kShadingTerms>;
  const int unknowns = options.symmetry_shading ? 2 + kShadingTerms : 2;
  auto odd_terms = [](const Vec2d& s, double* m) {
    const double a = s.x(), b = s.y();
    m[0] = a;
    m[1] = b;
    m[2] = a * a * a;
    m[3] = a * a * b;
    m[4] = a * b * b;
    m[5] = b * b * b;
  };
  auto evaluate = [&](const VecP& x, MatP* jtj, VecP* jtr) -> std::optional<double> {
    double cost = 0;
    if (jtj) {
      jtj->setZero();
      jtr->setZero();
    }
    const Vec2d t = x.head<2>();
    for (int b = 0; b <= n; ++b) {
      for (int a = (b == 0 ? 1 : -n); a <= n; ++a) {
        const Vec2d s(a * h, b * h);
        double value[2];
        Vec2d grad[2];
        for (int side = 0; side < 2; ++side) {
          Eigen::Matrix2d jacobian;
          const Vec2d pixel = frame.Map((side == 0 ? s : Vec2d(-s)) + t, jtj ? &jacobian : nullptr);
          double gx, gy;
          if (!SampleBicubic(photo, pixel.x(), pixel.y(), &value[side], &gx, &gy)) return std::nullopt;
          if (jtj) grad[side] = jacobian.transpose() * Vec2d(gx, gy);
        }
        double m[kShadingTerms];
        odd_terms(s, m);
        double gs = 0;
        for (int k = 0; k + 2 < unknowns; ++k) gs += x[2 + k] * m[k];
        const double r = value[0] - value[1] - gs * (value[0] + value[1]);
        cost += r * r;
        if (jtj) {
          VecP j = VecP::Zero();
          j.head<2>() = (1 - gs) * grad[0] - (1 + gs) * grad[1];
          for (int k = 0; k + 2 < unknowns; ++k) j[2 + k] = -(value[0] + value[1]) * m[k];
          *jtj += j * j.transpose();
          *jtr += j * r;
        }
      }
    }
    return cost;
  };
  VecP x = VecP::Zero();
  MatP jtj;
  VecP jtr;
  std::optional<double> cost = evaluate(x, &jtj, &jtr);
  if (!cost) return false;
  Eigen::Matrix2d jacobian;
  frame.Map(Vec2d::Zero(), &jacobian);
  double lambda = 1e-4;  // Marquardt's relative damping; the start is within a fraction of a pixel
  bool settled = false;
  for (int iteration = 0; iteration < kSymmetryMaxIterations && !settled; ++iteration) {
    MatP damped = MatP::Identity();
    damped.topLeftCorner(unknowns, unknowns) = jtj.topLeftCorner(unknowns, unknowns);
    VecP rhs = VecP::Zero();
    rhs.head(unknowns) = jtr.head(unknowns);
    // The tiny absolute term keeps the system definite if a window sees no edge at all.
    for (int k = 0; k < unknowns; ++k) damped(k, k) += lambda * jtj(k, k) + 1e-12;
    const VecP step = -damped.ldlt().solve(rhs);
    if (!step.allFinite()) return false;
    MatP jtj_trial;
    VecP jtr_trial;
    const std::optional<double> trial_cost = evaluate(x + step, &jtj_trial, &jtr_trial);
    if (trial_cost && *trial_cost <= *cost) {
      x += step;
      cost = trial_cost;
      jtj = jtj_trial;
      jtr = jtr_trial;
      // Floor: below 1e-9 the damping is far under double rounding of J^T J's diagonal anyway.
      lambda = std::max(lambda * 0.1, 1e-9);
      settled = (jacobian * step.head<2>()).norm() < kSymmetrySettledPx;
    } else {
      lambda *= 10;
      // Damping this strong means no step lowers the cost: the minimum is reached to rounding.
      if (lambda > 1e4) settled = true;
    }
  }
  if (!settled) return false;
  *corner = frame.Map(x.head<2>(), nullptr);
  return std::isfinite(corner->x()) && std::isfinite(corner->y());
}

void RefineBySubPix(const Image& grey, const BoardSpec& board, const DetectOptions& options,
                    std::vector<Vec2d>* corners, std::vector<uint8_t>* valid,
                    const std::vector<int>& half_window) {
  const int n = board.CornerCount();
  cv::Mat img = ToGrey32(grey);
  if (options.presmooth_sigma_px > 0) {
    cv::GaussianBlur(img, img, cv::Size(0, 0), options.presmooth_sigma_px, options.presmooth_sigma_px,
                     cv::BORDER_REPLICATE);
  }
  const cv::TermCriteria criteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4);
  for (int w = options.min_half_window; w <= options.max_half_window; ++w) {
    std::vector<int> ids;
    std::vector<cv::Point2f> pts;
    for (int k = 0; k < n; ++k) {
      const Vec2d& p = (*corners)[k];
      // cornerSubPix needs its window (and one pixel for gradients) inside the image.
      if (half_window[k] != w) continue;
      if (p.x() < w + 1 || p.y() < w + 1 || p.x() > grey.width - w - 2 || p.y() > grey.height - w - 2) {
        (*valid)[k] = 0;
        continue;
      }
      ids.push_back(k);
      pts.emplace_back(float(p.x()), float(p.y()));
    }
    if (pts.empty()) continue;
    try {
      cv::cornerSubPix(img, pts, cv::Size(w, w), cv::Size(-1, -1), criteria);
    } catch (const cv::Exception&) {
      for (int k : ids) (*valid)[k] = 0;
      continue;
    }
    for (size_t m = 0; m < ids.size(); ++m) (*corners)[ids[m]] = Vec2d(pts[m].x, pts[m].y);
  }
}

BoardDetection MakeDetection(const Image& grey, const std::vector<BoardSpec>& boards, Identified id,
                             const DetectOptions& options) {
  BoardDetection det;
  det.board = id.board;
  det.corners = std::move(id.corners);
  det.contrast = id.contrast;
  det.alternatives = std::move(id.alternatives);
  RefineCorners(grey, boards[id.board], options, &det.corners, &det.valid, &det.half_window,
                &det.refine_shift_rms);
  return det;
}

}  // namespace

Status DetectOptions::Validate() const {
  if (!(window_fraction > 0 && window_fraction < 0.5)) {
    return InvalidArgumentError("window_fraction must be in (0, 0.5) (got ", window_fraction, ")");
  }
  if (min_half_window < 1) return InvalidArgumentError("min_half_window must be >= 1");
  if (max_half_window < min_half_window) {
    return InvalidArgumentError("max_half_window must be >= min_half_window");
  }
  if (!(max_refine_shift_px > 0)) return InvalidArgumentError("max_refine_shift_px must be positive");
  if (!(symmetry_radius > 0 && symmetry_radius < 1)) {
    return InvalidArgumentError("symmetry_radius must be in (0, 1) squares (got ", symmetry_radius, ")");
  }
  if (!(symmetry_step_px >= 0.25 && symmetry_step_px <= 2)) {
    return InvalidArgumentError("symmetry_step_px must be in [0.25, 2] (got ", symmetry_step_px, ")");
  }
  if (!(min_contrast > 0 && min_contrast < 1)) return InvalidArgumentError("min_contrast must be in (0, 1)");
  // Beyond 3 px the blur spreads a corner over its neighbours' squares at typical square sizes.
  if (!(presmooth_sigma_px >= 0 && presmooth_sigma_px <= 3)) {
    return InvalidArgumentError("presmooth_sigma_px must be in [0, 3] (got ", presmooth_sigma_px, ")");
  }
  return OkStatus();
}

std::optional<CornerRefiner> ParseCornerRefiner(const std::string& name) {
  if (name == "symmetry") return CornerRefiner::kSymmetry;
  if (name == "subpix") return CornerRefiner::kCornerSubPix;
  return std::nullopt;
}

const char* CornerRefinerName(CornerRefiner refiner) {
  return refiner == CornerRefiner::kSymmetry ? "symmetry" : "subpix";
}

int BoardDetection::ValidCount() const { return int(std::count(valid.begin(), valid.end(), 1)); }

StatusOr<Image> LoadGrey(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  StatusOr<Image> read = ext == ".png" ? ReadPng(path) : ReadImageRgb(path);
  if (!read.ok()) return read.status();
  const Image& in = *read;
  if (in.channels == 1) return read;
  const int colour = in.channels >= 3 ? 3 : 1;  // grey+alpha: the grey; RGB(A): the mean of RGB
  Image out(in.width, in.height, 1);
  for (int y = 0; y < in.height; ++y) {
    for (int x = 0; x < in.width; ++x) {
      double s = 0;
      for (int c = 0; c < colour; ++c) s += in.at(x, y, c);
      out.at(x, y) = float(s / colour);
    }
  }
  return out;
}

std::vector<Vec2d> BoardOutline(const BoardSpec& board, double margin_fraction) {
  const double mu = margin_fraction * board.margin_u_m / board.square_m;
  const double mv = margin_fraction * board.margin_v_m / board.square_m;
  const double l = -1 - mu, r = board.squares_x - 1 + mu, t = -1 - mv, b = board.squares_y - 1 + mv;
  return {Vec2d(l, t), Vec2d(r, t), Vec2d(r, b), Vec2d(l, b)};
}

void RefineCorners(const Image& grey, const BoardSpec& board, const DetectOptions& options,
                   std::vector<Vec2d>* corners, std::vector<uint8_t>* valid,
                   std::vector<int>* half_window, double* shift_rms) {
  const int n = board.CornerCount();
  REFLCAP_CHECK(int(corners->size()) == n);
  valid->assign(n, 1);
  half_window->assign(n, options.min_half_window);
  const std::vector<Vec2d> start = *corners;
  if (options.refiner == CornerRefiner::kSymmetry) {
    const Plane photo = MakePlane(grey, options.photos_srgb, options.presmooth_sigma_px);
    // Two passes: the second fits each corner's homography through its refined neighbours, so a
    // detector's error in the neighbours (tenths of a pixel on oblique boards) does not shape the
    // window; a corner the first pass dropped keeps its start as a neighbour.
    for (int pass = 0; pass < kSymmetryPasses; ++pass) {
      const std::vector<Vec2d> frames_from = *corners;
      for (int j = 0; j < board.corners_y; ++j) {
        for (int i = 0; i < board.corners_x; ++i) {
          const int k = j * board.corners_x + i;
          CornerFrame frame;
          Vec2d refined;
          if (!FitCornerFrame(board, frames_from, i, j, &frame) || !RefineBySymmetry(photo, frame, options, &refined)) {
            (*valid)[k] = 0;
            (*corners)[k] = start[k];
            continue;
          }
          (*valid)[k] = 1;
          (*corners)[k] = refined;
          (*half_window)[k] = int(std::lround(options.symmetry_radius * frame.square_px));
        }
      }
    }
  } else {
    // Half-window per corner from its nearest 4-neighbour.
    for (int j = 0; j < board.corners_y; ++j) {
      for (int i = 0; i < board.corners_x; ++i) {
        const int k = j * board.corners_x + i;
        double d = 1e30;
        for (const auto& [di, dj] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
          const int ii = i + di, jj = j + dj;
          if (ii < 0 || jj < 0 || ii >= board.corners_x || jj >= board.corners_y) continue;
          d = std::min(d, ((*corners)[jj * board.corners_x + ii] - (*corners)[k]).norm());
        }
        (*half_window)[k] = std::clamp(int(std::floor(options.window_fraction * d)),
                                       options.min_half_window, options.max_half_window);
      }
    }
    RefineBySubPix(grey, board, options, corners, valid, *half_window);
  }
  double sum = 0;
  int count = 0;
  for (int k = 0; k < n; ++k) {
    const double shift = ((*corners)[k] - start[k]).norm();
    if (!(*valid)[k] || !std::isfinite(shift) || shift > options.max_refine_shift_px) {
      (*valid)[k] = 0;
      (*corners)[k] = start[k];
      continue;
    }
    sum += shift * shift;
    ++count;
  }
  *shift_rms = count > 0 ? std::sqrt(sum / count) : 0.0;
}

std::vector<BoardDetection> FindBoards(const Image& grey, const std::vector<BoardSpec>& boards,
                                       int max_found, const DetectOptions& options,
                                       std::vector<std::string>* refused) {
  std::vector<BoardDetection> found;
  if (boards.empty()) return found;
  cv::Mat work = ToGrey8(grey);
  const uint8_t fill = uint8_t(cv::mean(work)[0]);
  std::vector<int> remaining(boards.size());
  std::iota(remaining.begin(), remaining.end(), 0);
  // Larger grids first: a smaller board's pattern can match part of a larger one.
  std::sort(remaining.begin(), remaining.end(),
            [&](int a, int b) { return boards[a].CornerCount() > boards[b].CornerCount(); });
  // The probe: the largest grid every board contains (in some orientation). With CALIB_CB_LARGER
  // one search with it finds whichever board is easiest and grows to its full size.
  int probe_small = 1 << 20, probe_large = 1 << 20;
  for (const BoardSpec& b : boards) {
    probe_small = std::min(probe_small, std::min(b.corners_x, b.corners_y));
    probe_large = std::min(probe_large, std::max(b.corners_x, b.corners_y));
  }
  // The SB detector needs at least 3x3 corners to start a grid.
  probe_small = std::max(probe_small, 3);
  probe_large = std::max(probe_large, 3);
  const bool probe_differs = boards.size() > 1;
  std::vector<int> searches(boards.size() + 1, 0);  // per board; the last entry: the probe
  const int passes = options.exhaustive_retry ? 2 : 1;
  auto done = [&] { return remaining.empty() || (max_found > 0 && int(found.size()) >= max_found); };
  for (int pass = 0; pass < passes && !done(); ++pass) {
    if (pass == 1 && !found.empty()) break;
    const int flags = cv::CALIB_CB_LARGER |
                      (pass == 0 ? 0 : cv::CALIB_CB_EXHAUSTIVE | cv::CALIB_CB_ACCURACY);
    std::fill(searches.begin(), searches.end(), 0);
    bool progress = true;
    while (progress && !done()) {
      progress = false;
      // Candidates in order: the probe, then each remaining board's own pattern.
      std::vector<std::pair<int, int>> patterns;  // grid sizes (cx, cy) to search for
      std::vector<int> slots;  // per pattern: its entry in `searches`
      if (probe_differs) {
        patterns.emplace_back(probe_small, probe_large);
        slots.push_back(int(boards.size()));
      }
      for (int index : remaining) {
        patterns.emplace_back(boards[index].corners_x, boards[index].corners_y);
        slots.push_back(index);
      }
      for (size_t c = 0; c < patterns.size(); ++c) {
        if (searches[slots[c]] >= kMaxSearchesPerBoard) continue;
        ++searches[slots[c]];
        auto grid = RunSb(work, patterns[c].first, patterns[c].second, flags);
        if (!grid) continue;
        FillPolygon(&work, RawGridCover(*grid), fill);
        std::string why;
        auto id = IdentifyWithSubgrids(grey, *grid, boards, remaining, options, &why);
        if (!id) {
          if (refused) refused->push_back(why);
        } else {
          const int board = id->board;
          found.push_back(MakeDetection(grey, boards, std::move(*id), options));
          remaining.erase(std::find(remaining.begin(), remaining.end(), board));
        }
        progress = true;
        break;
      }
    }
  }
  return found;
}

std::optional<BoardDetection> FindBoardInRegion(const Image& grey,
                                                const std::vector<BoardSpec>& boards, int board,
                                                const std::vector<Vec2d>& region,
                                                const std::vector<Vec2d>* predicted,
                                                const DetectOptions& options, std::string* why) {
  std::string dummy;
  if (why == nullptr) why = &dummy;
  const BoardSpec& b = boards[board];
  double x0 = 1e30, y0 = 1e30, x1 = -1e30, y1 = -1e30;
  for (const Vec2d& p : region) {
    x0 = std::min(x0, p.x());
    y0 = std::min(y0, p.y());
    x1 = std::max(x1, p.x());
    y1 = std::max(y1, p.y());
  }
  const int ix0 = std::max(0, int(std::floor(x0))), iy0 = std::max(0, int(std::floor(y0)));
  const int ix1 = std::min(grey.width - 1, int(std::ceil(x1))), iy1 = std::min(grey.height - 1, int(std::ceil(y1)));
  if (ix1 - ix0 < 8 || iy1 - iy0 < 8) {
    *why = "the predicted region is outside the photo or too small";
    return std::nullopt;
  }
  const cv::Mat full = ToGrey8(grey);
  const cv::Rect roi(ix0, iy0, ix1 - ix0 + 1, iy1 - iy0 + 1);
  cv::Mat mask = cv::Mat::zeros(roi.size(), CV_8U);
  std::vector<cv::Point> poly;
  for (const Vec2d& p : region) poly.emplace_back(int(std::lround(p.x() - ix0)), int(std::lround(p.y() - iy0)));
  cv::fillConvexPoly(mask, poly, cv::Scalar(255));
  cv::Mat crop = full(roi).clone();
  const uint8_t fill = uint8_t(cv::mean(crop, mask)[0]);
  crop.setTo(cv::Scalar(fill), ~mask);
  const int passes = options.exhaustive_retry ? 2 : 1;
  *why = "no grid found in the predicted region";
  for (int pass = 0; pass < passes; ++pass) {
    const int flags = cv::CALIB_CB_LARGER |
                      (pass == 0 ? 0 : cv::CALIB_CB_EXHAUSTIVE | cv::CALIB_CB_ACCURACY);
    auto grid = RunSb(crop, b.corners_x, b.corners_y, flags);
    if (!grid) continue;
    for (Vec2d& p : grid->corners) p += Vec2d(ix0, iy0);
    auto id = IdentifyWithSubgrids(grey, *grid, boards, {board}, options, why);
    if (!id) continue;
    if (predicted != nullptr) {
      // Of the numberings that show the right colours, the prediction picks one.
      const double tolerance = kPredictionTolerance * MedianSpacing(b, *predicted);
      auto worst_of = [&](const std::vector<Vec2d>& c) {
        double worst = 0;
        for (int k = 0; k < b.CornerCount(); ++k) worst = std::max(worst, (c[k] - (*predicted)[k]).norm());
        return worst;
      };
      double best = worst_of(id->corners);
      std::vector<Vec2d> best_corners = id->corners;
      for (const std::vector<int>& alt : id->alternatives) {
        std::vector<Vec2d> c(alt.size());
        for (size_t k = 0; k < alt.size(); ++k) c[k] = id->corners[alt[k]];
        const double w = worst_of(c);
        if (w < best) {
          best = w;
          best_corners = std::move(c);
        }
      }
      if (best > tolerance) {
        *why = StrCat("found ", best, " px from where the pose predicts it (tolerance ", tolerance, " px)");
        continue;
      }
      id->corners = std::move(best_corners);
      id->alternatives.clear();
    }
    return MakeDetection(grey, boards, std::move(*id), options);
  }
  return std::nullopt;
}

}  // namespace reflcap::calib
