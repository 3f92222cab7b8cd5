#pragma once
// Checkerboard detection for calibration: OpenCV's findChessboardCornersSB (Duda & Frese 2018,
// "Accurate detection and localization of checkerboard corners for calibration") finds a grid,
// the grid is identified against the known boards, and every corner is refined by cornerSubPix
// (Förstner-style gradient orthogonality) in a window sized to the local square size.
//
// Identification. SB (with CALIB_CB_LARGER) returns a grid of w x h corners in an order of its
// own. A board matches when its inner-corner grid is w x h or h x w; of the grid's symmetries
// (turns and flips) only those that keep the board's handedness (u right, v down as seen from the
// printed side — a board seen from its front never appears mirrored) are tried, and the colours
// decide: through the board-plane homography every square centre must have its colour (square
// (0,0) black) and, where the board declares a white margin, points half-way into the margin must
// be white. A grid that is part of a larger board fails the margin test; a wrong turn fails the
// colours. A symmetric board (BoardSpec::Symmetry) passes in more than one numbering: all are
// returned, for the caller to choose with the rest of the target.
//
// Refinement (default: point symmetry). An inner corner of a checkerboard is a centre of point
// symmetry of the printed pattern: the board at corner + d looks like the board at corner - d.
// Each corner gets a homography H from board coordinates around it (in squares, the corner at 0)
// to pixels, fitted (RANSAC, so a lost neighbour drops out) through its grid neighbours; then a
// translation t is adjusted by Levenberg-Marquardt until the photo, sampled (bicubic) at H(s + t)
// and H(-s + t) for every s of a square window, agrees with itself; the corner is H(t). The
// residual compares black with black and white with white, so it needs no model of the edge
// profile or the blur; H follows a foreshortened board; the light may vary across the window (its
// odd part up to cubic, six more unknowns: a gradient of the light is the one thing that breaks
// the symmetry on a real board). Two passes: the second fits H through refined neighbours. The
// idea is Schöps et al. 2020, "Why having 10,000 parameters in your camera model is better than
// twelve" (their symmetry-based feature refinement); this formulation is ours. The window reaches
// symmetry_radius squares from the corner, so it uses the whole length of the edges near the
// corner, where cornerSubPix's gradient test uses a few pixels.
//
// Measured (corners started at their true projections + up to 0.3 px; bench/RESULTS.md, "Corner
// refinement"): on the shared cuboid photos (faces at cos >= 0.35) 0.026 px RMS against
// cornerSubPix's 0.060 px; on the shared board photos 0.020 px against 0.064 px; on the tests'
// synthetic renders 0.006 px against 0.030 px. The photos' sRGB curve is decoded first (without:
// 0.032 / 0.056 px); the shading terms take the cuboid from 0.028 to 0.026 px (the light falls off
// steeply towards the turntable plate) and a synthetic gradient from 0.044 to 0.007 px. What stays
// is systematic in those photos and common to both refiners: the corners sit 0.02 px off along the
// rows next to the plate, and every face shrinks by a relative 5e-5 (the cuboid looks 0.04 mm
// further away than it is). Larger windows average more noise, smaller ones see less of that
// shrink; symmetry_radius (below) is the measured compromise.
//
// cornerSubPix (Förstner-style gradient orthogonality) stays as CornerRefiner::kCornerSubPix. Its
// window must stay inside the four squares around a corner: on a foreshortened board a fixed 7x7
// window reaches the next corners and biases the result by tenths of a pixel. The half-window is
// window_fraction x the distance to the nearest grid neighbour, clamped to [min_half_window,
// max_half_window]: 0.060 px RMS on the shared photos against 0.076 px for a fixed 7x7 window.
// Larger windows and a Gaussian pre-smoothing lower its noise further but bias (lens distortion
// and perspective bend the squares around a corner; -2.2e-4 relative scale with 0.45 and a 0.8-px
// blur, which moved the adjusted axis point by 0.14 mm). Hence 0.4, no blur.
//
// OpenCV stays private: images cross this interface as engine Images.
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "calib/calib_file.h"
#include "engine/core/status.h"
#include "engine/image/image.h"
#include "engine/math/types.h"

namespace reflcap::calib {

enum class CornerRefiner {
  kSymmetry,      // point symmetry under a local projective map (default; see the header comment)
  kCornerSubPix,  // OpenCV's cornerSubPix with the adaptive window
};

// "symmetry" / "subpix"; nullopt for anything else.
std::optional<CornerRefiner> ParseCornerRefiner(const std::string& name);
const char* CornerRefinerName(CornerRefiner refiner);

struct DetectOptions {
  CornerRefiner refiner = CornerRefiner::kSymmetry;
  // Symmetry refinement: the window's half-size in squares, in (0, 1) (at 1 it reaches the next
  // corners, where the board's edge would break the symmetry). On the shared cuboid: 0.5 -> 0.8
  // lowers the corners' error (0.030 -> 0.025 px) and the principal point's error with
  // --refine-intrinsics (2.4 -> 1.9 px) but raises the faces' shrink (axis point 0.005 -> 0.019 mm,
  // the averaged-poses baseline 0.018-0.019 mm); 0.7 keeps both under their targets
  // (bench/RESULTS.md, "Calibration").
  double symmetry_radius = 0.7;
  // Symmetry refinement: spacing of the window's samples in the photo, pixels, in [0.25, 2]. Below
  // one pixel every pixel of the edges contributes; halving 0.7 changed nothing measurable.
  double symmetry_step_px = 0.7;
  // The photos are sRGB-encoded (8-bit PNG, as cameras write them): decode the curve before the
  // symmetry refinement. Its residual is indifferent to a tone curve only on an ideal image; on
  // sampled, interpolated pixels the decoded values halve the error on the shared photos (header
  // comment). False for linear photos.
  bool photos_srgb = true;
  // Symmetry refinement: let the light vary across the window (its odd part up to cubic: six more
  // unknowns per corner). A gradient of the light breaks the symmetry the residual assumes; on the
  // cuboid the light falls off steeply towards the turntable plate (see the header comment).
  bool symmetry_shading = true;
  // cornerSubPix half-window = window_fraction x distance to the nearest grid neighbour (pixels),
  // in (0, 0.5): at 0.5 the window reaches the neighbouring corners. Default 0.4; see the header
  // comment for the measured trade-off.
  double window_fraction = 0.4;
  // Gaussian pre-smoothing before either refinement, pixels (0: none, the default). It lowers
  // cornerSubPix's noise but biases both: see the header comment and bench/RESULTS.md.
  double presmooth_sigma_px = 0;
  int min_half_window = 2;  // pixels, >= 1: below 2 cornerSubPix sees too few gradients
  int max_half_window = 8;  // pixels, >= min_half_window: beyond it noise no longer averages down
  // A refined corner that moved further than this from the detector's estimate has locked on
  // something else and is dropped (pixels, > 0). SB's own error is < 1.5 px on foreshortened
  // boards (calib/1 README).
  double max_refine_shift_px = 2.0;
  // Minimum difference of the mean white and mean black square (image values 0..1, in (0, 1)).
  double min_contrast = 0.1;
  // When the fast search finds nothing, search again with findChessboardCornersSB's exhaustive
  // and accuracy flags (several times slower).
  bool exhaustive_retry = true;

  Status Validate() const;
};

// One board found in one photo.
struct BoardDetection {
  int board = -1;               // index into the boards searched
  std::vector<Vec2d> corners;   // pixels, in the board's corner order (BoardSpec)
  std::vector<uint8_t> valid;   // per corner: 1 refined and kept, 0 dropped
  // Other numberings of the same corners that show the same colours (a symmetric board, see
  // BoardSpec::Symmetry): alternatives[a][k] is the index into `corners` of board corner k.
  std::vector<std::vector<int>> alternatives;
  double contrast = 0;          // mean white - mean black square (0..1)
  double refine_shift_rms = 0;  // RMS move of the refinement (pixels)
  // Per corner, the refinement's half-window in pixels (cornerSubPix's half-window; for the
  // symmetry refinement symmetry_radius x the local square size).
  std::vector<int> half_window;
  int ValidCount() const;
};

// Loads a photo as one grey channel (RGB averaged, alpha dropped), values 0..1. Errors name the
// file (NotFound, DataLoss).
StatusOr<Image> LoadGrey(const std::filesystem::path& path);

// Searches the whole photo for the boards in `boards` (each found at most once), identifies each
// grid found (see above) and refines its corners; stops after `max_found` boards (0: no limit).
// The first search uses the largest grid every board contains (with CALIB_CB_LARGER it grows to
// whichever board it finds), then each board's own grid; found grids are masked out between
// searches. The slower exhaustive search runs only when the fast one found nothing.
// Grids that were found but refused are described in `refused` (may be null).
std::vector<BoardDetection> FindBoards(const Image& grey, const std::vector<BoardSpec>& boards,
                                       int max_found, const DetectOptions& options,
                                       std::vector<std::string>* refused);

// Searches for boards[board] inside `region` (a polygon in pixels, e.g. its predicted outline):
// the photo outside the polygon is replaced by the region's mean grey. With `predicted` corners
// (board order), the found corners must lie within a third of a square of them, and the prediction
// picks the numbering of a symmetric board (no alternatives then). nullopt when not found;
// `why` (may be null) then says why.
std::optional<BoardDetection> FindBoardInRegion(const Image& grey,
                                                const std::vector<BoardSpec>& boards, int board,
                                                const std::vector<Vec2d>& region,
                                                const std::vector<Vec2d>* predicted,
                                                const DetectOptions& options, std::string* why);

// Refines `corners` (board order, pixels) in place with options.refiner; corners that cannot be
// refined (window outside the photo, no convergence) or move more than max_refine_shift_px are
// marked 0 in `valid` and keep their start.
void RefineCorners(const Image& grey, const BoardSpec& board, const DetectOptions& options,
                   std::vector<Vec2d>* corners, std::vector<uint8_t>* valid,
                   std::vector<int>* half_window, double* shift_rms);

// The board's outline in board coordinates (squares from inner corner (0,0)), expanded by
// `margin_fraction` of its declared margin (0: the squares' outer edge): 4 points, clockwise.
std::vector<Vec2d> BoardOutline(const BoardSpec& board, double margin_fraction);

}  // namespace reflcap::calib
