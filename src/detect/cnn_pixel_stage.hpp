#pragma once
// A small fully-convolutional network (U-Net: `levels` poolings, 3x3
// convolutions, BatchNorm, ReLU, nearest upsampling with skip connections,
// 1x1 logit head) that maps the bands of a cell grid to a per-cell building
// probability: the alternative pixel stage (pixel_classifier.hpp, kind
// "cnn"). libtorch (CPU) is used only inside cnn_pixel_stage.cpp; this
// header is plain C++. Pure algorithm; no GDAL.
//
// Determinism: the weights are initialised from our own counter-based RNG
// (never torch's generator), crops and augmentations are drawn from it too,
// and every torch computation runs on ONE intra-op thread (set per calling
// thread), so the same data and options give the same weight bytes whatever
// the thread count. Prediction cuts the grid into fixed tiles (CnnTiling:
// up to kept_cells x kept_cells cells plus a 32-cell margin) computed one
// per task: any thread count gives the same map. Training's maps (the
// cross-validation's out-of-fold maps) use kCnnTrainingTiling, applied
// models kCnnDetectionTiling (larger tiles: less margin work per kept cell).
// With test-time augmentation (CnnOptions::tta 4 or 8) each tile is
// predicted under flips (and transposes), mapped back, and each cell's
// probabilities are sorted before they are summed, so the mean does not
// depend on the order of the transforms: a grid that is exactly one tile
// (unclipped: kept_cells square; clipped: sides plus 64 multiples of
// 2^levels), flipped (or, with 8, transposed), gives exactly the moved map.
#include <cstdint>
#include <string>
#include <vector>

namespace cityforge::detect {

/// The network and its training.
struct CnnOptions {
    int base_channels = 8;       ///< channels at full resolution (doubled per level, at most 4x)
    int levels = 3;              ///< poolings (1..4); crops must be divisible by 2^levels
    int crop_cells = 64;         ///< training crop side, cells (square; random flips and rot90)
    int batch = 8;               ///< crops per step
    int steps = 1500;            ///< optimisation steps (Adam)
    double learning_rate = 0.003;  ///< Adam step size (halved at 60 % and again at 85 % of the steps)
    uint64_t seed = 1;           ///< weight initialisation, crops and augmentations
    /// Test-time augmentation at prediction (training is unchanged): 1 = none;
    /// 4 = the mean probability under identity, left-right flip, up-down
    /// flip and rot180; 8 = under the 8 dihedral transforms (these plus
    /// the transposes). Costs that many forward passes.
    int tta = 1;
    void validate() const;
};

/// How predict_cnn cuts a grid into prediction tiles. Tile k keeps the
/// cells [kx * kept_cells, (kx + 1) * kept_cells) in each axis (clipped to
/// the grid) and sees a 32-cell margin around them; cells outside the grid
/// are 0. Every tile's place and size depend on the grid's size alone,
/// never on the thread count.
struct CnnTiling {
    int kept_cells = 128;  ///< kept cells per tile side; a multiple of 16 in [16, 1024]
    /// false: every tile is (kept_cells + 64) cells square, an edge tile
    /// padded with zeros; true: an edge tile ends a margin past its last kept
    /// cell, rounded up to a multiple of 2^levels (less work, other values
    /// in the last ~40 cells of the grid).
    bool clip_edges = false;
    void validate() const;
};

/// The tiling of maps made in training (the cross-validation's out-of-fold
/// maps, which the segment stage learns from): 128-cell tiles, unclipped.
/// Shipped models' bytes and CV figures depend on it; do not change it.
inline constexpr CnnTiling kCnnTrainingTiling{128, false};

/// The tiling of an applied model (footprints, run, bench_detect): 256-cell
/// tiles, edge tiles clipped. Its margins cost 1.5x the kept cells' work
/// rather than 2.25x; maps differ from training's tiling only within about
/// 40 cells of a 128-cell tile boundary that is not a 256-cell one, and of
/// the grid's far edges (README "Test-time augmentation").
inline constexpr CnnTiling kCnnDetectionTiling{256, true};

/// One training grid, planar: `input` = channels x height x width values
/// (about zero-mean, unit scale; the pixel stage gives cells without data
/// the band's mean, as the filter bank does), `target` = per
/// cell building share 0..1, `weight` = per cell loss weight (0 = ignored:
/// no data, or a held-out fold).
struct CnnGrid {
    int width = 0, height = 0;
    std::vector<float> input, target, weight;
};

/// Trains the network on `grids` (each with `channels` input channels) and
/// returns its weights: "CFCNN1", the tensor count, then per tensor its
/// rank, dimensions and little-endian float32 values, in the network's
/// fixed parameter/buffer order. Runs on the calling thread only.
std::vector<uint8_t> train_cnn(const std::vector<const CnnGrid*>& grids, int channels, const CnnOptions& options);

/// Building probability per cell (width x height, row-major) of a planar
/// `input` grid (channels x height x width) from weights of train_cnn,
/// averaged over `options.tta` transforms of each tile of `tiling`.
/// Tiles run in parallel (TBB); the values do not depend on the thread count.
std::vector<float> predict_cnn(const std::vector<uint8_t>& weights, const std::vector<float>& input, int width, int height, int channels,
                               const CnnOptions& options, const CnnTiling& tiling);

/// Throws Error naming `subject` unless `weights` is a complete weight blob
/// of the network of `options` with `channels` inputs (count, shapes,
/// length, finite values).
void check_cnn_weights(const std::vector<uint8_t>& weights, int channels, const CnnOptions& options, const std::string& subject);

}  // namespace cityforge::detect
