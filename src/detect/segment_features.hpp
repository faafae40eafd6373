#pragma once
// Per-segment features for learned building detection, computed on our own
// segmentation (watershed + heap-queue Baatz–Schäpe merging at several
// scales): band statistics for any band count, texture (gradients, edge
// density, orientation coherence, a local binary pattern histogram), shape
// (area in m², compactness, rectangularity, elongation), multi-scale features
// of the coarser regions that contain each segment, and context (neighbour
// contrast, adjacent dark segments by side, neighbouring vegetation).
// Pure algorithm: pixel units in, metres from the caller's GSD; no GDAL.
#include <cstdint>
#include <string>
#include <vector>

#include "core/image.hpp"
#include "core/progress.hpp"
#include "segment/watershed.hpp"

namespace cityforge::detect {

/// How a scene is segmented for detection. The first scale gives the
/// segments that are classified; the further (larger) scales give the
/// context regions that contain them. Merging costs are in the units of the
/// 0..255-normalised bands (normalize_bands), so they mean the same for Byte
/// and UInt16 images.
struct DetectorSegmentationOptions {
    WatershedOptions watershed;                 ///< over-segmentation (h_minima in normalised gradient units)
    std::vector<double> scales{30.0, 60.0, 120.0};  ///< strictly increasing, > 0
    double color_weight = 0.9;                  ///< Baatz–Schäpe colour weight (shape = 1 - this)
    /// > 0: the scales hold at this GSD (metres) and are scaled by
    /// reference_gsd_m / gsd for an image of another GSD, so segments keep
    /// their ground size (a merge cost grows with the pixel count); 0 = the
    /// scales as given at any GSD.
    double reference_gsd_m = 0.0;
    void validate(int bands) const;
    /// The merging scales applied to an image of `gsd_m` metres: `scales`
    /// times reference_gsd_m / gsd_m when reference_gsd_m > 0, else as given.
    std::vector<double> scales_at(double gsd_m) const;
};

/// The classified segments and the context regions that contain them.
struct SceneSegments {
    Image<uint32_t> labels;  ///< classified segments 1..count per pixel, 0 = no data
    uint32_t count = 0;
    /// context[l][k] = label at scale l+1 of segment k (index 0 unused);
    /// context_labels[l] the label raster of that scale.
    std::vector<std::vector<uint32_t>> context;
    std::vector<Image<uint32_t>> context_labels;
    std::vector<uint32_t> context_counts;
};

/// Watershed over-segmentation of `normalised` (bands scaled 0..255),
/// then one merge sequence through every scale. `gsd_m` = the image's
/// ground sample distance, metres (used with options.reference_gsd_m).
SceneSegments segment_scene(const Image<float>& normalised, const std::vector<uint8_t>& valid,
                            const DetectorSegmentationOptions& options, const Progress& progress = {}, double gsd_m = 0.0);

/// Map-guided first segments: every 4-connected piece of a segment whose
/// pixels have `map` (per pixel, the labels' size; a building probability
/// in 0..1) at or above `threshold` becomes a segment of its own (label
/// count+1, ... in raster order of the pieces' first pixels, same context
/// regions as the segment it came from) when it holds at least
/// `min_pixels` pixels and leaves at least `min_pixels` to the segment; the
/// rest keeps its label. A segment entirely above or below the threshold
/// is unchanged. Splits a segment that straddles a small roof and its yard
/// along the map's level set. Returns how many segments were added.
std::size_t split_segments_by_map(SceneSegments& segments, const std::vector<float>& map, double threshold, std::size_t min_pixels);

/// Which bands the image holds: colour bands first (R, G, B when 3+), then
/// optional near infrared; `nir_band` is its 0-based index or -1. An nDSM
/// band (heights above ground, 0..20 m scaled to 0..255, add_ndsm_band)
/// comes last; `ndsm_band` is its index or -1.
struct BandLayout {
    int bands = 0;
    int nir_band = -1;
    int ndsm_band = -1;
};

/// Heights above ground in metres (NaN = no data, counted as ground) ->
/// 0..255 on a fixed scale of 0..`full_scale_m` (the same for every image).
constexpr double kNdsmFullScaleM = 20.0;

/// Feature names in column order for a layout and a number of context
/// scales; `pixel_map` adds the features of a pixel building-probability map
/// (pixel_classifier.hpp): its mean, spread and percentiles per segment, the
/// neighbours' contrast and the context regions' means.
std::vector<std::string> feature_names(const BandLayout& layout, int context_levels, bool pixel_map = false);

/// Row-major features: row k-1 = segment k.
struct FeatureMatrix {
    std::size_t rows = 0, cols = 0;
    std::vector<float> values;
    std::vector<double> centroid_col, centroid_row;  ///< per row, pixels
    std::vector<uint32_t> pixel_count;               ///< per row
};

/// Features of every segment. `normalised` = the bands scaled 0..255 (as
/// segmented); `gsd_m` = ground size of a pixel, metres (areas and lengths
/// are computed in metres so a model carries across resolutions).
/// `pixel_probability` (w x h, 0..1, or null) adds the pixel-map features.
FeatureMatrix segment_features(const Image<float>& normalised, const std::vector<uint8_t>& valid, const SceneSegments& segments,
                               const BandLayout& layout, double gsd_m, const std::vector<float>* pixel_probability = nullptr);

/// Share of each segment's pixels that are building in `truth` (1 = building,
/// same size as the labels); index 0 unused.
std::vector<float> building_share(const SceneSegments& segments, const std::vector<uint8_t>& truth);

}  // namespace cityforge::detect
