#pragma once
// Orientation regularisation of building outlines: edges close to the
// dominant direction (or its perpendicular) are snapped to it, nearly
// collinear neighbours are merged, and vertices are recomputed as the
// intersections of consecutive edge lines, giving right angles and parallel
// edges. Planar, CRS units. No GDAL.
#include "core/geometry.hpp"

namespace cityforge {

/// lines: our edge-line snapping; cgal_contours: CGAL Shape_regularization
/// (regularize_closed_contour with the dominant direction and its normal).
enum class RegularizeMethod { lines, cgal_contours };

struct RegularizeOptions {
    RegularizeMethod method = RegularizeMethod::lines;
    double angle_tolerance_deg = 15.0;  ///< edges within this of 0/90 degrees to the dominant direction are snapped
    double merge_offset = 0.5;          ///< parallel consecutive edges closer than this (CRS units) are merged
    double min_edge = 0.5;              ///< shorter edges are absorbed by their neighbours (CRS units)
    /// Callers move all edges by one distance (at most this, CRS units) so the
    /// result keeps the raw outline's area (see match_area); 0 = do not.
    double match_area_max_offset = 1.0;
};

/// Regularises every ring of `polygon` to `orientation_deg` (e.g. from the
/// minimum-area rectangle). Throws Error when the result would be degenerate
/// or invalid (callers keep the raw outline and report why).
Polygon regularize_polygon(const Polygon& polygon, double orientation_deg, const RegularizeOptions& options = {});

/// The regularised fit of an outline traced along pixel edges (`traced`,
/// CRS units): its staircase straightened by Douglas–Peucker with at least
/// 1.5 pixels (`pixel_size`, CRS units) or `simplify`, edges regularised to
/// `orientation_deg`, then moved to `target_area` (see match_area) when
/// options.match_area_max_offset > 0. Throws Error like regularize_polygon.
Polygon regularised_fit(const Polygon& traced, double orientation_deg, double pixel_size, double simplify, double target_area,
                        const RegularizeOptions& options = {});

}  // namespace cityforge
