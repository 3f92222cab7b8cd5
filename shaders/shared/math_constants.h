// Constants of engine/math (types.h, safe_math.h) for shaders/common/safe_math.glsl, as the
// float values the C++ float twins compare against (static_cast<float> of the double constants).
// tests/engine/gpu/shared_headers_test.cc static_asserts that each equals its engine twin.
#ifndef REFLCAP_SHADERS_SHARED_MATH_CONSTANTS_H_
#define REFLCAP_SHADERS_SHARED_MATH_CONSTANTS_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

// reflcap::kPi and reflcap::kInvPi rounded to float.
REFLCAP_CONST(float, kPi, 3.14159265358979323846f);
REFLCAP_CONST(float, kInvPi, 0.318309886183790671538f);
// reflcap::kTiny: smallest argument SafeLog takes (see engine/math/safe_math.h for why 1e-30).
REFLCAP_CONST(float, kTiny, 1e-30f);
// reflcap::kPowBaseMin: SafePow(b, n) is exactly 0 for b <= kPowBaseMin (= kTiny).
REFLCAP_CONST(float, kPowBaseMin, 1e-30f);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_MATH_CONSTANTS_H_
