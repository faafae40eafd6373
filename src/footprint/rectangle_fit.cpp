#include "footprint/rectangle_fit.hpp"

#include <algorithm>
// Boost.Geometry's rescale policy trips GCC 12's maybe-uninitialized analysis
// (a false positive inside Boost); silence it for this file only.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <boost/geometry.hpp>
#include <boost/geometry/geometries/point_xy.hpp>
#include <boost/geometry/geometries/polygon.hpp>
#include <cmath>
#include <numbers>

#include "core/error.hpp"

namespace cityforge {
namespace bg = boost::geometry;
namespace {
using BPoint = bg::model::d2::point_xy<double>;
using BPolygon = bg::model::polygon<BPoint, false, false>;  // counter-clockwise, open rings
using BMulti = bg::model::multi_polygon<BPolygon>;

BPolygon to_boost(const Polygon& p) {
    BPolygon out;
    for (const MapPoint& q : p.outer) out.outer().push_back({q.x, q.y});
    for (const Ring& h : p.holes) {
        out.inners().emplace_back();
        for (const MapPoint& q : h) out.inners().back().push_back({q.x, q.y});
    }
    bg::correct(out);
    return out;
}
}  // namespace

std::array<MapPoint, 4> OrientedRectangle::corners() const {
    const double a = orientation_deg * std::numbers::pi / 180.0;
    const double ux = std::cos(a), uy = std::sin(a), vx = -uy, vy = ux;
    const double hl = 0.5 * length, hw = 0.5 * width;
    return {MapPoint{centre.x - ux * hl - vx * hw, centre.y - uy * hl - vy * hw},
            MapPoint{centre.x + ux * hl - vx * hw, centre.y + uy * hl - vy * hw},
            MapPoint{centre.x + ux * hl + vx * hw, centre.y + uy * hl + vy * hw},
            MapPoint{centre.x - ux * hl + vx * hw, centre.y - uy * hl + vy * hw}};
}

Polygon OrientedRectangle::polygon() const {
    const auto c = corners();
    return Polygon{Ring(c.begin(), c.end()), {}};
}

Ring convex_hull(const std::vector<MapPoint>& pts_in) {
    std::vector<MapPoint> pts = pts_in;
    std::sort(pts.begin(), pts.end(), [](const MapPoint& a, const MapPoint& b) { return a.x != b.x ? a.x < b.x : a.y < b.y; });
    pts.erase(std::unique(pts.begin(), pts.end(), [](const MapPoint& a, const MapPoint& b) { return a.x == b.x && a.y == b.y; }), pts.end());
    if (pts.size() < 3) return pts;
    auto cross = [](const MapPoint& o, const MapPoint& a, const MapPoint& b) {
        return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
    };
    Ring hull(2 * pts.size());
    std::size_t k = 0;
    for (const MapPoint& p : pts) {
        while (k >= 2 && cross(hull[k - 2], hull[k - 1], p) <= 0) --k;
        hull[k++] = p;
    }
    for (std::size_t i = pts.size() - 1, t = k + 1; i-- > 0;) {
        while (k >= t && cross(hull[k - 2], hull[k - 1], pts[i]) <= 0) --k;
        hull[k++] = pts[i];
    }
    hull.resize(k - 1);
    return hull;
}

OrientedRectangle minimum_area_rectangle(const Polygon& polygon) {
    const Ring hull = convex_hull(polygon.outer);
    if (hull.size() < 3 || std::abs(signed_area(hull)) <= 0.0)
        throw Error("rectangle fit", "degenerate polygon (fewer than 3 distinct vertices or zero area)");
    // Work relative to the first vertex: large map coordinates lose precision.
    const MapPoint o = hull[0];
    OrientedRectangle best;
    double best_area = INFINITY;
    for (std::size_t i = 0; i < hull.size(); ++i) {
        const MapPoint& a = hull[i];
        const MapPoint& b = hull[(i + 1) % hull.size()];
        double ux = b.x - a.x, uy = b.y - a.y;
        const double len = std::hypot(ux, uy);
        if (len == 0) continue;
        ux /= len, uy /= len;
        double smin = INFINITY, smax = -INFINITY, tmin = INFINITY, tmax = -INFINITY;
        for (const MapPoint& p : hull) {
            const double dx = p.x - o.x, dy = p.y - o.y;
            const double s = dx * ux + dy * uy, t = -dx * uy + dy * ux;
            smin = std::min(smin, s), smax = std::max(smax, s), tmin = std::min(tmin, t), tmax = std::max(tmax, t);
        }
        const double area = (smax - smin) * (tmax - tmin);
        double angle = std::atan2(uy, ux) * 180.0 / std::numbers::pi;
        double length = smax - smin, width = tmax - tmin;
        if (width > length) std::swap(width, length), angle += 90.0;
        angle = std::fmod(angle + 360.0, 180.0);
        if (area < best_area * (1 - 1e-12) || (std::abs(area - best_area) <= 1e-12 * best_area && angle < best.orientation_deg)) {
            best_area = area;
            const double sc = 0.5 * (smin + smax), tc = 0.5 * (tmin + tmax);
            best.centre = {o.x + sc * ux - tc * uy, o.y + sc * uy + tc * ux};
            best.length = length, best.width = width, best.orientation_deg = angle;
        }
    }
    return best;
}

double polygon_iou(const Polygon& a, const Polygon& b) {
    const BPolygon pa = to_boost(a), pb = to_boost(b);
    BMulti inter;
    bg::intersection(pa, pb, inter);
    const double i = bg::area(inter);
    const double u = bg::area(pa) + bg::area(pb) - i;
    return u > 0 ? i / u : 0.0;
}

FitAccuracy fit_accuracy(const Polygon& raw, const Polygon& fit) {
    const double ar = polygon_area(raw);
    if (!(ar > 0)) throw Error("fit accuracy", "raw polygon has no area");
    return {(polygon_area(fit) - ar) / ar * 100.0, polygon_iou(raw, fit)};
}

double polygon_perimeter(const Polygon& p) {
    auto ring = [](const Ring& r) {
        double s = 0.0;
        for (std::size_t i = 0; i < r.size(); ++i) s += std::hypot(r[(i + 1) % r.size()].x - r[i].x, r[(i + 1) % r.size()].y - r[i].y);
        return s;
    };
    double s = ring(p.outer);
    for (const Ring& h : p.holes) s += ring(h);
    return s;
}

}  // namespace cityforge
