#pragma once
// Footprint accuracy: one-to-one matching of predicted and reference
// polygons at an IoU threshold (the SpaceNet rule: greedy by IoU), with
// precision, recall, F1, mean IoU and area errors of the matches. Planar, in
// the polygons' shared CRS (callers reproject first). No GDAL.
#include <cstddef>
#include <vector>

#include "core/geometry.hpp"

namespace cityforge {

struct FootprintMatch {
    std::size_t predicted = 0;  ///< index into the predicted list
    std::size_t reference = 0;  ///< index into the reference list
    double iou = 0.0;
    double area_error_pct = 0.0;  ///< (predicted - reference) / reference * 100
    double polis = 0.0;           ///< PoLiS distance, CRS units (see polis_distance)
};

struct FootprintScores {
    std::size_t true_positives = 0, predicted = 0, reference = 0;
    double precision = 0.0, recall = 0.0, f1 = 0.0;
    /// ISPRS per-object measures: completeness = recall, correctness =
    /// precision, quality = TP / (TP + FP + FN).
    double object_quality = 0.0;
    double mean_iou = 0.0;                 ///< over matches
    double mean_abs_area_error_pct = 0.0;  ///< over matches
    double mean_polis = 0.0;               ///< over matches, CRS units
    /// ISPRS per-area measures (footprints of each set assumed not to overlap):
    /// completeness = area(pred ∩ ref) / area(ref), correctness = ... / area(pred),
    /// quality = area(pred ∩ ref) / area(pred ∪ ref).
    double area_completeness = 0.0, area_correctness = 0.0, area_quality = 0.0;
    std::vector<FootprintMatch> matches;   ///< sorted by reference index
};

/// PoLiS distance (Avbelj et al. 2015) between two footprints: the mean
/// distance from the vertices of A to the boundary of B and from the vertices
/// of B to the boundary of A, averaged: 1/(2q) sum_a d(a, dB) + 1/(2r) sum_b d(b, dA).
/// All rings (holes included) count. CRS units; 0 for identical outlines.
double polis_distance(const std::vector<Polygon>& a, const std::vector<Polygon>& b);

/// Each footprint may have several parts (a multipolygon). Ties in IoU go to
/// the lower (predicted, reference) indices, so the result is deterministic.
FootprintScores match_footprints(const std::vector<std::vector<Polygon>>& predicted,
                                 const std::vector<std::vector<Polygon>>& reference, double iou_threshold = 0.5);

}  // namespace cityforge
