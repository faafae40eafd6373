#pragma once
// Orientation regularisation of building outlines: edges close to the
// dominant direction (or its perpendicular) are snapped to it, nearly
// collinear neighbours are merged, and vertices are recomputed as the
// intersections of consecutive edge lines, giving right angles and parallel
// edges. Planar, CRS units. No GDAL.
#include "core/geometry.hpp"

namespace cityforge {

struct RegularizeOptions {
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

}  // namespace cityforge
