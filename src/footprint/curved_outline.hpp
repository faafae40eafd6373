#pragma once
// Round and many-sided buildings (towers, rotundas, silos, gasometers):
// rectangle fits and edge regularisation turn their outlines into
// staircases. This tells a curved outline from a rectilinear one and gives a
// smooth outline for it. Planar, in the polygon's CRS units (projected CRS
// expected); no GDAL.
#include <optional>

#include "core/geometry.hpp"

namespace cityforge {

struct CurvedOutlineOptions {
    /// An outline counts as curved when less than this share of its smoothed
    /// perimeter runs within `axis_tolerance_deg` of its rectangle's two axes
    /// (rectilinear buildings: 0.9-1; a one-corner cut: about 0.8; circles
    /// and octagons: 0.2-0.5).
    double max_rectilinear_share = 0.6;
    double axis_tolerance_deg = 12.0;
    /// Douglas-Peucker tolerance of the smooth outline, in pixels.
    double simplify_px = 0.35;
    /// Tolerance of the coarser outline the share is measured on, in pixels
    /// (a slanted straight edge's staircase leaves a zigzag of midpoints
    /// that the fine tolerance keeps).
    double classify_simplify_px = 1.0;
    /// and is convex (area over its convex hull's at least this: real
    /// outlines with bays and wings are not round) ...
    double min_solidity = 0.9;
    /// ... and fills its minimum-area rectangle less than a rectangle does
    /// (circle pi/4 = 0.785, hexagon 0.75; ragged rectangles 0.83-0.95).
    double max_rectangularity = 0.82;
    void validate() const;  ///< throws Error naming the option
};

/// The pixel outline `pixels` (rings along pixel edges, `pixel_size` CRS
/// units) smoothed: each ring's edges cut into pixel steps, the ring through
/// the steps' midpoints, simplified with Douglas-Peucker (`simplify_px`).
/// Straight runs stay straight; each staircase corner loses half a pixel.
Polygon smooth_pixel_outline(const Polygon& pixels, double pixel_size, double simplify_px);

/// The smoothed outline of `pixels` (pixel edges of `pixel_size` CRS units)
/// when the building is round or many-sided (see CurvedOutlineOptions: few
/// edges along its rectangle's axes, convex, not filling its rectangle) and
/// the smoothed outline is valid; nothing otherwise.
std::optional<Polygon> curved_outline(const Polygon& pixels, double pixel_size, const CurvedOutlineOptions& options);

/// Share (0-1) of the outer ring's perimeter whose edges run within
/// `tolerance_deg` of `orientation_deg` or of its perpendicular (degrees,
/// counter-clockwise from east).
double rectilinear_share(const Polygon& polygon, double orientation_deg, double tolerance_deg);

}  // namespace cityforge
