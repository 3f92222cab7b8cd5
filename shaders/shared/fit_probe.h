// Buffer layout of shaders/fit/fit_probe.comp, which evaluates the fitting model's GLSL twins
// element by element (tests/engine/fit/fit_vulkan_test.cc compares them with engine/fit/model.h).
#ifndef REFLCAP_SHADERS_SHARED_FIT_PROBE_H_
#define REFLCAP_SHADERS_SHARED_FIT_PROBE_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

struct FitProbeInput {
  float exp_arg;  // FitExp's argument, in [kFitMinLobeLogArg, kFitMaxLobeLogArg]
  float log_arg;  // FitLog's argument, > kTiny
  float base;     // FitLobeValueAndSlopes' base and exponent
  float n;
};
REFLCAP_STD430_SIZE(FitProbeInput, 16);

struct FitProbeOutput {
  float exp_value;
  float log_value;
  float lobe_value;
  float dvalue_dbase;
  float dvalue_dn;
  float reserved0;
  float reserved1;
  float reserved2;
};
REFLCAP_STD430_SIZE(FitProbeOutput, 32);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_FIT_PROBE_H_
