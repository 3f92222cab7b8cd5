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
// Refinement. cornerSubPix's window must stay inside the four squares around a corner: on a
// foreshortened board a fixed 7x7 window reaches the next corners and biases the result by tenths
// of a pixel. The half-window is window_fraction x the distance to the nearest grid neighbour,
// clamped to [min_half_window, max_half_window]. On the shared cuboid photos (corners started at
// their true positions, faces with cos >= 0.35) this gives 0.060 px RMS, against 0.076 px for a
// fixed 7x7 window. Larger windows and a Gaussian pre-smoothing lower the noise further (0.3 ->
// 0.45 of the spacing: 0.071 -> 0.059 px; with a 0.8-px blur 0.050 px) but bias: lens distortion
// and perspective bend the squares around a corner, and the more of them a window sees, the more
// the corners are pulled in, by a relative scale of -1e-5 (0.3), -6e-5 (0.4), -2.2e-4 (0.45 with
// the blur) of the board's size. -2.2e-4 makes the cuboid look 0.2 mm further away than it is
// (the adjusted axis point moved by 0.14 mm); -6e-5 stays within 0.01 mm. Hence 0.4, no blur.
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

struct DetectOptions {
  // cornerSubPix half-window = window_fraction x distance to the nearest grid neighbour (pixels),
  // in (0, 0.5): at 0.5 the window reaches the neighbouring corners. Default 0.4; see the header
  // comment for the measured trade-off.
  double window_fraction = 0.4;
  // Gaussian pre-smoothing before cornerSubPix, pixels (0: none, the default). It lowers the
  // noise but biases: see the header comment.
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
  std::vector<int> half_window; // cornerSubPix half-window used per corner (pixels)
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

// Refines `corners` (board order, pixels) in place by cornerSubPix with the adaptive window;
// corners that move more than max_refine_shift_px are marked 0 in `valid`.
void RefineCorners(const Image& grey, const BoardSpec& board, const DetectOptions& options,
                   std::vector<Vec2d>* corners, std::vector<uint8_t>* valid,
                   std::vector<int>* half_window, double* shift_rms);

// The board's outline in board coordinates (squares from inner corner (0,0)), expanded by
// `margin_fraction` of its declared margin (0: the squares' outer edge): 4 points, clockwise.
std::vector<Vec2d> BoardOutline(const BoardSpec& board, double margin_fraction);

}  // namespace reflcap::calib
