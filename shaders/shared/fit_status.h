// Per-texel fit status codes and the Levenberg–Marquardt constants that the CPU fitters
// (engine/fit/lm.h, engine/fit/batched_kernel.cc) and the Vulkan fitter (shaders/fit/lm_fit.comp,
// shaders/fit/fit_model.glsl) share bit for bit, so that every backend damps, stops and clamps
// alike.
// engine/fit/fitter.h turns the codes into `enum class FitStatus`; engine/fit/lm.h reads the
// constants. tests/engine/fit/fit_model_test.cc static_asserts that the C++ side uses these values.
//
// Valid C++17 and GLSL (GL_GOOGLE_include_directive): see interop.h.
#ifndef REFLCAP_SHADERS_SHARED_FIT_STATUS_H_
#define REFLCAP_SHADERS_SHARED_FIT_STATUS_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

// ---- Status codes (written to FIT/status.exr as floats; the order is the combination priority
// of engine/fit/fitter.h's CombineStatus only through that function, not through these values) --
// The last stage ended on a stopping test (relative step, relative cost decrease or gradient).
REFLCAP_CONST(int, kFitStatusConverged, 0);
// The last stage ran max_iterations evaluated steps without meeting a stopping test.
REFLCAP_CONST(int, kFitStatusMaxIterations, 1);
// J^T J at the solution is rank deficient on the free parameters (a Cholesky pivot of its
// unit-diagonal form < kLmSingularPivot), or kLmMaxSolveFailures damped factorisations in a row
// failed: some parameter combination is not determined by the samples. The texel then gets its
// Lambert-only fit (the lobe's parameters are not trusted; engine/fit/problem.h).
REFLCAP_CONST(int, kFitStatusSingular, 2);
// Fewer valid samples than the model needs (FitOptions::min_samples, and always > parameters):
// Lambert-only fit of what there is.
REFLCAP_CONST(int, kFitStatusTooFewSamples, 3);
// No valid sample within FitOptions::highlight_cone_deg of the mirror configuration: the seed's
// mirror-lobe start has nothing to start from and no lobe can be told apart from the diffuse
// term; or the fitted lobe rises above kMaxLobeSupremum x the brightest sample somewhere on the
// hemisphere (extrapolation: engine/fit/problem.h). Lambert-only fit.
REFLCAP_CONST(int, kFitStatusUnidentifiableLobe, 4);
// The texel's samples held a NaN or Inf (value, weight or direction); those samples were dropped
// and the rest fitted. This status replaces any other the fit of the rest would have had.
REFLCAP_CONST(int, kFitStatusNonFiniteInput, 5);
REFLCAP_CONST(int, kFitStatusCount, 6);
// status.exr value of atlas pixels that hold no texel.
REFLCAP_CONST(int, kFitStatusNoTexel, -1);

// ---- Levenberg–Marquardt constants (engine/fit/lm.h documents each use) --------------------
// Most parameters of one problem: aniso 1 + 4K (13 at K = 3), iso 1 + 3K, shared 3 + 6K (K <= 2).
REFLCAP_CONST(int, kLmMaxParams, 16);
// Packed lower triangle of a kLmMaxParams square matrix.
REFLCAP_CONST(int, kLmMaxPacked, 136);
// Start damping (TinySolver's 1 / initial_trust_region_radius).
REFLCAP_CONST(float, kLmInitialLambda, 1e-4f);
// Damping stays within [kLmMinLambda, kLmMaxLambda]: below the minimum the damped system is the
// Gauss–Newton one to float precision; above the maximum the step is ~1e-16 of the gradient
// step and the relative-step test ends the stage.
REFLCAP_CONST(float, kLmMinLambda, 1e-12f);
REFLCAP_CONST(float, kLmMaxLambda, 1e16f);
// The damping diagonal is the Jacobi-scaled J^T J diagonal clamped to [kLmMinDiagonal,
// kLmMaxDiagonal] (TinySolver), so a parameter without influence still gets a positive pivot.
REFLCAP_CONST(float, kLmMinDiagonal, 1e-6f);
REFLCAP_CONST(float, kLmMaxDiagonal, 1e32f);
// A step is accepted when actual / predicted cost decrease > kLmMinGainRatio (Ceres'
// min_relative_decrease).
REFLCAP_CONST(float, kLmMinGainRatio, 1e-3f);
// Consecutive failed damped factorisations (non-positive pivot) before the stage is kSingular.
REFLCAP_CONST(int, kLmMaxSolveFailures, 10);
// Rank test on the final J^T J scaled to unit diagonal: a Cholesky pivot (1 - R^2 of a parameter
// regressed on the ones before it) below 1e-4 means the samples determine that parameter 100x
// worse than they would alone — practically not at all. Float accumulation of J^T J perturbs
// pivots by ~1e-6, so the test gives the same answer in float and double except for problems
// within a hair of the threshold.
REFLCAP_CONST(float, kLmSingularPivot, 1e-4f);

// ---- Model constants in normalised units (engine/fit/model.h documents each) ---------------
// Lobe saturation while fitting, and the exp() argument clamps around it.
REFLCAP_CONST(float, kFitMaxLobeValue, 1e6f);
REFLCAP_CONST(float, kFitMaxLobeLogArg, 14.8155f);  // log(1e6) + 1
REFLCAP_CONST(float, kFitMinLobeLogArg, -80.0f);
// Box bounds: rho' in [0, kFitMaxRho], C' in [-kFitMaxC, kFitMaxC], s' in [0, kFitMaxScale],
// n in [kMinExponent, kMaxExponent] of lafortune_constants.h.
REFLCAP_CONST(float, kFitMaxRho, 1e3f);
REFLCAP_CONST(float, kFitMaxC, 1e3f);
REFLCAP_CONST(float, kFitMaxScale, 1e3f);
// Normalised weights are clamped to this.
REFLCAP_CONST(float, kFitMaxNormalisedWeight, 1e20f);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_FIT_STATUS_H_
