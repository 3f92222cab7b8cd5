#include "tests/calib/synthetic_session.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <nlohmann/json.hpp>

#include "engine/camera/camera.h"
#include "engine/core/check.h"
#include "engine/image/png_io.h"
#include "tests/support/test_support.h"

namespace reflcap::calib::testing {
namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;

namespace {

constexpr double kBoxX = 0.10, kBoxY = 0.08, kBoxZ = 0.12;
constexpr double kBlack = 0.05, kWhite = 0.80, kBackground = 0.25, kBottom = 0.5;
constexpr int kSuper = 3;  // 3x3 sub-samples per pixel: a box filter, symmetric about the pixel centre
// Optics: a Gaussian blur of 1 pixel (a box-sharp edge biases sub-pixel corners towards pixel
// centres; real lenses and the shared renders' 1.5-pixel filter are never box-sharp).
constexpr double kBlurSigmaPx = 1.0;

BoardSpec Face(const std::string& name, const Vec3d& normal, const Vec3d& u, const Vec3d& v, int sx, int sy,
               double square, double extent_u, double extent_v) {
  BoardSpec b;
  b.name = name;
  b.squares_x = sx;
  b.squares_y = sy;
  b.corners_x = sx - 1;
  b.corners_y = sy - 1;
  b.square_m = square;
  b.margin_u_m = 0.5 * (extent_u - sx * square);
  b.margin_v_m = 0.5 * (extent_v - sy * square);
  b.u_axis = u;
  b.v_axis = v;
  b.normal = normal;
  const Vec3d centre(normal.x() * kBoxX / 2, normal.y() * kBoxY / 2, normal.z() > 0 ? kBoxZ : kBoxZ / 2);
  b.origin = centre - (0.5 * sx - 1) * square * u - (0.5 * sy - 1) * square * v;
  return b;
}

Mat3d MinimalRotation(const Vec3d& from, const Vec3d& to) {
  return Eigen::Quaterniond::FromTwoVectors(from, to).toRotationMatrix();
}

Mat3d Rz(double deg) { return AxisAngleRotation(Vec3d::UnitZ(), DegToRad(deg)); }

Camera CameraOf(const SyntheticRig& rig, int c) {
  return MakeCamera("c", rig.width, rig.height, rig.intrinsics[c], Rigid3());
}

// Colour of a board point at board coordinates (i, j) (squares from inner corner (0,0)); false
// outside the board's margin.
bool BoardColour(const BoardSpec& b, double i, double j, double* value) {
  const double mu = b.margin_u_m / b.square_m, mv = b.margin_v_m / b.square_m;
  if (i < -1 - mu || j < -1 - mv || i > b.squares_x - 1 + mu || j > b.squares_y - 1 + mv) return false;
  const int a = int(std::floor(i + 1)), c = int(std::floor(j + 1));
  if (a >= 0 && c >= 0 && a < b.squares_x && c < b.squares_y) {
    *value = (a + c) % 2 == 0 ? kBlack : kWhite;
  } else {
    *value = kWhite;
  }
  return true;
}

// Renders by shooting kSuper^2 rays per pixel; `shade` returns the radiance of a camera ray.
template <typename Shade>
Image Render(const SyntheticRig& rig, int camera, double noise, uint64_t seed, Shade shade) {
  const Camera cam = CameraOf(rig, camera);
  Image img(rig.width, rig.height, 1);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0, 1);
  for (int y = 0; y < rig.height; ++y) {
    for (int x = 0; x < rig.width; ++x) {
      double sum = 0;
      for (int sy = 0; sy < kSuper; ++sy) {
        for (int sx = 0; sx < kSuper; ++sx) {
          const Vec2d pixel(x - 0.5 + (sx + 0.5) / kSuper, y - 0.5 + (sy + 0.5) / kSuper);
          Vec3d origin, dir;
          cam.PixelRay(pixel, &origin, &dir);
          sum += shade(dir);
        }
      }
      img.at(x, y) = float(sum / (kSuper * kSuper));
    }
  }
  // Optics (kBlurSigmaPx), separable.
  Image blurred = img;
  const int radius = int(std::ceil(3 * kBlurSigmaPx));
  std::vector<double> w(2 * radius + 1);
  double wsum = 0;
  for (int i = -radius; i <= radius; ++i) wsum += w[i + radius] = std::exp(-0.5 * i * i / (kBlurSigmaPx * kBlurSigmaPx));
  for (double& v : w) v /= wsum;
  for (int pass = 0; pass < 2; ++pass) {
    const Image src = pass == 0 ? img : blurred;
    for (int y = 0; y < rig.height; ++y) {
      for (int x = 0; x < rig.width; ++x) {
        double sum = 0;
        for (int i = -radius; i <= radius; ++i) {
          const int xx = std::clamp(pass == 0 ? x + i : x, 0, rig.width - 1);
          const int yy = std::clamp(pass == 0 ? y : y + i, 0, rig.height - 1);
          sum += w[i + radius] * src.at(xx, yy);
        }
        blurred.at(x, y) = float(sum);
      }
    }
  }
  for (float& v : blurred.data) v += float(noise * gauss(rng));
  return blurred;
}

}  // namespace

Rigid3 SyntheticRig::CamFromBox(int camera, int angle) const {
  const Turntable t{axis, point};
  return cam_from_world[camera] * t.WorldFromObject(angles_deg[angle] + angle_offsets_deg[angle]) * world_from_box0;
}

std::vector<BoardSpec> CuboidFaces() {
  std::vector<BoardSpec> f;
  f.push_back(Face("+x", Vec3d::UnitX(), Vec3d::UnitY(), -Vec3d::UnitZ(), 5, 8, 0.012, kBoxY, kBoxZ));
  f.push_back(Face("-x", -Vec3d::UnitX(), -Vec3d::UnitY(), -Vec3d::UnitZ(), 6, 9, 0.010, kBoxY, kBoxZ));
  f.push_back(Face("+y", Vec3d::UnitY(), -Vec3d::UnitX(), -Vec3d::UnitZ(), 6, 7, 0.013, kBoxX, kBoxZ));
  f.push_back(Face("-y", -Vec3d::UnitY(), Vec3d::UnitX(), -Vec3d::UnitZ(), 7, 8, 0.011, kBoxX, kBoxZ));
  f.push_back(Face("+z", Vec3d::UnitZ(), Vec3d::UnitX(), -Vec3d::UnitY(), 8, 6, 0.009, kBoxX, kBoxY));
  for (size_t i = 0; i < f.size(); ++i) f[i].field = "cuboid.faces[" + std::to_string(i) + "]";
  return f;
}

BoardSpec PlanarBoard() {
  BoardSpec b;
  b.name = "intrinsics_board";
  b.field = "intrinsics_board";
  b.squares_x = 9;
  b.squares_y = 6;
  b.corners_x = 8;
  b.corners_y = 5;
  b.square_m = 0.012;
  b.margin_u_m = b.margin_v_m = 0.010;
  return b;
}

SyntheticRig MakeRig(int cameras, int angles) {
  SyntheticRig rig;
  rig.faces = CuboidFaces();
  rig.board = PlanarBoard();
  const Vec3d target(0, 0, 0.06);
  for (int c = 0; c < cameras; ++c) {
    const double el = DegToRad(cameras == 1 ? 35.0 : 15.0 + 50.0 * c / (cameras - 1));
    const double az = DegToRad(-8.0 * c);
    // 0.68 m: the cuboid fills most of a 400-pixel frame and its squares span 15-20 pixels, as
    // in the shared session's 640-pixel photos.
    const Vec3d eye = target + 0.68 * Vec3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    rig.cam_from_world.push_back(CamFromWorldLookAt(eye, target));
    IntrinsicParams p{};
    p[kFx] = 1100 + 3 * c;
    p[kFy] = p[kFx];
    p[kCx] = 201.3 - 1.1 * c;
    p[kCy] = 198.7 + 0.7 * c;
    p[kK1] = -0.10 + 0.01 * c;
    p[kK2] = 0.05;
    p[kP1] = 3e-4;
    p[kP2] = -2e-4;
    rig.intrinsics.push_back(p);
  }
  const double tilt = DegToRad(1.0), tilt_az = DegToRad(35.0);
  rig.axis = Vec3d(std::sin(tilt) * std::cos(tilt_az), std::sin(tilt) * std::sin(tilt_az), std::cos(tilt));
  rig.point = Vec3d(0.003, -0.0025, 0.0);
  const Mat3d plate = MinimalRotation(Vec3d::UnitZ(), rig.axis);
  rig.world_from_box0 = {plate * Rz(25), rig.point + plate * Vec3d(0.03, 0.012, 0)};
  for (int a = 0; a < angles; ++a) rig.angles_deg.push_back(360.0 * a / angles);
  rig.angle_offsets_deg.assign(angles, 0.0);
  return rig;
}

Image RenderCuboidPhoto(const SyntheticRig& rig, int camera, int angle, double noise, uint64_t seed) {
  const Rigid3 box_from_cam = rig.CamFromBox(camera, angle).Inverse();
  const Vec3d lo(-kBoxX / 2, -kBoxY / 2, 0), hi(kBoxX / 2, kBoxY / 2, kBoxZ);
  return Render(rig, camera, noise, seed, [&](const Vec3d& dir_cam) {
    const Vec3d o = box_from_cam.translation, d = box_from_cam.rotation * dir_cam;
    double t_near = -1e30, t_far = 1e30;
    int axis = -1;
    double sign = 0;
    for (int k = 0; k < 3; ++k) {
      if (std::abs(d[k]) < 1e-15) {
        if (o[k] < lo[k] || o[k] > hi[k]) return kBackground;
        continue;
      }
      double t0 = (lo[k] - o[k]) / d[k], t1 = (hi[k] - o[k]) / d[k];
      double s = -1;
      if (t0 > t1) {
        std::swap(t0, t1);
        s = 1;
      }
      if (t0 > t_near) {
        t_near = t0;
        axis = k;
        sign = s;
      }
      t_far = std::min(t_far, t1);
    }
    if (t_near > t_far || t_far < 0 || axis < 0) return kBackground;
    const Vec3d hit = o + t_near * d;
    Vec3d normal = Vec3d::Zero();
    normal[axis] = sign;
    for (const BoardSpec& f : rig.faces) {
      if ((f.normal - normal).norm() > 1e-9) continue;
      const Vec3d q = hit - f.origin;
      double value = kWhite;
      BoardColour(f, q.dot(f.u_axis) / f.square_m, q.dot(f.v_axis) / f.square_m, &value);
      // Faces differ a little in brightness, as under real light.
      return value * (0.85 + 0.05 * axis);
    }
    return kBottom;
  });
}

Image RenderBoardPhoto(const SyntheticRig& rig, int camera, const Rigid3& cam_from_board, double noise,
                       uint64_t seed) {
  const Rigid3 board_from_cam = cam_from_board.Inverse();
  return Render(rig, camera, noise, seed, [&](const Vec3d& dir_cam) {
    const Vec3d o = board_from_cam.translation, d = board_from_cam.rotation * dir_cam;
    if (std::abs(d.z()) < 1e-15) return kBackground;
    const double t = -o.z() / d.z();
    if (t <= 0) return kBackground;
    const Vec3d hit = o + t * d;
    double value = kBackground;
    BoardColour(rig.board, hit.x() / rig.board.square_m, hit.y() / rig.board.square_m, &value);
    return value;
  });
}

namespace {

Json Matrix(const Eigen::MatrixXd& m) {
  Json rows = Json::array();
  for (int r = 0; r < m.rows(); ++r) {
    Json row = Json::array();
    for (int c = 0; c < m.cols(); ++c) row.push_back(m(r, c));
    rows.push_back(row);
  }
  return rows;
}

Json Vec(const Vec3d& v) { return Json::array({v.x(), v.y(), v.z()}); }

std::string CameraId(int c) { return "cam" + std::to_string(c); }

std::string PhotoName(int c, double angle) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "images/cam%d_%03d.png", c, int(std::lround(angle)));
  return buf;
}

// Board poses that keep the whole board (with its margin) in the frame.
std::vector<Rigid3> BoardPoses(const SyntheticRig& rig, int camera, int count, std::mt19937_64* rng) {
  std::uniform_real_distribution<double> uni(-1, 1);
  const BoardSpec& b = rig.board;
  const Vec3d centre_board(0.5 * (b.squares_x - 2) * b.square_m, 0.5 * (b.squares_y - 2) * b.square_m, 0);
  std::vector<Rigid3> poses;
  while (int(poses.size()) < count) {
    const double dist = 0.5 + 0.1 * uni(*rng);
    const Vec3d centre_cam((0.25 * uni(*rng)) * dist * rig.width / rig.intrinsics[camera][kFx],
                           (0.25 * uni(*rng)) * dist * rig.height / rig.intrinsics[camera][kFy], dist);
    const Mat3d r = AxisAngleRotation(Vec3d::UnitX(), DegToRad(35 * uni(*rng))) *
                    AxisAngleRotation(Vec3d::UnitY(), DegToRad(35 * uni(*rng))) * Rz(20 * uni(*rng));
    const Rigid3 pose{r, centre_cam - r * centre_board};
    bool inside = true;
    for (const Vec2d& q : {Vec2d(-2, -2), Vec2d(b.squares_x, -2), Vec2d(-2, b.squares_y), Vec2d(b.squares_x, b.squares_y)}) {
      const Vec3d p = pose * Vec3d(q.x() * b.square_m, q.y() * b.square_m, 0);
      double pixel[2];
      const double pc[3] = {p.x(), p.y(), p.z()};
      ProjectToPixel(rig.intrinsics[camera].data(), pc, pixel);
      inside &= p.z() > 0 && pixel[0] > 4 && pixel[1] > 4 && pixel[0] < rig.width - 5 && pixel[1] < rig.height - 5;
    }
    if (inside) poses.push_back(pose);
  }
  return poses;
}

}  // namespace

fs::path WriteSession(SyntheticRig* rig, const fs::path& dir, const SessionOptions& options) {
  const int cameras = int(rig->cam_from_world.size());
  std::mt19937_64 rng(12345);
  if (options.board_photos_per_camera > 0 && rig->cam_from_board.empty()) {
    for (int c = 0; c < cameras; ++c) rig->cam_from_board.push_back(BoardPoses(*rig, c, options.board_photos_per_camera, &rng));
  }
  Json root;
  root["format"] = "calib/1";
  Json cams = Json::array();
  for (int c = 0; c < cameras; ++c) {
    Json j = {{"id", CameraId(c)}, {"width", rig->width}, {"height", rig->height}};
    if (options.with_intrinsics) {
      j["K"] = Matrix(KFromParams(rig->intrinsics[c]));
      const auto d = DistFromParams(rig->intrinsics[c]);
      j["dist"] = Json(std::vector<double>(d.begin(), d.end()));
    }
    cams.push_back(j);
  }
  root["cameras"] = cams;
  root["turntable"] = {{"angles_deg", Json(rig->angles_deg)}};
  Json images = Json::array(), truth_boxes = Json::object();
  for (int c = 0; c < cameras; ++c) {
    for (size_t a = 0; a < rig->angles_deg.size(); ++a) {
      const std::string name = PhotoName(c, rig->angles_deg[a]);
      images.push_back({{"file", name}, {"camera", CameraId(c)}, {"turntable_deg", rig->angles_deg[a]}, {"target", "cuboid"}});
      truth_boxes[name] = Matrix(rig->CamFromBox(c, int(a)).ToMatrix());
      if (!options.render_photos) continue;
      const Image photo = RenderCuboidPhoto(*rig, c, int(a), options.noise, 1000 * c + a);
      fs::create_directories((dir / name).parent_path());
      REFLCAP_CHECK(WritePng(dir / name, photo).ok());
    }
  }
  root["images"] = images;
  Json board_images = Json::array(), truth_boards = Json::object();
  for (int c = 0; c < int(rig->cam_from_board.size()); ++c) {
    for (size_t k = 0; k < rig->cam_from_board[c].size(); ++k) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "intrinsics/cam%d_%02d.png", c, int(k));
      board_images.push_back({{"file", buf}, {"camera", CameraId(c)}, {"target", "intrinsics_board"}});
      truth_boards[buf] = Matrix(rig->cam_from_board[c][k].ToMatrix());
      if (!options.render_photos) continue;
      const Image photo = RenderBoardPhoto(*rig, c, rig->cam_from_board[c][k], options.noise, 5000 + 100 * c + k);
      fs::create_directories((dir / buf).parent_path());
      REFLCAP_CHECK(WritePng(dir / buf, photo).ok());
    }
  }
  if (!board_images.empty()) root["intrinsics_images"] = board_images;
  Json faces = Json::array();
  for (const BoardSpec& f : rig->faces) {
    faces.push_back({{"name", f.name},
                     {"normal", Vec(f.normal)},
                     {"u_axis", Vec(f.u_axis)},
                     {"v_axis", Vec(f.v_axis)},
                     {"squares", {f.squares_x, f.squares_y}},
                     {"inner_corners", {f.corners_x, f.corners_y}},
                     {"square_m", f.square_m},
                     {"board_margin_m", {f.margin_u_m, f.margin_v_m}},
                     {"first_inner_corner_box", Vec(f.origin)}});
  }
  root["cuboid"] = {{"size_m", {kBoxX, kBoxY, kBoxZ}}, {"faces", faces}};
  const BoardSpec& b = rig->board;
  root["intrinsics_board"] = {{"squares", {b.squares_x, b.squares_y}},
                              {"inner_corners", {b.corners_x, b.corners_y}},
                              {"square_m", b.square_m},
                              {"margin_m", b.margin_u_m}};
  if (options.with_truth) {
    Json gt;
    Json cfw = Json::object(), intr = Json::object();
    for (int c = 0; c < cameras; ++c) {
      cfw[CameraId(c)] = Matrix(rig->cam_from_world[c].ToMatrix());
      const auto d = DistFromParams(rig->intrinsics[c]);
      intr[CameraId(c)] = {{"K", Matrix(KFromParams(rig->intrinsics[c]))}, {"dist", Json(std::vector<double>(d.begin(), d.end()))}};
    }
    gt["cam_from_world"] = cfw;
    gt["turntable"] = {{"axis", Vec(rig->axis)}, {"point", Vec(rig->point)}};
    gt["world_from_box_at_0"] = Matrix(rig->world_from_box0.ToMatrix());
    gt["cam_from_box"] = truth_boxes;
    gt["intrinsics"] = intr;
    if (!truth_boards.empty()) gt["intrinsics_cam_from_board"] = truth_boards;
    root["ground_truth"] = gt;
  }
  const fs::path path = dir / "calib.json";
  reflcap::testing::WriteText(path, root.dump(2));
  return path;
}

std::vector<std::vector<FaceCorners>> ProjectedCorners(const SyntheticRig& rig, const CalibFile& file,
                                                       double noise_px, double min_cos, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0, 1);
  std::vector<std::vector<FaceCorners>> out(file.images.size());
  for (size_t i = 0; i < file.images.size(); ++i) {
    const CuboidImage& image = file.images[i];
    const Rigid3 pose = rig.CamFromBox(image.camera, image.angle);
    for (size_t f = 0; f < rig.faces.size(); ++f) {
      const BoardSpec& face = rig.faces[f];
      const Vec3d centre = pose * face.Point(0.5 * (face.corners_x - 1), 0.5 * (face.corners_y - 1));
      if (-(pose.rotation * face.normal).dot(centre.normalized()) < min_cos) continue;
      FaceCorners fc;
      fc.face = int(f);
      for (int k = 0; k < face.CornerCount(); ++k) {
        const Vec3d p = pose * face.Corner(k);
        double pixel[2];
        const double pc[3] = {p.x(), p.y(), p.z()};
        ProjectToPixel(rig.intrinsics[image.camera].data(), pc, pixel);
        fc.corners.emplace_back(pixel[0] + noise_px * gauss(rng), pixel[1] + noise_px * gauss(rng));
      }
      fc.valid.assign(fc.corners.size(), 1);
      out[i].push_back(std::move(fc));
    }
  }
  return out;
}

}  // namespace reflcap::calib::testing
