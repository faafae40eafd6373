#pragma once
// Which adjacent building segments belong to one building: features of every
// pair of 4-adjacent segments (their shared boundary, the step across it, the
// shape of their union, the pixel map along it, the merge hierarchy) for a
// learned "same building" classifier, and the grouping of building segments
// into buildings by its probabilities. Connected building segments are
// otherwise one building; touching roofs (terraces, compounds, dense
// settlements) then merge into one outline that matches no label at IoU 0.5.
// Pure algorithm: pixel units in, metres from the caller's GSD; no GDAL.
#include <cstdint>
#include <string>
#include <vector>

#include "core/image.hpp"
#include "detect/segment_features.hpp"

namespace cityforge::detect {

/// Names of the pair features in column order (for `context_levels` context
/// scales, with or without a pixel probability map).
std::vector<std::string> pair_feature_names(int context_levels, bool pixel_map);

/// Every pair of 4-adjacent segments a < b (labels of SceneSegments), in
/// increasing (a, b) order, and their features (row-major, one row per pair).
struct SegmentPairs {
    std::vector<uint32_t> a, b;
    std::size_t cols = 0;
    std::vector<float> values;
    std::size_t size() const { return a.size(); }
};

/// Pair features. `normalised` = the bands scaled 0..255 (as segmented);
/// `gsd_m` = ground size of a pixel, metres; `pixel_probability` (w x h,
/// 0..1, or null) adds the pixel-map features. Deterministic (one pass, no threads).
SegmentPairs segment_pairs(const Image<float>& normalised, const SceneSegments& segments, double gsd_m,
                           const std::vector<float>* pixel_probability = nullptr);

/// Building object of every segment (index = label): building segments
/// (`building[k]` != 0) joined through the pairs whose probability reaches
/// `threshold` carry the smallest label of their group; every other segment
/// its own label. Same result for any pair order.
std::vector<uint32_t> merge_groups(const SegmentPairs& pairs, const std::vector<float>& pair_probability, const std::vector<uint8_t>& building,
                                   double threshold);

/// Training labels of the pairs: for pairs whose two segments are building
/// (share >= `min_share`), 1 when most of both segments' labelled pixels lie in
/// the same reference building of `reference_ids` (per pixel, 0 = none), else
/// 0; other pairs -1 (not a training example).
std::vector<int8_t> pair_labels(const SegmentPairs& pairs, const SceneSegments& segments, const std::vector<float>& share,
                                const std::vector<uint32_t>& reference_ids, double min_share);

}  // namespace cityforge::detect
