#pragma once
// Ortho-only building detection on merged segments: per-segment spectral and
// shape features, rule-based classification (vegetation, shadow, roads and
// shape), and the building mask that results. Pure algorithm (no GDAL).
#include <cstdint>
#include <vector>

#include "core/image.hpp"

namespace cityforge {

struct SegmentClassifierOptions {
    double gsd_m = 0.5;                  ///< pixel size, metres
    double max_vegetation_index = 0.25;  ///< ExG = (2G - R - B) / (R + G + B) above this -> vegetation (RGB only)
    int nir_band = -1;                   ///< 0-based band holding near infrared (-1 = none); red is band 0
    double max_ndvi = 0.3;               ///< with NIR: NDVI = (NIR - R) / (NIR + R) above this -> vegetation
    /// Weaker vegetation colours (crowns in shade, the true orthos of photo
    /// clouds): ExG / NDVI above these mark a pixel "possibly vegetation",
    /// which decides only together with a rough surface (ortho refinement).
    double weak_vegetation_index = 0.08;
    double weak_ndvi = 0.15;
    double min_brightness = 0.2;         ///< mean (R+G+B)/3 relative to the image's 99th percentile; darker -> shadow
    double min_area_m2 = 20.0;
    double max_area_m2 = 5000.0;
    double min_rectangularity = 0.65;    ///< area / minimum-area-rectangle area
    /// Neighbouring segments are grouped while the group's rectangularity
    /// stays within this of its least rectangular part's.
    double max_rectangularity_loss = 0.05;
    double max_elongation = 5.0;         ///< rectangle length / width above this -> road or track
    /// A group that is not rectangular is still a building (L, T, U,
    /// courtyard) when this many rectangles aligned with it cover it with at
    /// least this IoU (1 = never).
    int max_rectilinear_rectangles = 4;
    double min_rectilinear_iou = 0.9;
    void validate() const;
};

/// Features of one segment.
struct SegmentFeatures {
    double area_m2 = 0.0;
    double brightness = 0.0;        ///< 0..1 relative
    double vegetation_index = 0.0;  ///< ExG, 0 for fewer than 3 bands
    double ndvi = 0.0;              ///< NDVI, 0 without a NIR band
    bool vegetation = false;        ///< ExG or NDVI above its limit
    bool shadow = false;            ///< darker than min_brightness
    bool building = false;          ///< in a group that passed the shape rules
};

/// Pixels whose colours say vegetation: 2 = ExG above max_vegetation_index
/// with 3+ bands or NDVI above max_ndvi with a NIR band; 1 = only above the
/// weak limits (possibly vegetation); 0 = neither. Empty when the image has
/// neither colours nor NIR.
std::vector<uint8_t> vegetation_pixels(const Image<float>& image, const SegmentClassifierOptions& options);

/// Spectral features of every segment (index = label; 0 and empty labels
/// zero): area, brightness, ExG, NDVI and the vegetation and shadow flags.
std::vector<SegmentFeatures> segment_spectra(const Image<float>& image, const Image<uint32_t>& labels, uint32_t count,
                                             const SegmentClassifierOptions& options);

/// Segments are first kept or rejected on their spectra (vegetation,
/// shadow); adjacent kept segments (roof facets, shaded halves) are then
/// grouped, longest shared boundary first, while the group stays about as
/// rectangular as its parts, and the shape rules (area, rectangularity,
/// elongation) apply to the groups.
/// `image` holds the original band values (1 band: panchromatic; 3+: R, G, B
/// first); `labels` the merged segments (1..count, 0 = nodata). Returns the
/// features of every segment (index = label) and sets `building_mask`
/// (1 = building pixel).
std::vector<SegmentFeatures> classify_segments(const Image<float>& image, const Image<uint32_t>& labels, uint32_t count,
                                               const SegmentClassifierOptions& options, std::vector<uint8_t>& building_mask);

}  // namespace cityforge
