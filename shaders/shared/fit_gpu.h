// Buffer layouts of the Vulkan fitter (shaders/fit/lm_fit.comp, driven by
// engine/fit/vulkan_fitter.cc): push constants, settings, the queue control block, and the word
// layouts of the per-problem descriptors, the per-lane LM state and the per-problem results.
// The LM constants themselves are in fit_status.h, shared with the CPU fitters.
//
// Arrays whose stride depends on the problem's parameter count P (a compile-time permutation of
// the shader, NumParams(model, lobes) on the C++ side) are plain 32-bit word arrays (uint; floats
// stored as their bits) with the strides below, so that a P = 5 problem moves 5-parameter
// records and not kLmMaxParams-sized ones.
//
// Valid C++17 and GLSL (GL_GOOGLE_include_directive): see interop.h.
#ifndef REFLCAP_SHADERS_SHARED_FIT_GPU_H_
#define REFLCAP_SHADERS_SHARED_FIT_GPU_H_

#include "fit_status.h"
#include "interop.h"

// ---- Word strides (P = parameters of the layout) ---------------------------------------------
// Residuals: the five floats of a residual as ResidualView holds them (normalised units,
// problem.h): xx, yy, zz, y, sqrt(w).
#define REFLCAP_FIT_RECORD_FLOATS 5
// On the device (binding 3, an RGBA32F uniform texel buffer) a problem's residuals are quads:
// residuals 4q .. 4q + 3 are the REFLCAP_FIT_QUAD_TEXELS texels from the problem's first texel
// + 5q on, one per float of the record (xx of the four, then yy, zz, y, sqrt(w)); the last
// quad is padded with zeros (sqrt(w) = 0: no weight). lm_fit.comp says why.
#define REFLCAP_FIT_QUAD_TEXELS REFLCAP_FIT_RECORD_FLOATS
// Descriptors and results are read and written as uvec4s (lm_fit.comp says why), so their
// strides are whole uvec4s; the padding words are unused.
#define REFLCAP_FIT_ROUND_UP4(n) (((n) + 3) / 4 * 4)
// Problem descriptor (binding 1): kFitDesc* header words, then x0[P] (float bits).
#define REFLCAP_FIT_DESC_STRIDE(p) REFLCAP_FIT_ROUND_UP4(8 + (p))
// Lane state (binding 4, uint[]): kFitLane* header words, then x, x_new, jacobi, 1 / jacobi and
// J^T r at x (P floats each), then J^T J at x (packed lower triangle, P (P + 1) / 2 floats).
#define REFLCAP_FIT_LANE_STRIDE(p) (16 + 5 * (p) + (p) * ((p) + 1) / 2)
// Result (binding 5): kFitOut* header words, then x[P], then J^T J at x (packed).
#define REFLCAP_FIT_OUT_STRIDE(p) REFLCAP_FIT_ROUND_UP4(4 + (p) + (p) * ((p) + 1) / 2)

REFLCAP_SHARED_BEGIN

// No problem (lane state word kFitLaneProblem of an idle lane).
REFLCAP_CONST(uint, kFitNoProblem, 0xFFFFFFFFu);

// Descriptor header words.
REFLCAP_CONST(int, kFitDescBegin, 0);      // first texel of the problem's first quad
REFLCAP_CONST(int, kFitDescBlock1, 1);     // residuals of channel block 0 (= start of block 1)
REFLCAP_CONST(int, kFitDescBlock2, 2);     // start of channel block 2 (shared model), relative
REFLCAP_CONST(int, kFitDescCount, 3);      // residuals of the problem
REFLCAP_CONST(int, kFitDescStages, 4);     // LM stages (1 or 2; 0-stage problems stay on the CPU)
REFLCAP_CONST(int, kFitDescMask0, 5);      // free-parameter mask of stage 0
REFLCAP_CONST(int, kFitDescMask1, 6);      // free-parameter mask of stage 1
REFLCAP_CONST(int, kFitDescLossScale, 7);  // robust loss scale, normalised units (float bits)
REFLCAP_CONST(int, kFitDescX0, 8);         // start parameters x0[P] (float bits)

// Lane state header words (lm.h's LmState plus the problem's stage bookkeeping).
REFLCAP_CONST(int, kFitLaneProblem, 0);      // batch problem index, kFitNoProblem when idle
REFLCAP_CONST(int, kFitLaneStage, 1);        // current stage
REFLCAP_CONST(int, kFitLanePhase, 2);        // LmPhase
REFLCAP_CONST(int, kFitLaneStatus, 3);       // FitStatus of the stage
REFLCAP_CONST(int, kFitLaneFreeMask, 4);     // free mask of the stage
REFLCAP_CONST(int, kFitLaneIterations, 5);   // evaluated steps of the stage
REFLCAP_CONST(int, kFitLaneFailures, 6);     // consecutive failed factorisations
REFLCAP_CONST(int, kFitLaneTotal, 7);        // evaluated steps of the finished stages
REFLCAP_CONST(int, kFitLaneLambda, 8);       // damping (float bits)
REFLCAP_CONST(int, kFitLaneNu, 9);           // damping growth (float bits)
REFLCAP_CONST(int, kFitLaneCost, 10);        // cost at x (float bits)
REFLCAP_CONST(int, kFitLanePredicted, 11);   // predicted decrease of x_new (float bits)
REFLCAP_CONST(int, kFitLaneAtCost, 12);      // cost of the normal equations at x (float bits)
REFLCAP_CONST(int, kFitLaneArrays, 16);      // x[P] starts here

// Result header words.
REFLCAP_CONST(int, kFitOutStatus, 0);      // FitStatus of the last stage
REFLCAP_CONST(int, kFitOutFreeMask, 1);    // free mask of the last stage
REFLCAP_CONST(int, kFitOutIterations, 2);  // evaluated steps over all stages
REFLCAP_CONST(int, kFitOutCost, 3);        // cost of the normal equations at x (float bits)
REFLCAP_CONST(int, kFitOutX, 4);           // x[P] starts here, then J^T J packed

// lm.h's LmPhase values.
REFLCAP_CONST(uint, kFitPhaseEvaluateStart, 0u);
REFLCAP_CONST(uint, kFitPhaseEvaluateStep, 1u);
REFLCAP_CONST(uint, kFitPhaseDone, 2u);
REFLCAP_CONST(uint, kFitPhasePropose, 3u);

// FitOptions::loss values (specialization constant 1 of lm_fit.comp).
REFLCAP_CONST(int, kFitLossNone, 0);
REFLCAP_CONST(int, kFitLossHuber, 1);
REFLCAP_CONST(int, kFitLossCauchy, 2);

// Push constants of one dispatch.
struct FitGpuPush {
  uint problem_count;  // entries of the queue (binding 2)
  uint lane_count;     // persistent lanes; invocations at or past it return at once
  uint ticks;          // LM ticks (one evaluation each) every lane may run in this dispatch
  uint reserved;
};
REFLCAP_STD430_SIZE(FitGpuPush, 16);

// Push constants of one dispatch of lm_fit_cluster.comp: the queue entries [queue_begin,
// queue_begin + queue_count) and the control entry (binding 6) whose `next` hands them out.
struct FitGpuClusterPush {
  uint queue_begin;
  uint queue_count;
  uint control_slot;
  uint reserved;
};
REFLCAP_STD430_SIZE(FitGpuClusterPush, 16);

// Specialization constants of lm_fit_cluster.comp (0 = local_size_x, 1 = loss as lm_fit.comp).
REFLCAP_CONST(int, kFitClusterSizeConstantId, 2);  // invocations per problem
REFLCAP_CONST(int, kFitNativeMathConstantId, 3);   // 1: the device's exp/log (fit_model.glsl)

// Binding 0: what every problem of a batch shares (lm.h's LmSettings and the layout's bounds).
struct FitGpuSettings {
  float lower[kLmMaxParams];   // ParameterBounds, normalised units
  float upper[kLmMaxParams];
  int max_iterations;          // evaluated steps per stage
  int first_stage_iterations;  // cap of stage 0 of a two-stage problem
  float step_tolerance;
  float cost_tolerance;
  float gradient_tolerance;
  int reserved0;
  int reserved1;
  int reserved2;
};
REFLCAP_STD430_SIZE(FitGpuSettings, 160);
REFLCAP_STD430_OFFSET(FitGpuSettings, max_iterations, 128);
REFLCAP_STD430_OFFSET(FitGpuSettings, gradient_tolerance, 144);

// Binding 6 (an array: lm_fit.comp uses entry 0, lm_fit_cluster.comp one entry per dispatch):
// the queue head and the dispatch's count of lanes that still hold a problem.
struct FitGpuControl {
  uint next;    // queue entries handed out so far (atomicAdd)
  uint busy;    // lanes that ended the dispatch holding an unfinished problem (atomicAdd)
  uint evaluations;  // residual evaluations in the dispatch (atomicAdd; statistics only; the
                     // host resets it with `busy`, and one dispatch does at most
                     // lanes x ticks x residuals < 2^32 of them, see vulkan_fitter.cc)
  uint reserved0;
};
REFLCAP_STD430_SIZE(FitGpuControl, 16);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_FIT_GPU_H_
