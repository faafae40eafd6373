#pragma once
// `cityforge segment`: read a georeferenced raster, resample it to the working
// GSD, over-segment it (watershed) and merge regions through a list of scales;
// write one UInt32 label GeoTIFF per level on the input's grid and a report.
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/progress.hpp"
#include "segment/region_merging.hpp"
#include "segment/watershed.hpp"

namespace cityforge {

struct SegmentOptions {
    WatershedOptions watershed;
    RegionMergingOptions merging;
    /// Working ground sample distance in metres: inputs at another GSD are
    /// resampled (average when shrinking, bilinear when enlarging) so that
    /// scale parameters mean the same on every input. 0 = keep the input GSD.
    double working_gsd_m = 0.5;
    /// 1-based bands to use (empty = all).
    std::vector<int> bands;
    /// Accept rasters without georeferencing (pixel coordinates, GSD 1 m).
    bool allow_pixel_coordinates = false;
    /// Throws Error naming the option on bad values that need no input to check.
    void validate() const;
};

/// Reads a segment config (JSON object): keys scales, strategy, color_weight,
/// compactness, band_weights, h_minima, smoothing_sigma_px, working_gsd_m,
/// bands. Unknown keys are refused with an Error naming `source` and the key.
SegmentOptions segment_options_from_json(const nlohmann::json& j, const std::string& source);

struct SegmentLevelReport {
    double scale = 0.0;
    uint32_t regions_before = 0;
    uint32_t regions_after = 0;
    uint64_t initial_queue_length = 0;
    uint64_t merges = 0;
    uint64_t queue_pushes = 0;
    double seconds = 0.0;
    std::string labels_path;
};

struct SegmentReport {
    std::string input_path;
    std::string crs;                 ///< label of the input CRS
    int input_width = 0, input_height = 0;
    double input_gsd_m = 0.0;
    int working_width = 0, working_height = 0;
    double working_gsd_m = 0.0;
    uint32_t oversegmentation_regions = 0;
    double watershed_seconds = 0.0;
    double read_seconds = 0.0;
    std::string oversegmentation_path;
    std::string hierarchy_path;
    std::string strategy;
    std::vector<SegmentLevelReport> levels;
};

/// Runs the segmentation and writes into `out_dir`: oversegmentation.tif,
/// segments_scale_<S>.tif per scale, hierarchy.json (parent of every region
/// at the next level) and segment_report.json. Throws Error naming the file
/// or option on bad input; writes nothing before the input has been checked.
SegmentReport segment_raster(const std::string& raster_path, const std::string& out_dir, const SegmentOptions& options,
                             const Progress& progress = {});

nlohmann::json to_json(const SegmentReport& report);

/// The label raster of one scale level in a `cityforge segment` folder:
/// DIR/segments_scale_<S>.tif (S without trailing zeros, e.g. 30 or 12.5).
std::string segment_level_path(const std::string& out_dir, double scale);

}  // namespace cityforge
