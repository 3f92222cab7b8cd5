// Constants of engine/brdf/lafortune.h for shaders/common/lafortune.glsl (float where the C++
// float twin compares in float). tests/engine/gpu/shared_headers_test.cc static_asserts that each
// equals its engine twin.
#ifndef REFLCAP_SHADERS_SHARED_LAFORTUNE_CONSTANTS_H_
#define REFLCAP_SHADERS_SHARED_LAFORTUNE_CONSTANTS_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

// brdf::kMaxLobes, brdf::kChannels, brdf::kMaxParamsPerChannel (= 1 + 4 kMaxLobes): one channel's
// parameters are [rho_d, Cx_0, Cy_0, Cz_0, n_0, Cx_1, ...].
REFLCAP_CONST(int, kMaxLobes, 3);
REFLCAP_CONST(int, kChannels, 3);
REFLCAP_CONST(int, kMaxParamsPerChannel, 13);
// brdf::kMinExponent, brdf::kMaxExponent: the valid range of a lobe exponent n.
REFLCAP_CONST(float, kMinExponent, 1.0f);
REFLCAP_CONST(float, kMaxExponent, 1e4f);
// brdf::kMaxLobeValue: a lobe value b^n above this is returned as this constant (gradient 0).
REFLCAP_CONST(float, kMaxLobeValue, 1e30f);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_LAFORTUNE_CONSTANTS_H_
