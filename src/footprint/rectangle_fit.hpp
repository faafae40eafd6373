#pragma once
// Rectangle fits of building outlines and their accuracy against the raw
// polygon. Planar, in the polygon's CRS units (projected CRS expected).
#include <array>
#include <vector>

#include "core/geometry.hpp"

namespace cityforge {

/// An oriented rectangle.
struct OrientedRectangle {
    MapPoint centre;
    double length = 0.0;       ///< along the orientation, CRS units (>= width)
    double width = 0.0;        ///< across, CRS units
    double orientation_deg = 0.0;  ///< long side from east, counter-clockwise, in [0, 180)
    /// Corners counter-clockwise.
    std::array<MapPoint, 4> corners() const;
    /// Whether `p` lies inside or on the rectangle.
    bool contains(MapPoint p) const;
    Polygon polygon() const;
};

/// Convex hull (Andrew's monotone chain), counter-clockwise, no collinear points.
Ring convex_hull(const std::vector<MapPoint>& points);

/// Minimum-area bounding rectangle of the polygon's exterior (rotating
/// calipers over the convex hull's edges; ties go to the smaller angle).
/// Throws Error for a polygon with fewer than 3 distinct vertices or zero area.
OrientedRectangle minimum_area_rectangle(const Polygon& polygon);


/// Accuracy of a fitted polygon against the raw one.
struct FitAccuracy {
    double area_error_pct = 0.0;  ///< (area(fit) - area(raw)) / area(raw) * 100
    double iou = 0.0;             ///< area(fit ∩ raw) / area(fit ∪ raw)
};
FitAccuracy fit_accuracy(const Polygon& raw, const Polygon& fit);

/// Intersection over union of two polygons with holes (Boost.Geometry).
double polygon_iou(const Polygon& a, const Polygon& b);

/// Perimeter of all rings, CRS units.
double polygon_perimeter(const Polygon& p);

/// True when the polygon is valid in the OGC sense (closed, non-crossing
/// rings, holes inside the exterior), via Boost.Geometry.
bool polygon_is_valid(const Polygon& p);

/// Moves every edge of every ring by `distance` along its outward normal
/// (> 0 grows the polygon, < 0 shrinks it), keeping each edge's direction:
/// vertices are the mitred intersections of the moved edge lines, so right
/// angles stay right angles. Expects oriented rings (outer counter-clockwise,
/// holes clockwise); CRS units.
Polygon offset_edges(const Polygon& polygon, double distance);

/// Moves all edges by one common distance (at most `max_offset`) so that the
/// polygon's area becomes `target_area`: outlines traced from rasters sit on
/// the staircase's outer or inner corners, and a fit made of straight edges
/// inherits that band. Returns the input when no valid polygon within the
/// limit reaches the target (thin parts would collapse).
Polygon match_area(const Polygon& polygon, double target_area, double max_offset);

}  // namespace cityforge

namespace cityforge {

struct RecursiveFitOptions {
    double tolerance_pct = 1.0;        ///< stop when |area error| is below this
    double min_rectangle_area = 2.0;   ///< smallest rectangle added or cut, CRS units squared
    int max_rectangles = 16;           ///< cuts + additions after the first rectangle
    double cell = 0.0;                 ///< working grid cell, CRS units (0 = automatic)
    /// Final step: all edges moved by one distance (at most this, CRS units)
    /// so that the fit has the raw polygon's area; 0 = keep the grid's edges.
    double match_area_max_offset = 1.0;
};

struct RecursiveFit {
    Polygon polygon;                   ///< union/difference of rectangles aligned with the dominant direction
    double orientation_deg = 0.0;      ///< the dominant direction (of the minimum-area rectangle)
    int rectangles = 1;                ///< 1 + cuts + additions
    FitAccuracy accuracy;              ///< against the raw polygon
};

/// Recursive rectangle fitting: start from the minimum-area rectangle and cut
/// (or add) the largest rectangles aligned with its direction inside the
/// remaining difference until the area error is under the tolerance. Gives
/// L, T, U, Z and courtyard shapes with right angles.
RecursiveFit recursive_rectangle_fit(const Polygon& polygon, const RecursiveFitOptions& options = {});

}  // namespace cityforge
