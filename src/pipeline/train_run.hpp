#pragma once
// `cityforge train`: a building detector learned from labelled footprints on
// our segmentation (src/detect), with a spatial k-fold cross-validation that
// measures it the way `footprints` + `audit footprints` would (object F1 at
// IoU 0.5 of the fitted outlines) and at segment level; and the image input
// shared with `footprints --detector model`.
#include <string>
#include <utility>
#include <vector>

#include "cloud/cloud_rasters.hpp"
#include "core/progress.hpp"
#include "crs/crs.hpp"
#include "detect/detector.hpp"
#include "footprint/building_mask.hpp"
#include "raster/raster.hpp"

namespace cityforge {

/// An ortho read for detection: colour bands (an alpha band is a mask, not
/// a colour), normalised 0..255 per band, and the true ground GSD.
struct DetectionImage {
    std::string path;
    GridSpec grid;
    CrsInfo crs;
    Image<float> normalised;
    std::vector<uint8_t> valid;  ///< 0 = nodata or alpha 0
    detect::BandLayout layout;
    double gsd_m = 0.0;          ///< ground size of a pixel at the centre, metres (geodesic for any CRS)
    int alpha_band = 0;          ///< 1-based band used as a mask (0 = none)
};
/// `nir_band` = 1-based band of near infrared (0 = none).
DetectionImage read_detection_image(const std::string& path, int nir_band = 0);
/// The same from bands already read: band k of `image` holds the 1-based
/// band `source_bands[k]` of the raster `info` describes (as read, e.g.
/// warped onto a working CRS); `valid` = the colour bands' data mask.
DetectionImage detection_image_from(const Image<float>& image, const std::vector<int>& source_bands, const std::vector<uint8_t>& valid,
                                    const RasterInfo& info, int nir_band, const std::string& path);

/// Heights above ground on the detection image's grid, metres (NaN = no
/// data): an nDSM raster aligned with the image (`ndsm_path`) or a point
/// cloud rasterised on it (`cloud_path`, its CRS overridden by `cloud_crs`).
Image<float> heights_on_image_grid(const DetectionImage& image, const std::string& ndsm_path, const std::string& cloud_path,
                                   const std::string& cloud_crs = {});
/// Appends the heights as the image's last band, 0..kNdsmFullScaleM metres
/// -> 0..255 (NaN = 0), and records it in the layout (ndsm_band).
void add_ndsm_band(DetectionImage& image, const Image<float>& heights_m);

/// Building pixels and components from a model on one image (used by
/// `footprints --detector model` and by the cross-validation).
BuildingMask detect_building_mask(const detect::DetectorModel& model, const DetectionImage& image, int threads = 0,
                                  const Progress& progress = {});

/// Smallest and largest GSD (metres) of the images a model was trained on
/// (its header's training sources); {0, 0} when none is recorded.
std::pair<double, double> training_gsd_range_m(const detect::DetectorModel& model);

/// How far (as a factor) beyond its training GSD range a default model is
/// still chosen for an image.
constexpr double kDefaultModelGsdReach = 4.0;

/// The model `footprints` uses when none is given, for an image of this band
/// layout and ground GSD: among models/default_pan*.cfdet (1 band) or
/// models/default_rgb*.cfdet (3 colours) beside the sources
/// (CITYFORGE_MODELS_DIR overrides the folder), the one whose training GSD
/// range is nearest the image's GSD on a log scale (0 inside the range; ties:
/// the first by file name; a model without recorded GSDs fits any). Throws
/// naming --model when there is none for the layout, or when the nearest range
/// is more than kDefaultModelGsdReach times finer or coarser than the image.
std::string default_model_path(const detect::BandLayout& layout, double gsd_m);

struct TrainOptions {
    std::vector<std::string> orthos;  ///< training images (any CRS GDAL reads)
    /// Labels: one per ortho or one for all; any OGR polygon layer in any CRS
    /// (reprojected to each image), or a mask raster on the ortho's grid (> 0 = building).
    std::vector<std::string> labels;
    std::string label_layer;          ///< empty = first layer
    /// Heights as one more band (the model then needs them when applied):
    /// nDSM rasters aligned with the orthos, or point clouds; one per ortho.
    std::vector<std::string> ndsms, clouds;
    std::string cloud_crs;            ///< overrides the clouds' CRS
    int nir_band = 0;                 ///< 1-based NIR band of every ortho (0 = none)
    detect::DetectorOptions detector;
    int folds = 5;                    ///< spatial k-fold cross-validation (0 = none)
    double fold_block_m = 60.0;       ///< fold blocks, metres a side
    /// Candidate thresholds; the one with the best pooled object F1 in the
    /// cross-validation goes into the model (empty or no CV: detector.threshold).
    std::vector<double> thresholds{0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85};
    /// Candidate DetectorOptions::object_split_level values, chosen with the
    /// threshold by the cross-validation (levels beyond the context scales
    /// are skipped; empty or no CV: detector.object_split_level).
    std::vector<int> split_levels{0, 1, 2};
    /// Candidate DetectorOptions::merge_threshold values (buildings grouped
    /// by the pair classifier, segment_merge.hpp), tried with every threshold
    /// against the split levels; empty = no pair classifier is trained.
    std::vector<double> merge_thresholds{0.5, 0.6, 0.7, 0.8, 0.9};
    /// Candidate neck splits (DetectorOptions::neck_split_m, metres), tried
    /// by the cross-validation after the grouping (empty = never split).
    std::vector<double> neck_split_candidates_m{};
    /// Non-empty: the cross-validation's out-of-fold result of the chosen
    /// options is written there per training image (<ortho stem>_cv.json:
    /// predicted and reference footprints in pixel space, x = column,
    /// y = -row; <stem>_cv_map.f32: the out-of-fold pixel-stage map, w x h
    /// row-major float32; <stem>_cv_core.f32: the core CNN's, when trained;
    /// <stem>_cv_truth.u8: the label mask; <stem>_cv_fold.u8: the fold of
    /// each pixel), for error analysis. Needs folds >= 2; a folder that is
    /// not empty is refused unless the command may overwrite.
    std::string cv_out_dir;
    /// Candidate InstanceOptions::core_threshold values (instance separation
    /// from the core CNN, detector.instance), tried by the cross-validation
    /// after the neck split; empty = no core CNN is trained.
    std::vector<double> core_threshold_candidates{};
    void validate() const;
};

struct DetectionScores {
    std::size_t tp = 0, predicted = 0, reference = 0;
    double precision = 0.0, recall = 0.0, f1 = 0.0;
    void add(const DetectionScores& o);
    void finish();
};

struct FoldReport {
    int fold = 0;
    std::size_t train_segments = 0, test_segments = 0;
    DetectionScores objects;   ///< footprints at IoU 0.5 (recursive rectangle fits, as `footprints` writes)
    DetectionScores segments;  ///< segment level, area-weighted (pixels of segments)
};

struct TrainReport {
    std::size_t images = 0, segments = 0, building_segments = 0, reference_buildings = 0, features = 0;
    std::string bands;
    std::vector<FoldReport> folds;
    DetectionScores pooled_objects, pooled_segments;
    std::vector<std::pair<std::string, DetectionScores>> per_image;  ///< pooled object scores per ortho
    double threshold = 0.5;
    int object_split_level = 0;
    double merge_threshold = 0.0;  ///< chosen; 0 = the split level groups buildings
    std::string fingerprint;
    std::size_t model_bytes = 0;
    double seconds = 0.0;
};

/// Trains and writes the model to `out_path` (not overwritten unless
/// `overwrite`). Throws Error naming the file for unreadable inputs, labels
/// that do not overlap an image, images with different bands, or no
/// building among the training segments.
TrainReport run_train(const std::string& out_path, const TrainOptions& options, bool overwrite = false, const Progress& progress = {});

}  // namespace cityforge
