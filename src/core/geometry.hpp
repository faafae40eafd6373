#pragma once
// Plain planar geometry shared by all modules: rings and polygons with holes
// in map coordinates (CRS units), and the few predicates every stage needs.
#include <algorithm>
#include <cmath>
#include <vector>

#include "core/geo_transform.hpp"

namespace cityforge {

/// A polygon ring: closed implicitly (first point not repeated), CRS units.
using Ring = std::vector<MapPoint>;

/// Polygon with holes: `outer` then any number of `holes`.
struct Polygon {
    Ring outer;
    std::vector<Ring> holes;
};

/// Signed area of a ring (> 0 counter-clockwise), CRS units squared.
/// Coordinates are taken relative to the first vertex: with projected
/// coordinates of 10^5-10^6 the plain shoelace formula loses ~6 digits.
inline double signed_area(const Ring& r) {
    double a = 0.0;
    const std::size_t n = r.size();
    if (n < 3) return 0.0;
    const double ox = r[0].x, oy = r[0].y;
    for (std::size_t i = 0; i < n; ++i) {
        const MapPoint& p = r[i];
        const MapPoint& q = r[(i + 1) % n];
        a += (p.x - ox) * (q.y - oy) - (q.x - ox) * (p.y - oy);
    }
    return 0.5 * a;
}

/// Area of a polygon (outer minus holes), CRS units squared.
inline double polygon_area(const Polygon& p) {
    double a = std::abs(signed_area(p.outer));
    for (const Ring& h : p.holes) a -= std::abs(signed_area(h));
    return a;
}

/// Makes the outer ring counter-clockwise and holes clockwise (OGC/RFC 7946).
inline void orient_polygon(Polygon& p) {
    if (signed_area(p.outer) < 0) std::reverse(p.outer.begin(), p.outer.end());
    for (Ring& h : p.holes)
        if (signed_area(h) > 0) std::reverse(h.begin(), h.end());
}

/// Even-odd point-in-ring test (points exactly on an edge may go either way).
inline bool point_in_ring(const Ring& r, double x, double y) {
    bool inside = false;
    const std::size_t n = r.size();
    for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
        const MapPoint& a = r[i];
        const MapPoint& b = r[j];
        if ((a.y > y) != (b.y > y) && x < (b.x - a.x) * (y - a.y) / (b.y - a.y) + a.x) inside = !inside;
    }
    return inside;
}

/// Inside the outer ring and outside every hole.
inline bool point_in_polygon(const Polygon& p, double x, double y) {
    if (!point_in_ring(p.outer, x, y)) return false;
    for (const Ring& h : p.holes)
        if (point_in_ring(h, x, y)) return false;
    return true;
}

/// Distance from (x, y) to the nearest edge of any ring of the polygon.
inline double distance_to_boundary(const Polygon& p, double x, double y) {
    double best = INFINITY;
    auto ring = [&](const Ring& r) {
        const std::size_t n = r.size();
        for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
            const double ax = r[j].x, ay = r[j].y, bx = r[i].x, by = r[i].y;
            const double dx = bx - ax, dy = by - ay;
            const double len2 = dx * dx + dy * dy;
            double t = len2 > 0 ? ((x - ax) * dx + (y - ay) * dy) / len2 : 0.0;
            t = std::clamp(t, 0.0, 1.0);
            const double ex = ax + t * dx - x, ey = ay + t * dy - y;
            best = std::min(best, ex * ex + ey * ey);
        }
    };
    ring(p.outer);
    for (const Ring& h : p.holes) ring(h);
    return std::sqrt(best);
}

/// An extent that contains nothing; include() grows it.
inline Extent empty_extent() { return {INFINITY, INFINITY, -INFINITY, -INFINITY}; }

/// Grows `e` to cover `o`.
inline void include(Extent& e, const Extent& o) {
    e.min_x = std::min(e.min_x, o.min_x), e.min_y = std::min(e.min_y, o.min_y);
    e.max_x = std::max(e.max_x, o.max_x), e.max_y = std::max(e.max_y, o.max_y);
}

/// Bounding box of the outer ring.
inline Extent polygon_extent(const Polygon& p) {
    Extent e = empty_extent();
    for (const MapPoint& q : p.outer) {
        e.min_x = std::min(e.min_x, q.x), e.max_x = std::max(e.max_x, q.x);
        e.min_y = std::min(e.min_y, q.y), e.max_y = std::max(e.max_y, q.y);
    }
    return e;
}

/// Bounding box of a footprint's parts (a multipolygon).
inline Extent parts_extent(const std::vector<Polygon>& parts) {
    Extent e = empty_extent();
    for (const Polygon& p : parts) include(e, polygon_extent(p));
    return e;
}

/// Area of a footprint's parts (parts do not overlap), CRS units squared.
inline double parts_area(const std::vector<Polygon>& parts) {
    double a = 0.0;
    for (const Polygon& p : parts) a += polygon_area(p);
    return a;
}

}  // namespace cityforge
