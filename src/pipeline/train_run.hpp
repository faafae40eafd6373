#pragma once
// `cityforge train`: a building detector learned from labelled footprints on
// our segmentation (src/detect), with a spatial k-fold cross-validation that
// measures it the way `footprints` + `audit footprints` would (object F1 at
// IoU 0.5 of the fitted outlines) and at segment level; and the image input
// shared with `footprints --detector model`.
#include <string>
#include <vector>

#include "cloud/cloud_rasters.hpp"
#include "core/progress.hpp"
#include "crs/crs.hpp"
#include "detect/detector.hpp"
#include "footprint/building_mask.hpp"

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

/// Building pixels and components from a model on one image (used by
/// `footprints --detector model` and by the cross-validation).
BuildingMask detect_building_mask(const detect::DetectorModel& model, const DetectionImage& image, int threads = 0,
                                  const Progress& progress = {});

/// The model `footprints` uses when none is given: models/default_<bands>.cfdet
/// beside the sources (CITYFORGE_MODELS_DIR overrides the folder).
std::string default_model_path(const detect::BandLayout& layout);

struct TrainOptions {
    std::vector<std::string> orthos;  ///< training images (any CRS GDAL reads)
    /// Labels: one per ortho or one for all; any OGR polygon layer in any CRS
    /// (reprojected to each image), or a mask raster on the ortho's grid (> 0 = building).
    std::vector<std::string> labels;
    std::string label_layer;          ///< empty = first layer
    int nir_band = 0;                 ///< 1-based NIR band of every ortho (0 = none)
    detect::DetectorOptions detector;
    int folds = 5;                    ///< spatial k-fold cross-validation (0 = none)
    double fold_block_m = 60.0;       ///< fold blocks, metres a side
    /// Candidate thresholds; the one with the best pooled object F1 in the
    /// cross-validation goes into the model (empty or no CV: detector.threshold).
    std::vector<double> thresholds{0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85};
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
