#pragma once
// Raster regions -> polygons exactly along pixel edges (holes kept), and
// outline simplification. No GDAL: pixel geometry goes to map coordinates
// through the raster's GeoTransform.
#include <cstdint>
#include <vector>

#include "core/geo_transform.hpp"
#include "core/geometry.hpp"
#include "core/image.hpp"

namespace cityforge {

/// The polygons of one region: its 4-connected parts, each with its holes.
/// Exterior rings counter-clockwise, holes clockwise (in map coordinates with
/// y up); only corner vertices are kept (collinear pixel-edge vertices dropped).
/// Rings may touch at single vertices (diagonal pixels) but never cross.
std::vector<Polygon> vectorize_region(const Image<uint32_t>& labels, uint32_t region, const GeoTransform& transform);

/// Every region 1..max label of `labels` at once (index = label; entry 0 and
/// absent labels are empty). One pass over the raster plus the boundaries.
std::vector<std::vector<Polygon>> vectorize_all(const Image<uint32_t>& labels, const GeoTransform& transform);

/// `polygon` with its exterior ring made simple where it passes one vertex
/// twice: a background pocket open to the outside only diagonally, which the
/// 4-connected outline enters and leaves through that vertex (an exterior
/// touching itself is not a valid polygon, and a hole touching the exterior
/// would make the extruded walls share an edge). The pocket is filled: the
/// ring splits into loops, and when exactly one has the exterior's
/// orientation (the others being pockets) it stays. Holes are kept.
/// Unchanged when no vertex repeats or when two loops have the exterior's
/// orientation (pieces touching at a corner: nothing is dropped).
Polygon fill_pinched_pockets(const Polygon& polygon);

/// Douglas–Peucker simplification of every ring with `tolerance` (CRS units).
/// A ring that would collapse below 3 vertices is kept as it was.
Polygon simplify_polygon(const Polygon& polygon, double tolerance);

}  // namespace cityforge
