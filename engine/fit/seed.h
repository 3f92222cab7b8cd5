#pragma once
// Start values: the seed paper's data-driven initialisation and a fixed start to compare it with.
//
// The seed (Fukuda, Kawasaki, Kuno, Furukawa, "Efficient reflectance property estimation of 3D
// object's surface"), section 4.2, as the issue restates it, and how we read it:
//
//   "ρ_d from the median of the samples divided by cos θi". The seed's samples are pixel
//   intensities I = E_0 f cos θi (E_0 the light's irradiance at normal incidence), so I / cos θi
//   is E_0 f: the seed divides by cos θi to turn intensities into BRDF values. Our BrdfSamples
//   are already BRDF values (the resampler divided by the irradiance E_0 cos θi), so the
//   division has been done, and the seed's f = ρ_d + lobes (no 1/π) makes our start albedo
//     ρ_d,0 = π · median_j f_j   (per channel, over the valid samples).
//   The median ignores the few highlight samples and the shadowed ones.
//
//   "the lobe's C's from the brightest sample's directions (C = wi / wo per component, with
//   guarded division)". For the brightest sample j* (largest value above ρ_d,0 / π) we take
//     C_dir,x = wi_x / wo_x,  C_dir,y = wi_y / wo_y,  C_dir,z = wi_z / wo_z,
//   the lobe that, lit from wo, peaks exactly at wi (and by reciprocity the reverse): its base
//   C_dir · (wi ∘ wo) = |wi|^2 = 1 at j*, the largest value over unit directions. For a mirror
//   pair this is the classic (-1, -1, 1). Guarded division: a component whose product
//   |wi_j wo_j| < kSeedMinProduct carries no information (near-normal incidence makes both x
//   and y tiny) and takes the mirror value (-1, -1, +1)_j instead; the ratio is clamped to
//   ±kSeedMaxRatio. Then C = k C_dir with k chosen so the lobe reproduces the sample's excess
//   e = f_j* - ρ_d,0 / π at the start exponent: (k b*)^n0 = e, b* = C_dir · (wi ∘ wo).
//   If b* < kSeedMinBase (the guarded direction does not reach the brightest sample), the
//   mirror direction is used, and if that fails too, b* is taken as 1.
//
//   "n fixed to a documented start value": n0 = FitOptions::start_exponent (default 20).
//
// Section 4.3's two-stage LM follows: stage 1 frees only the lobes' C's (ρ_d and n held at
// their start values), stage 2 frees everything. For the shared model stage 1 frees the
// shape's Cx, Cy and the per-channel scales (the magnitude that C carries in the other models).
//
// Lobes k >= 1 (K > 1) start the same way from the brightest sample of what the start's
// Lambert term and lobes 0..k-1 leave unexplained; if nothing is left (no positive excess),
// lobe k starts as the mirror lobe with a tenth of lobe 0's peak and 4^k n0.
//
// The fixed start (InitScheme::kFixed) is the same BRDF for every texel, in natural units:
// ρ_d = kFixedAlbedo and lobe k the mirror lobe C = (-1, -1, 1) c with peak c^n = kFixedPeak /
// (k + 1) at exponent 4^k n0 (shared: Cx = Cy = -1, s_c = kFixedPeak / (k + 1)), converted to
// the problem's normalised units; one LM stage over all parameters. It uses no data, so
// comparing the two (the seed's Fig. 19) measures what the data-driven start and the staging buy.
#include "engine/fit/model.h"
#include "engine/math/types.h"

namespace reflcap::fit {

// |wi_j wo_j| below this: component j of the base is < 1 % of a unit base, too little to
// determine C_j from one sample.
constexpr double kSeedMinProduct = 0.01;
// |wi_j / wo_j| above 4 means wo_j is much smaller than wi_j, far from any mirror pair; the
// clamp keeps a start coefficient within the range real lobes have.
constexpr double kSeedMaxRatio = 4.0;
// A start lobe whose base at its own brightest sample is < 0.1 would need k > 10 x the usual to
// reach that sample; fall back to the mirror direction instead.
constexpr double kSeedMinBase = 0.1;
// Smallest excess (normalised units) a start lobe is given, so k > 0 and log(k) is defined.
constexpr double kSeedMinExcess = 1e-3;
// Fixed start: a mid-grey albedo and a lobe peaking at 1 / sr, typical of glossy paint.
constexpr double kFixedAlbedo = 0.5;
constexpr double kFixedPeak = 1.0;

// The seed's guarded direction C_dir for a brightest sample (wi, wo), and its base b* there.
Vec3d SeedLobeDirection(const Vec3d& wi, const Vec3d& wo, double* base);

// Writes lobe k's start parameters (normalised units) into x for a brightest sample (wi, wo)
// with excess e_c per channel (channels of the problem: 1 for aniso/iso, 3 for shared), at
// exponent n. For kShared, C_dir is rescaled to Cz = 1 (mirror direction when C_dir,z <=
// kSeedMinBase) and s_c = e_c / b_s^n with b_s the rescaled base.
void SeedLobeStart(const ProblemLayout& layout, int k, const Vec3d& wi, const Vec3d& wo,
                   const double* excess, double n, double* x);

// The fixed start (every parameter of x) for a problem of normalisation scale S.
void FixedStart(const ProblemLayout& layout, double n0, double scale, double* x);

}  // namespace reflcap::fit
