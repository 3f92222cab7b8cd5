#pragma once
// Re-rendering a capture's photographs from a fit: what `reflcap render` does (and `reflcap run`
// will do), as a library so tests and later verbs call it directly.
//
// Input: a capture/1 and a parameter map FIT/params.exr (BrdfMaps channels, brdf_maps.h) in the
// layout of the capture's atlas — BuildTexelAtlas(mesh, W, H) with W x H the size of params.exr for
// mesh captures, BuildNormalMapAtlas(normals, mask) for normal-map captures (params.exr then has
// the camera's size). A synthetic capture's gt/params.exr is such a map.
//
// Output folder (the caller stages it; see StagingDir), for each selected photograph with
// relative file F (e.g. images/0003.exr) and key K = ImageKey(F) (e.g. 0003):
//   F with extension .exr    the re-render: float RGB, exposure_s * radiance (as the photograph)
//   masks/K.png              object mask at the pixel centre, 8-bit grey, 255 = object
//   aux/K.exr                validation buffers, float, channels AuxChannelNames() (see
//                            reference_renderer.h: cast_shadow, cos_theta_i, cos_theta_o,
//                            curvature, mask)
//   render_report.json       backend, device, capture, fit, split, options, atlas, per-image
//                            files and seconds, timings
#include <array>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "engine/capture/capture.h"
#include "engine/core/shard.h"
#include "engine/core/status.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"
#include "render/reference/indirect_light.h"
#include "render/reference/reference_renderer.h"

namespace reflcap::render {

// Which photographs a command works on.
enum class SplitSelection { kHoldout, kTrain, kAll };
// "holdout", "train", "all"; anything else is InvalidArgument naming `option`.
StatusOr<SplitSelection> ParseSplitSelection(const std::string& text, const std::string& option);
const char* SplitSelectionName(SplitSelection selection);
bool IsSelected(SplitSelection selection, Split split);

// The name an image's derived files take: its relative file without extension, and without a
// leading "images/" folder ("images/0003.exr" -> "0003", "raw/a.png" -> "raw/a").
std::string ImageKey(const std::string& file);
// Relative paths of the derived files of image file F inside a render folder. An F that is
// absolute or leaves the capture's folder ("..") contributes only its file name (images/<name>),
// so no output ever lands outside the render folder.
std::string RenderPathFor(const std::string& file);  // F with extension .exr
std::string MaskPathFor(const std::string& file);    // masks/<key>.png
std::string AuxPathFor(const std::string& file);     // aux/<key>.exr

// A capture's geometry with a fit on it, ready to render.
struct FittedCapture {
  const Capture* capture = nullptr;
  bool normal_map = false;
  TriangleMesh mesh;                  // mesh captures
  std::unique_ptr<RayScene> scene;    // mesh captures
  TexelAtlas atlas;
  BrdfMaps maps;
  // Normal-map captures: the height field integrated from the normal map (cast shadows), when
  // LoadFittedCapture was asked for it and the camera is orthographic; else null.
  std::unique_ptr<HeightField> height_field;
};

// Loads the geometry of `capture` and the parameter map `params_exr` in its atlas layout; for a
// normal-map capture with `height_field` also integrates its height field (IntegrateNormalMap;
// skipped with a warning for a pinhole camera). Errors name the file: NotFound (missing),
// InvalidArgument (a missing channel, a size that does not match a normal-map capture's camera),
// DataLoss (corrupt).
StatusOr<std::unique_ptr<FittedCapture>> LoadFittedCapture(const Capture& capture,
                                                           const std::filesystem::path& params_exr,
                                                           bool height_field = true);

// Renders capture image `index` (mesh or normal map).
StatusOr<RenderResult> RenderCaptureImage(const FittedCapture& fitted, size_t index,
                                          const RenderOptions& options);

enum class IndirectMode { kAuto, kOn, kOff };
// "auto", "on", "off"; anything else is InvalidArgument naming `option`.
StatusOr<IndirectMode> ParseIndirectMode(const std::string& text, const std::string& option);
const char* IndirectModeName(IndirectMode mode);

// CaptureRenderOptions::supersampling = kAutoSupersampling: the pixel model follows the
// photographs (PixelEvidence): one ray through each pixel centre when they are point samples (every
// `reflcap synth` capture without --supersample), kAutoBoxSupersampling² stratified rays averaged
// over the pixel (a box filter) when they integrate over their pixels, as a camera's sensor does
// and a path tracer's pixel filter (suzanne: Blackman-Harris 1.5 px) does.
constexpr int kAutoSupersampling = 0;
// 4 x 4 = 16 rays: suzanne's holdout PSNR-L 29.04 dB at 1, 30.66 at 2, 30.94 at 3, 31.04 at 4
// (render 8.3 / 21.4 / 31.7 s at 1 / 3 / 4); past 4 the box average changes by less than the
// photographs' own noise.
constexpr int kAutoBoxSupersampling = 4;
// "auto" -> kAutoSupersampling, "1".."16" -> N; anything else InvalidArgument naming `option`.
StatusOr<int> ParseSupersampling(const std::string& text, const std::string& option);

// CaptureRenderOptions::pixel_footprint = kAutoPixelFootprint: with the pixel model auto and a box
// chosen, the square the N x N samples cover (RenderOptions::pixel_footprint) follows the
// photographs too (FootprintEvidence); else 1, the pixel itself.
constexpr double kAutoPixelFootprint = 0;
// The footprints the evidence compares (px): the pixel, then wider in steps whose renders differ
// visibly at edges. Suzanne (Cycles' Blackman-Harris filter, "1.5 px" — which Cycles doubles for
// this filter: 3 px of support, standard deviation 0.42 px) holdout PSNR-L 31.08 dB at 1, 31.35
// at 1.25, 31.45 at 1.5, 31.41 at 1.75, 31.24 at 2.
constexpr std::array<double, 5> kPixelFootprintCandidates = {1.0, 1.25, 1.5, 1.75, 2.0};
// The auto pixel model's rays per side over a footprint W px wide: the 1 px box's density,
// kAutoBoxSupersampling per pixel width, kept — ceil(4 W), at most kMaxSupersampling (1.5 px:
// 6 x 6). Suzanne at 1.5 px: 4 x 4 rays PSNR-L 31.45 dB, shadow-edge ratio 1.52x; 6 x 6 31.50 dB,
// 1.49x (render 42 → 66 s on 2 cores): spread over a wider square, 4 rays a side undersample its
// edges.
int AutoBoxSupersampling(double pixel_footprint);
// "auto" -> kAutoPixelFootprint, a number in [1, kMaxPixelFootprint] -> it; anything else
// InvalidArgument naming `option`.
StatusOr<double> ParsePixelFootprint(const std::string& text, const std::string& option);

// Normal-map captures' point spread (point_spread.h), CaptureRenderOptions::psf_sigma_px: auto
// decides it from the train photographs; 0 = sharp (each pixel its texel's shade).
constexpr double kAutoPsf = -1.0;
// Largest σ accepted (px): wider than any focused camera's spread; the blur's cost grows with it.
constexpr double kMaxPsfSigmaPx = 4.0;
// "auto" -> kAutoPsf, "none" -> 0, a number in [0, kMaxPsfSigmaPx] -> σ; anything else
// InvalidArgument naming `option` (point_spread.cc).
StatusOr<double> ParsePsf(const std::string& text, const std::string& option);

// Normal-map captures: which integration of the normal map casts the render's shadows
// (engine/mesh/height_field.h). kAuto renders up to kHeightFieldEvidenceImages train photographs
// with direct light over the least-squares and the L1 field and compares them with the
// photographs where the two fields' shadows differ (elsewhere the renders are equal):
// `reduction` = 1 − Σ (photo − L1 render)² / Σ (photo − LS render)² there. L1 is taken when at
// least kMinHeightFieldEvidencePixels such pixels were seen and reduction ≥
// kMinHeightFieldErrorReduction (HeightFieldEvidence).
enum class HeightFieldChoice { kAuto, kLeastSquares, kL1 };
// "auto", "ls", "l1"; anything else InvalidArgument naming `option`.
StatusOr<HeightFieldChoice> ParseHeightFieldChoice(const std::string& text,
                                                   const std::string& option);
const char* HeightFieldChoiceName(HeightFieldChoice choice);
// 8 lights show the object's shadows from every side (DiLiGenT's grid spans the hemisphere).
constexpr int kHeightFieldEvidenceImages = 8;
// Fewer pixels of differing shadow than this decide nothing (least squares stays): ball16 has 0,
// the concave DiLiGenT objects 400–2,200 over 8 photographs.
constexpr size_t kMinHeightFieldEvidencePixels = 100;
// Where the shadows differ, one render is dark and the other lit, so the photograph votes: the
// DiLiGenT objects measured +0.45 (buddha) to +0.98 (bear) for L1 and −0.29 (cat) against it.
// 0.1 asks for a clear majority of that light; less keeps least squares.
constexpr double kMinHeightFieldErrorReduction = 0.1;

struct HeightFieldEvidence {
  int images = 0;
  int skipped = 0;
  size_t pixels = 0;
  size_t pixels_differing = 0;         // pixels (of `pixels`) whose shadows differ
  double error_ls = 0, error_l1 = 0;  // Σ (photo − direct render)² over those pixels
  double reduction = 0;               // 1 − error_l1 / error_ls
  bool l1 = false;
};
// `l1_field`: the L1 integration of `fitted`'s normal map (fitted.height_field is the
// least-squares one). Unreadable photographs are left out with a warning.
HeightFieldEvidence MeasureHeightFieldEvidence(const FittedCapture& fitted,
                                               const HeightField& l1_field);

struct CaptureRenderOptions {
  SplitSelection split = SplitSelection::kHoldout;
  // N x N samples per pixel, [1, kMaxSupersampling], or kAutoSupersampling (the default); mesh
  // captures (a normal map's pixel is its texel).
  int supersampling = kAutoSupersampling;
  // Mesh captures: the square (px) the N x N samples of a pixel cover, [1, kMaxPixelFootprint], or
  // kAutoPixelFootprint (the default): decided with the pixel model when `supersampling` is auto,
  // 1 when it is fixed. Without supersampling (N = 1) it changes nothing. With `supersampling`
  // auto and a box, a footprint W > 1 takes AutoBoxSupersampling(W) rays a side.
  double pixel_footprint = kAutoPixelFootprint;
  bool cast_shadows = true;  // mesh captures: shadow rays; normal maps: see height_shadows
  // Normal-map captures: cast shadows from the height field integrated from the normal map (with
  // cast_shadows; false = none, as before the height field). Mesh captures ignore it.
  bool height_shadows = true;
  // Normal-map captures with height_shadows: the height field's integration (above).
  HeightFieldChoice height_field = HeightFieldChoice::kAuto;
  // Interreflection (indirect_light.h), mesh captures: kOff renders direct light only; kOn adds
  // `indirect_bounces` bounces gathered over `indirect_rays` rays per texel; kAuto adds them when
  // the capture's train photographs show light where no direct light reaches (IndirectEvidence).
  IndirectMode indirect = IndirectMode::kAuto;
  int indirect_bounces = 2;  // [1, kMaxIndirectBounces]
  int indirect_rays = 64;    // [1, kMaxIndirectRays]
  // Normal-map captures: the photographs' point spread, a Gaussian of this standard deviation in
  // pixels applied within the mask (point_spread.h); kAutoPsf or [0, kMaxPsfSigmaPx]. Mesh
  // captures ignore it (their pixel model is `supersampling`).
  double psf_sigma_px = kAutoPsf;
  // Threads writing the output files while later images render (EXR compression is most of a
  // GPU render's time); 0 = one per hardware thread. [0, 256].
  int writers = 0;
  // Shard `shard.index` of `shard.count` (`render --shard I/N`): only a contiguous range of the
  // selected photographs (ShardRange over them, in capture order); render_report.json then
  // carries `shard` and MergeRenderParts joins the parts.
  Shard shard;
  // Called by a writer thread once the files of capture image `index` are written, with the
  // result they were written from (`reflcap run` scores it for validation while it is in memory:
  // validate::StreamingValidation). An error stops the render as a write error does. Empty: none.
  std::function<Status(size_t index, const RenderResult& result)> after_write;
  Status Validate() const;
};

// Whether a capture's photographs show interreflection (CaptureRenderOptions::indirect = kAuto):
// up to 12 train photographs, evenly spaced, are rendered with direct light and with the indirect
// light alone; over the pixels whose 3x3 neighbourhood is object without direct light (facing away
// from the light, or cast-shadowed; unsaturated, finite), `scale` = Σ photo · indirect / Σ
// indirect² (~0 when the photographs are black there, ~1 when the prediction explains them) and
// `error_reduction` = 1 − Σ (photo − indirect)² / Σ photo², the share of those pixels' squared
// error (against a black direct-light render) that adding the indirect light removes. `shows`
// when at least 1000 such pixels were seen and error_reduction ≥ 0.25. A photograph that cannot
// be rendered or read, or whose size is not its camera's, is left out (`skipped`, with a
// warning naming it): the evidence advises, and a selected photograph reports its own error.
// `supersampling` is the render's pixel model (1, or a box's N > 1: MeasurePixelEvidence decided
// it): for a box both renders are averaged over 2 x 2 samples per pixel and a pixel is unlit only
// when none of its samples gets direct light — at the pixel centre alone, the partly lit pixels
// beside shadow edges (lit in a photograph that integrates over its pixels) passed for unlit and
// hid the interreflection (synthetic 3 x 3 photographs with it: error reduction 0.18, off).
struct IndirectEvidence {
  int images = 0;
  int skipped = 0;
  size_t pixels = 0;
  double scale = 0;
  double error_reduction = 0;
  bool shows = false;
};
// Renders capture image `index` of a FittedCapture for the evidence below (direct light, with
// aux buffers when asked): empty = the CPU reference renderer (RenderCaptureImage); a render
// backend on a GPU passes its own (CaptureRenderBackend::renders_evidence).
using EvidenceRender = std::function<StatusOr<RenderResult>(size_t index, const RenderOptions&)>;
IndirectEvidence MeasureIndirectEvidence(const FittedCapture& fitted,
                                         const IndirectLight& indirect, int bounces,
                                         bool cast_shadows, int supersampling,
                                         const EvidenceRender& render = {});
// Which pixel model reproduces a capture's photographs (CaptureRenderOptions::supersampling =
// kAutoSupersampling): up to 8 train photographs, evenly spaced, are rendered with direct light at
// the pixel centre (1 ray) and averaged over the pixel (2 x 2 stratified rays, a box filter);
// `error_point` and `error_box` are their display-referred squared errors over the photographs'
// pixels (finite, unsaturated): both images over the photograph's 99th percentile, clipped to
// [0, 1], sRGB-encoded, as PSNR-L and the footprint's evidence weigh them. `reduction` = 1 −
// error_box / error_point. `box` when reduction ≥ kMinPixelErrorReduction: the photographs
// integrate over their pixels, and the render then uses kAutoBoxSupersampling. A photograph that
// cannot be rendered or read, or whose size is not its camera's, is left out (`skipped`, with a
// warning naming it); a black one is not counted.
struct PixelEvidence {
  int images = 0;
  int skipped = 0;
  size_t pixels = 0;
  double error_point = 0;
  double error_box = 0;
  double reduction = 0;
  bool box = false;
};
// A box-filtered render must remove at least this share of the point render's squared error.
// Measured on the train photographs (display-referred): photographs that integrate over their
// pixels 0.105 (synthetic, 3 x 3 rays over the pixel, 64 px; the weakest seen), 0.147 (4 x 4 over
// 1.5 px), 0.25 (a Blender torus knot), 0.33 (a scan of suzanne), 0.37 (suzanne: Cycles' 1.5 px
// Blackman-Harris filter); point-sampled synthetic captures −0.02 (million preset), −0.03, −0.05,
// −0.10 (seed 11), −0.17 (demo). 5 % sits between the two with 7 points to spare on each side.
// (In linear values the knot's missed highlights held its reduction to 0.032, and to below 0.02
// on a noisier rendering of it, which then rendered point samples: display values weigh the
// edges and texture borders where the pixel model shows.)
constexpr double kMinPixelErrorReduction = 0.05;
PixelEvidence MeasurePixelEvidence(const FittedCapture& fitted, bool cast_shadows,
                                   const EvidenceRender& render = {});

// How wide a pixel's footprint is (CaptureRenderOptions::pixel_footprint = kAutoPixelFootprint,
// once MeasurePixelEvidence chose a box): the same train photographs rendered at `supersampling`
// N x N rays spread over each of kPixelFootprintCandidates, with direct light and, when
// `indirect` is given, its `indirect_bounces` of interreflection (as the render will add them:
// without, the light bounced into shadows rewards footprints that smear lit pixels into them);
// `error[k]` = Σ (photo − render)² over their usable pixels, display-referred (both over the
// photograph's 99th percentile, clipped to [0, 1], sRGB: see the .cc). `footprint` is the candidate with the least error when it
// removes at least kMinFootprintErrorReduction of the error at 1 px (`reduction`), else 1.
// Photographs left out as MeasurePixelEvidence does (`skipped`).
struct FootprintEvidence {
  int images = 0;
  int skipped = 0;
  size_t pixels = 0;
  std::array<double, kPixelFootprintCandidates.size()> error{};
  double reduction = 0;
  double footprint = 1;
};
// A wider footprint must remove at least this share of the 1 px box's squared error. Suzanne's
// train photographs: 1.5 px removes 25 %; synthetic photographs at 3 x 3 rays over 1 px: the
// least error is at 1 px; at 4 x 4 rays over 1.5 px, 1.5 px removes 7 %. 1 % asks for a real
// gain over the pixel, not noise.
constexpr double kMinFootprintErrorReduction = 0.01;
FootprintEvidence MeasureFootprintEvidence(const FittedCapture& fitted, bool cast_shadows,
                                           int supersampling, const IndirectLight* indirect,
                                           int indirect_bounces,
                                           const EvidenceRender& render = {});

// Adds the interreflection of capture image `index` (IndirectLight::TexelRadiance for its light
// and pose, then AddTexelRadiance with its camera and exposure) to `pixels`.
void AddIndirectLight(const FittedCapture& fitted, const IndirectLight& indirect, size_t index,
                      int bounces, bool cast_shadows, int supersampling, double pixel_footprint,
                      Image* pixels);
// Its second half: adds texel radiance (TexelRadiance's) to capture image `index`'s pixels.
void AddTexelRadiancePixels(const FittedCapture& fitted, size_t index, int supersampling,
                            double pixel_footprint, const std::vector<Vec3f>& radiance,
                            Image* pixels);

struct CaptureRenderSummary {
  size_t images = 0;
  size_t texels = 0;
  int num_lobes = 0;
  int writers = 0;
  // load_s: capture, mesh and fit loaded (and uploaded); render_s: from then until the last image
  // was rendered; write_s: wall time spent writing files, summed over the writer threads (it
  // overlaps rendering, and on busy cores includes waiting for one);
  // write_tail_s: from the last image rendered until its files were written.
  double load_s = 0, render_s = 0, write_s = 0, write_tail_s = 0, total_s = 0;
};

// Renders every selected photograph of `capture` into `out_dir` (created if missing), with the
// layout above; each image's files are written by a pool of writer threads while the next
// images render. FailedPrecondition when no photograph is selected; errors of LoadFittedCapture,
// of rendering (naming capture.json and images[i]) and of writing (Internal, naming the file).
// After an error the folder may hold some images' files (the CLI stages it: nothing appears).
// `reflcap merge` of render parts: checks that `parts` are the shards 0..N-1 of one render (the
// same capture, fit and options, each shard once, their images tiling the selection) and
// copies their files into `out_dir` (which must exist: the caller stages it), with one
// render_report.json listing every image in capture order. FailedPrecondition naming the part
// and field for parts that do not belong together; NotFound/DataLoss for a missing file.
Status MergeRenderParts(const std::vector<std::filesystem::path>& parts,
                        const std::filesystem::path& out_dir);

StatusOr<CaptureRenderSummary> RenderCapture(const Capture& capture,
                                             const std::filesystem::path& params_exr,
                                             const std::filesystem::path& out_dir,
                                             const CaptureRenderOptions& options);

// What renders the photographs for RenderCapture below: another backend (the Vulkan renderer,
// render/vulkan) plugs in here and gets the same file layout and report.
struct CaptureRenderBackend {
  std::string backend = "cpu";  // render_report.json "backend"
  std::string device = "cpu";   // render_report.json "device" (the Vulkan device's name)
  std::string renderer;         // render_report.json "renderer": one line on what it is
  // Called once, after the capture and the fit are loaded and before the first render (e.g. to
  // upload the scene); may be empty.
  std::function<Status(const FittedCapture&)> prepare;
  // Renders image `index` (as RenderCaptureImage does); called once per selected image unless
  // render_many is set.
  std::function<StatusOr<RenderResult>(const FittedCapture&, size_t, const RenderOptions&)> render;
  // Optional: renders images `indices` (capture image indices) in one call and hands them over
  // as sink(k, result) for k = 0, 1, ... (positions in `indices`), in order — a backend that
  // renders many images per submission (the Vulkan renderer) does it this way.
  using Sink = std::function<Status(size_t k, RenderResult&& result)>;
  std::function<Status(const FittedCapture&, const std::vector<size_t>& indices,
                       const RenderOptions&, const Sink& sink)>
      render_many;
  // Whether `render` also renders the train photographs that decide the auto settings (pixel
  // model, interreflection): for a GPU, where it is far faster than the CPU reference renderer
  // those renders otherwise take (10.6 s of `reflcap render`'s 11.4 s load on the million
  // preset, 2 cores). `prepare` then runs before them. The decisions compare sums over millions of
  // pixels with a 2 % or 25 % margin: the renderers' differences (shadow maps against rays, at
  // shadow edges) do not move them.
  bool renders_evidence = false;
};
// The CPU reference renderer as a backend (what RenderCapture above uses).
CaptureRenderBackend CpuCaptureRenderBackend();
// RenderCapture with `backend` rendering each photograph.
StatusOr<CaptureRenderSummary> RenderCapture(const Capture& capture,
                                             const std::filesystem::path& params_exr,
                                             const std::filesystem::path& out_dir,
                                             const CaptureRenderOptions& options,
                                             const CaptureRenderBackend& backend);

}  // namespace reflcap::render
