#pragma once
// Small fixed-size linear algebra types used across reflcap (Eigen, column vectors).
#include <Eigen/Core>
#include <Eigen/Geometry>

namespace reflcap {

using Vec2d = Eigen::Vector2d;
using Vec3d = Eigen::Vector3d;
using Vec4d = Eigen::Vector4d;
using Vec2f = Eigen::Vector2f;
using Vec3f = Eigen::Vector3f;
using Mat3d = Eigen::Matrix3d;
using Mat4d = Eigen::Matrix4d;
using Vec3i = Eigen::Vector3i;

constexpr double kPi = 3.14159265358979323846;
constexpr double kInvPi = 1.0 / kPi;

inline double DegToRad(double deg) { return deg * (kPi / 180.0); }
inline double RadToDeg(double rad) { return rad * (180.0 / kPi); }

}  // namespace reflcap
