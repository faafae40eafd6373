#include "footprint/regularize.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "core/error.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Shape_regularization/regularize_contours.h>

namespace cityforge {
namespace {

struct Line {
    double dx, dy;  // unit direction
    double px, py;  // a point on the line
    double length;  // supporting edge length
};

Ring regularize_ring(const Ring& ring, double theta, const RegularizeOptions& o) {
    const std::size_t n = ring.size();
    if (n < 3) throw Error("regularisation", "ring with fewer than 3 vertices");
    const double tol = o.angle_tolerance_deg * std::numbers::pi / 180.0;
    // 1. Edge lines, snapped to the dominant directions when close enough.
    std::vector<Line> lines;
    for (std::size_t i = 0; i < n; ++i) {
        const MapPoint& a = ring[i];
        const MapPoint& b = ring[(i + 1) % n];
        const double len = std::hypot(b.x - a.x, b.y - a.y);
        if (len == 0) continue;
        double phi = std::atan2(b.y - a.y, b.x - a.x);
        // Angle relative to the dominant direction, folded to (-45, 45] degrees.
        double rel = std::remainder(phi - theta, std::numbers::pi / 2);
        if (std::abs(rel) <= tol) phi -= rel;
        lines.push_back({std::cos(phi), std::sin(phi), 0.5 * (a.x + b.x), 0.5 * (a.y + b.y), len});
    }
    // Short edges (jags) are absorbed: their neighbours' lines meet instead.
    {
        std::vector<Line> kept;
        for (const Line& l : lines)
            if (l.length >= o.min_edge) kept.push_back(l);
        if (kept.size() >= 3) lines.swap(kept);
    }
    // 2. Merge consecutive (cyclic) lines that are parallel and nearly collinear,
    //    or drop short edges between them.
    bool changed = true;
    while (changed && lines.size() > 3) {
        changed = false;
        for (std::size_t i = 0; i < lines.size() && lines.size() > 3; ++i) {
            Line& a = lines[i];
            const Line& b = lines[(i + 1) % lines.size()];
            const bool parallel = std::abs(a.dx * b.dy - a.dy * b.dx) < 1e-9 && a.dx * b.dx + a.dy * b.dy > 0;
            const double offset = std::abs((b.px - a.px) * -a.dy + (b.py - a.py) * a.dx);
            if (parallel && offset < o.merge_offset) {
                const double w = a.length + b.length;
                a.px = (a.px * a.length + b.px * b.length) / w;
                a.py = (a.py * a.length + b.py * b.length) / w;
                a.length = w;
                lines.erase(lines.begin() + static_cast<std::ptrdiff_t>((i + 1) % lines.size()));
                changed = true;
            }
        }
    }
    if (lines.size() < 3) throw Error("regularisation", "outline collapsed");
    // 3. Vertices: intersections of consecutive lines; parallel neighbours
    //    (a step) get a perpendicular connector.
    Ring out;
    for (std::size_t i = 0; i < lines.size(); ++i) {
        const Line& a = lines[i];
        const Line& b = lines[(i + 1) % lines.size()];
        const double den = a.dx * b.dy - a.dy * b.dx;
        if (std::abs(den) > 1e-9) {
            const double t = ((b.px - a.px) * b.dy - (b.py - a.py) * b.dx) / den;
            out.push_back({a.px + t * a.dx, a.py + t * a.dy});
        } else {
            // Project b's point onto a and a connector from there to b's line.
            const double s = (b.px - a.px) * a.dx + (b.py - a.py) * a.dy;
            const double fx = a.px + s * a.dx, fy = a.py + s * a.dy;
            out.push_back({fx, fy});
            out.push_back({b.px, b.py});
        }
    }
    return out;
}

bool rings_cross(const Ring& r) {
    const std::size_t n = r.size();
    auto seg = [&](std::size_t i, std::size_t j) {
        const MapPoint &a = r[i], &b = r[(i + 1) % n], &c = r[j], &d = r[(j + 1) % n];
        auto orient = [](const MapPoint& p, const MapPoint& q, const MapPoint& s) { return (q.x - p.x) * (s.y - p.y) - (q.y - p.y) * (s.x - p.x); };
        const double o1 = orient(a, b, c), o2 = orient(a, b, d), o3 = orient(c, d, a), o4 = orient(c, d, b);
        return ((o1 > 0) != (o2 > 0)) && ((o3 > 0) != (o4 > 0)) && o1 != 0 && o2 != 0 && o3 != 0 && o4 != 0;
    };
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = i + 2; j < n; ++j) {
            if (i == 0 && j == n - 1) continue;
            if (seg(i, j)) return true;
        }
    return false;
}


// CGAL Shape_regularization contours: edges oriented to the dominant direction
// or its perpendicular (User_defined_directions_2), parallel consecutive edges
// closer than merge_offset made collinear.
Ring regularize_ring_cgal(const Ring& ring, double theta, const RegularizeOptions& o) {
    using K = CGAL::Exact_predicates_inexact_constructions_kernel;
    using P2 = K::Point_2;
    if (ring.size() < 3) throw Error("regularisation", "ring with fewer than 3 vertices");
    // Relative to the first vertex: map coordinates of 10^5-10^6 lose digits.
    const MapPoint origin = ring[0];
    std::vector<P2> in;
    for (const MapPoint& p : ring) in.emplace_back(p.x - origin.x, p.y - origin.y);
    // Short jags (pixel staircase steps) are dropped first: their direction is noise.
    std::vector<P2> kept;
    for (std::size_t i = 0; i < in.size(); ++i) {
        const P2& a = in[i];
        const P2& b = in[(i + 1) % in.size()];
        if (std::sqrt(CGAL::squared_distance(a, b)) >= o.min_edge || kept.empty()) kept.push_back(a);
    }
    if (kept.size() < 3) kept = in;
    const std::vector<K::Direction_2> directions{K::Direction_2(std::cos(theta), std::sin(theta)),
                                                 K::Direction_2(-std::sin(theta), std::cos(theta))};
    CGAL::Shape_regularization::Contours::User_defined_directions_2<K, std::vector<P2>> dirs(kept, true, directions);
    std::vector<P2> out;
    CGAL::Shape_regularization::Contours::regularize_closed_contour(kept, dirs, std::back_inserter(out),
                                                                    CGAL::parameters::maximum_offset(o.merge_offset));
    Ring r;
    for (const P2& p : out) r.push_back({CGAL::to_double(p.x()) + origin.x, CGAL::to_double(p.y()) + origin.y});
    return r;
}

}  // namespace

Polygon regularize_polygon(const Polygon& polygon, double orientation_deg, const RegularizeOptions& o) {
    const double theta = orientation_deg * std::numbers::pi / 180.0;
    Polygon out;
    auto ring = [&](const Ring& r) { return o.method == RegularizeMethod::cgal_contours ? regularize_ring_cgal(r, theta, o) : regularize_ring(r, theta, o); };
    out.outer = ring(polygon.outer);
    for (const Ring& h : polygon.holes) out.holes.push_back(ring(h));
    orient_polygon(out);
    if (rings_cross(out.outer)) throw Error("regularisation", "regularised outline self-intersects");
    for (const Ring& h : out.holes)
        if (rings_cross(h)) throw Error("regularisation", "regularised hole self-intersects");
    if (!polygon_is_valid(out)) throw Error("regularisation", "regularised outline is not a valid polygon");
    const double a0 = polygon_area(polygon), a1 = polygon_area(out);
    if (!(a1 > 0) || std::abs(a1 - a0) > 0.25 * a0) throw Error("regularisation", "regularised outline changed the area by more than 25 %");
    return out;
}

Polygon regularised_fit(const Polygon& traced, double orientation_deg, double pixel_size, double simplify, double target_area,
                        const RegularizeOptions& o) {
    // Pixel staircases must be straightened before edges can be snapped.
    const double straighten = std::max(simplify, 1.5 * std::abs(pixel_size));
    Polygon out = regularize_polygon(simplify_polygon(traced, straighten), orientation_deg, o);
    if (o.match_area_max_offset > 0) out = match_area(out, target_area, o.match_area_max_offset);
    return out;
}

}  // namespace cityforge
