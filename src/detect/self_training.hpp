#pragma once
// Self-training of an image model for one scene from the buildings its
// heights found: where a point cloud (or nDSM) covers only part of an ortho,
// the segments inside the cloud's coverage are labelled by the cloud's
// buildings, a gradient-boosted segment classifier (the same features and
// booster as `cityforge train`) is trained on them, and the segments outside
// the coverage are classified by it. Pure algorithm; no GDAL.
#include <cstdint>
#include <string>
#include <vector>

#include "core/image.hpp"
#include "core/progress.hpp"
#include "detect/booster.hpp"
#include "detect/segment_features.hpp"

namespace cityforge::detect {

struct SelfTrainingOptions {
    bool enabled = true;
    DetectorSegmentationOptions segmentation;  ///< the scene's segmentation (as `cityforge train`'s default)
    BoosterOptions booster;                    ///< trained on one thread: same bytes for any thread count
    /// A segment is a training example when at least this share of its
    /// pixels is covered by the heights.
    double min_train_coverage = 0.95;
    /// A segment is classified by the image model when less than this share
    /// of its pixels is covered (the heights decide the others).
    double max_detect_coverage = 0.5;
    double min_label_share = 0.5;   ///< a training segment is building when this share of its pixels is a cloud building
    double threshold = 0.5;         ///< building probability of a classified segment
    /// Coverage = pixels with height data, closed (dilated, then eroded) by
    /// this radius in metres so that gaps between sparse points count as covered.
    double coverage_closing_m = 3.0;
    /// Self-training runs when at least this share of the ortho's valid
    /// pixels lies outside the coverage ...
    double min_uncovered_share = 0.02;
    /// ... and the covered segments hold at least this many building and
    /// this many non-building examples.
    std::size_t min_examples = 20;
    void validate(int bands) const;
};

/// Pixels covered by heights: `has_data` (1 = a height value) closed with a
/// square of radius `radius_px` (w x h, row-major).
std::vector<uint8_t> coverage_mask(const std::vector<uint8_t>& has_data, int w, int h, int radius_px);

struct SelfTrainingResult {
    bool trained = false;
    std::string reason;                    ///< why not trained (empty when trained)
    double uncovered_share = 0.0;          ///< share of valid pixels outside the coverage
    std::size_t training_segments = 0, building_examples = 0, classified_segments = 0, building_segments = 0;
    /// Per pixel: 1 = building by the scene's image model (only in segments
    /// it classified; never inside a building of `cloud_building`).
    std::vector<uint8_t> building;
    std::vector<uint8_t> model;            ///< the scene's booster (XGBoost UBJSON), empty when not trained
};

/// `normalised` = the ortho's bands scaled 0..255 (normalize_bands), `valid`
/// its data mask, `gsd_m` metres per pixel; `covered` = coverage_mask of the
/// heights and `cloud_building` = pixels of the buildings found from them
/// (all on the ortho's grid, w x h).
SelfTrainingResult self_train_and_detect(const Image<float>& normalised, const std::vector<uint8_t>& valid, const BandLayout& layout,
                                         double gsd_m, const std::vector<uint8_t>& covered, const std::vector<uint8_t>& cloud_building,
                                         const SelfTrainingOptions& options, const Progress& progress = {});

}  // namespace cityforge::detect
