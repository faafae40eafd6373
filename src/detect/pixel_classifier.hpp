#pragma once
// Pixel-level building probability (ilastik-style): a filter bank per pixel
// (Gaussian smoothings per band, gradient magnitude, Hessian and
// structure-tensor eigenvalues and local standard deviation of brightness
// at several scales in metres, colour ratios) on a working grid of cells
// (the image box-averaged to about `cell_m`), classified by gradient-boosted
// trees trained on sampled cells. The map (upsampled to the image grid)
// becomes per-segment features (segment_features.hpp), so buildings smaller
// or darker than the segment statistics show are still seen. The
// alternative kind "cnn" maps the box-averaged bands of the same cells with a
// small convolutional network (cnn_pixel_stage.hpp) under the same contract.
// Pure algorithm; no GDAL.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/image.hpp"
#include "core/progress.hpp"
#include "detect/booster.hpp"
#include "detect/cnn_pixel_stage.hpp"
#include "detect/label_raster.hpp"
#include "detect/segment_features.hpp"

namespace cityforge::detect {

/// What computes the pixel stage's map.
enum class PixelStageKind {
    boosted,  ///< filter bank + gradient-boosted trees (XGBoost model)
    cnn,      ///< small U-Net on the cell bands (CFCNN1 weights, cnn_pixel_stage.hpp)
    both,     ///< the mean of the two maps (both models, packed by pack_pixel_models)
};
/// "boosted" / "cnn" / "both"; parse_pixel_stage_kind throws Error on another name.
std::string to_string(PixelStageKind kind);
PixelStageKind parse_pixel_stage_kind(const std::string& name);

/// How the pixel stage is computed and trained.
struct PixelClassifierOptions {
    bool enabled = true;
    PixelStageKind kind = PixelStageKind::boosted;
    /// Working cell, metres: the image is box-averaged by an integer factor
    /// max(1, round(cell_m / gsd)) before filtering (the map is upsampled
    /// back), so a model carries across resolutions and 4000 x 4000 px
    /// tiles stay fast.
    double cell_m = 0.8;
    std::vector<double> sigmas_m{0.7, 1.5, 3.0};  ///< filter scales, metres (strictly increasing, > 0)
    std::size_t samples_per_image = 30000;         ///< training cells per image (half building where there are enough)
    BoosterOptions booster{60, 6, 0.2, 0.8, 0.8, 1.0, 1.0, 1};  ///< kind boosted
    CnnOptions cnn;                                               ///< kind cnn
    void validate() const;
};

/// Box-averaging factor of an image of ground sample distance `gsd_m`.
int pixel_cell_factor(double gsd_m, const PixelClassifierOptions& options);

/// Filter names in column order.
std::vector<std::string> pixel_feature_names(const BandLayout& layout, const PixelClassifierOptions& options);

/// The filter bank on the working grid: one band per pixel_feature_names
/// entry, ceil(w / f) x ceil(h / f) cells (f = pixel_cell_factor);
/// `cell_valid` (out, optional) = 1 where the cell holds a valid pixel.
/// `normalised` = bands scaled 0..255 (normalize_bands).
Image<float> pixel_feature_stack(const Image<float>& normalised, const std::vector<uint8_t>& valid, const BandLayout& layout, double gsd_m,
                                 const PixelClassifierOptions& options, std::vector<uint8_t>* cell_valid = nullptr);

/// The pixel model of kind both: "CFPIX2", then the boosted and the CNN
/// model, each length-prefixed (u64 little-endian). unpack throws Error
/// naming `subject` on a truncated or corrupt pack.
std::vector<uint8_t> pack_pixel_models(const std::vector<uint8_t>& boosted, const std::vector<uint8_t>& cnn);
std::pair<std::vector<uint8_t>, std::vector<uint8_t>> unpack_pixel_models(const std::vector<uint8_t>& pack, const std::string& subject);

/// Building probability per image pixel (w x h, row-major; 0 outside
/// `valid`) from a pixel model (XGBoost UBJSON, CNN weights for kind cnn,
/// a pack of both for kind both). Any thread count gives the same values.
/// `threads`: 0 = all. `cnn_tiling` = the CNN's prediction tiles (kinds cnn
/// and both; no default, so that no caller changes a model's maps unawares):
/// kCnnDetectionTiling where a model is applied, kCnnTrainingTiling for maps
/// made in training (the shipped models' CV figures and bytes depend on it).
std::vector<float> pixel_probability(const std::vector<uint8_t>& model, const Image<float>& normalised, const std::vector<uint8_t>& valid,
                                     const BandLayout& layout, double gsd_m, const PixelClassifierOptions& options, int threads,
                                     const CnnTiling& cnn_tiling);

/// One labelled training image of the pixel stage.
struct PixelTrainingImage {
    const Image<float>* normalised = nullptr;  ///< bands scaled 0..255
    const std::vector<uint8_t>* valid = nullptr;
    const std::vector<uint8_t>* truth = nullptr;  ///< 1 = building pixel
    double gsd_m = 0.0;
};

/// The trained pixel stage: the model on every sample, and (with folds) the
/// out-of-fold probability of every pixel of every image (each pixel
/// predicted by the model trained without its fold's blocks).
struct PixelStage {
    std::vector<uint8_t> model;  ///< XGBoost UBJSON (boosted), CFCNN1 weights (cnn) or pack_pixel_models (both)
    std::vector<std::vector<float>> out_of_fold;  ///< per image, w x h (empty without folds)
};
/// `folds` = the cross-validation blocks (pixel units of each image) or
/// null; `fold_count` their number. Each model trains on one thread (the
/// fold models in parallel: same bytes for any thread count); prediction
/// may use `threads`.
PixelStage train_pixel_stage(const std::vector<PixelTrainingImage>& images, const BandLayout& layout, const PixelClassifierOptions& options,
                             const FoldBlocks* folds, int fold_count, int threads = 0, const Progress& progress = {});

}  // namespace cityforge::detect
