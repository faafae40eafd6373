#include "footprint/curved_outline.hpp"

#include <cmath>

#include "core/error.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"

namespace cityforge {

void CurvedOutlineOptions::validate() const {
    if (!(max_rectilinear_share >= 0 && max_rectilinear_share <= 1)) throw Error("curved outlines", "max_rectilinear_share must be in [0, 1]");
    if (!(axis_tolerance_deg > 0 && axis_tolerance_deg < 45)) throw Error("curved outlines", "axis_tolerance_deg must be in (0, 45)");
    if (!(simplify_px >= 0) || !(classify_simplify_px >= 0)) throw Error("curved outlines", "simplify tolerances must be >= 0");
    if (!(min_solidity >= 0 && min_solidity <= 1) || !(max_rectangularity >= 0 && max_rectangularity <= 1))
        throw Error("curved outlines", "min_solidity and max_rectangularity must be in [0, 1]");
}

namespace {

Ring smooth_ring(const Ring& ring, double pixel_size) {
    // Rings are closed implicitly; a repeated last vertex is skipped.
    std::size_t n = ring.size();
    if (n >= 2 && ring.front().x == ring.back().x && ring.front().y == ring.back().y) --n;
    if (n < 3) return ring;
    Ring steps;  // the ring cut into steps of about one pixel
    for (std::size_t i = 0; i < n; ++i) {
        const MapPoint a = ring[i], b = ring[(i + 1) % n];
        const double len = std::hypot(b.x - a.x, b.y - a.y);
        const int k = std::max(1, static_cast<int>(std::lround(len / pixel_size)));
        for (int j = 0; j < k; ++j) steps.push_back({a.x + (b.x - a.x) * j / k, a.y + (b.y - a.y) * j / k});
    }
    Ring out;
    out.reserve(steps.size() + 1);
    for (std::size_t i = 0; i < steps.size(); ++i) {
        const MapPoint a = steps[i], b = steps[(i + 1) % steps.size()];
        out.push_back({0.5 * (a.x + b.x), 0.5 * (a.y + b.y)});
    }
    return out;
}

}  // namespace

Polygon smooth_pixel_outline(const Polygon& pixels, double pixel_size, double simplify_px) {
    if (!(pixel_size > 0)) throw Error("curved outlines", "pixel size must be > 0");
    Polygon out;
    out.outer = smooth_ring(pixels.outer, pixel_size);
    for (const Ring& h : pixels.holes) out.holes.push_back(smooth_ring(h, pixel_size));
    return simplify_polygon(out, simplify_px * pixel_size);
}

std::optional<Polygon> curved_outline(const Polygon& pixels, double pixel_size, const CurvedOutlineOptions& o) {
    const Polygon smooth = smooth_pixel_outline(pixels, pixel_size, o.simplify_px);
    if (smooth.outer.size() < 5) return std::nullopt;
    const double area = polygon_area(smooth), hull = std::abs(signed_area(convex_hull(smooth.outer)));
    if (!(area > 0) || area < o.min_solidity * hull) return std::nullopt;
    const OrientedRectangle rect = minimum_area_rectangle(smooth);
    if (area > o.max_rectangularity * rect.length * rect.width) return std::nullopt;
    const Polygon coarse = simplify_polygon(smooth, o.classify_simplify_px * pixel_size);
    if (rectilinear_share(coarse, rect.orientation_deg, o.axis_tolerance_deg) >= o.max_rectilinear_share) return std::nullopt;
    if (!polygon_is_valid(smooth)) return std::nullopt;
    return smooth;
}

double rectilinear_share(const Polygon& polygon, double orientation_deg, double tolerance_deg) {
    const Ring& r = polygon.outer;
    double along = 0, total = 0;
    const double pi = 3.14159265358979323846;
    for (std::size_t i = 0; i < r.size(); ++i) {
        const MapPoint p = r[i], q = r[(i + 1) % r.size()];
        const double dx = q.x - p.x, dy = q.y - p.y, len = std::hypot(dx, dy);
        if (!(len > 0)) continue;
        // Angle to the nearest axis, folded into [0, 45] degrees.
        double a = std::fmod(std::atan2(dy, dx) * 180.0 / pi - orientation_deg, 90.0);
        if (a < 0) a += 90.0;
        a = std::min(a, 90.0 - a);
        total += len;
        if (a <= tolerance_deg) along += len;
    }
    return total > 0 ? along / total : 1.0;
}

}  // namespace cityforge
