#version 460
// Evaluates the fitting model's GLSL twins (fit/fit_model.glsl) element by element, for
// tests/engine/fit/fit_vulkan_test.cc to compare with engine/fit/model.h in float: FitExp and
// FitLog against expf/logf, FitLobeValueAndSlopes against LobeValueAndSlopes<float>.
//
// Bindings (set 0): 0 = FitProbeInput[] (read), 1 = FitProbeOutput[] (write), one per element.
// Push constants:   uint count (elements).
// Specialization:   constant_id 0 = local_size_x (default 64).
// C++ twin:         engine/fit/model.h (LobeValueAndSlopes), libm's expf and logf.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require

#define FIT_MODEL 0
#define FIT_LOBES 1
#include "fit/fit_model.glsl"
#include "shared/fit_probe.h"

layout(local_size_x = 64, local_size_x_id = 0) in;

layout(std430, set = 0, binding = 0) readonly buffer Inputs { FitProbeInput inputs[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Outputs { FitProbeOutput outputs[]; };
layout(push_constant) uniform Push { uint count; };

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= count) return;
  FitProbeInput in_ = inputs[i];
  FitProbeOutput out_;
  // The element goes in component i % 4 of the vec4 twins (the others hold harmless values),
  // so every component's arithmetic is checked.
  int c = int(i % 4u);
  vec4 exp_arg = vec4(0.0);
  vec4 log_arg = vec4(1.0);
  vec4 base = vec4(0.5);
  vec4 n = vec4(1.0);
  exp_arg[c] = in_.exp_arg;
  log_arg[c] = in_.log_arg;
  base[c] = in_.base;
  n[c] = in_.n;
  out_.exp_value = FitExp(exp_arg)[c];
  out_.log_value = FitLog(log_arg)[c];
  vec4 dvdb, dvdn;
  out_.lobe_value = FitLobeValueAndSlopes(base, n, dvdb, dvdn)[c];
  out_.dvalue_dbase = dvdb[c];
  out_.dvalue_dn = dvdn[c];
  out_.reserved0 = 0.0;
  out_.reserved1 = 0.0;
  out_.reserved2 = 0.0;
  outputs[i] = out_;
}
