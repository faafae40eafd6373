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
#include "core/morphology.hpp"

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

bool OrientedRectangle::contains(MapPoint p) const {
    const double a = orientation_deg * std::numbers::pi / 180.0, ux = std::cos(a), uy = std::sin(a);
    const double dx = p.x - centre.x, dy = p.y - centre.y;
    const double eps = 1e-9 * std::max(1.0, length);
    return std::abs(dx * ux + dy * uy) <= 0.5 * length + eps && std::abs(-dx * uy + dy * ux) <= 0.5 * width + eps;
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

bool polygon_is_valid(const Polygon& p) {
    const BPolygon b = to_boost(p);
    return bg::is_valid(b);
}

Polygon offset_edges(const Polygon& polygon, double d) {
    auto ring = [d](const Ring& r) {
        const std::size_t n = r.size();
        Ring out(n);
        // Outward normal of edge i (r[i] -> r[i+1]): the right-hand side, since
        // the interior lies to the left of every edge of an oriented ring.
        std::vector<MapPoint> normal(n);
        for (std::size_t i = 0; i < n; ++i) {
            const MapPoint& a = r[i];
            const MapPoint& b = r[(i + 1) % n];
            const double len = std::hypot(b.x - a.x, b.y - a.y);
            normal[i] = len > 0 ? MapPoint{(b.y - a.y) / len, -(b.x - a.x) / len} : MapPoint{0.0, 0.0};
        }
        for (std::size_t i = 0; i < n; ++i) {
            const MapPoint& n1 = normal[(i + n - 1) % n];
            const MapPoint& n2 = normal[i];
            // Mitre: the point at distance d from both moved edge lines.
            const double c = 1.0 + n1.x * n2.x + n1.y * n2.y;
            const double k = c > 0.1 ? d / c : d / 0.1;  // near-reversals are clamped
            out[i] = {r[i].x + k * (n1.x + n2.x), r[i].y + k * (n1.y + n2.y)};
        }
        return out;
    };
    Polygon out;
    out.outer = ring(polygon.outer);
    for (const Ring& h : polygon.holes) out.holes.push_back(ring(h));
    return out;
}

Polygon match_area(const Polygon& polygon_in, double target_area, double max_offset) {
    Polygon polygon = polygon_in;
    orient_polygon(polygon);
    const double a0 = polygon_area(polygon);
    const double perimeter = polygon_perimeter(polygon);
    if (!(target_area > 0) || !(perimeter > 0) || !(max_offset > 0)) return polygon_in;
    // Area as a function of the offset is a quadratic, A(d) = a0 + P d + k d²;
    // secant steps from the linear guess converge in two or three steps.
    double d_prev = 0.0, a_prev = a0;
    double d = (target_area - a0) / perimeter;
    Polygon best = polygon_in;
    for (int it = 0; it < 4; ++it) {
        if (std::abs(d) > max_offset) return polygon_in;
        Polygon moved = offset_edges(polygon, d);
        const double a = polygon_area(moved);
        best = std::move(moved);
        if (std::abs(a - target_area) <= 1e-9 * target_area || a == a_prev) break;
        const double slope = (a - a_prev) / (d - d_prev);
        if (!(std::abs(slope) > 0)) break;
        d_prev = d, a_prev = a;
        d += (target_area - a) / slope;
    }
    if (!polygon_is_valid(best)) return polygon_in;
    return best;
}

}  // namespace cityforge

#include "footprint/vectorize.hpp"

namespace cityforge {
namespace {

// Largest all-ones axis-aligned rectangle of a binary grid (histogram stack).
struct GridRect {
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;  // inclusive
    long area() const { return static_cast<long>(x1 - x0 + 1) * (y1 - y0 + 1); }
};
GridRect largest_rectangle(const std::vector<uint8_t>& m, int w, int h) {
    std::vector<int> height(w, 0);
    GridRect best;
    long best_area = 0;
    std::vector<int> stack;
    for (int y = 0; y < h; ++y) {
        const uint8_t* row = m.data() + static_cast<std::size_t>(y) * w;
        int any = 0;
        for (int x = 0; x < w; ++x) height[x] = row[x] ? height[x] + 1 : 0, any |= height[x];
        // The masks are sparse (a fit's missing and extra cells): a row of
        // empty columns ends no rectangle, and in a run of empty columns each
        // one only replaces the one before it on the stack (its area is 0,
        // never a best): both skipped, the same rectangles met in the same order.
        if (!any) continue;
        stack.clear();
        for (int x = 0; x <= w; ++x) {
            const int hx = x < w ? height[x] : 0;
            if (hx == 0 && stack.size() == 1 && height[stack[0]] == 0) {
                stack[0] = x;
                continue;
            }
            while (!stack.empty() && height[stack.back()] >= hx) {
                const int top = stack.back();
                stack.pop_back();
                const int left = stack.empty() ? 0 : stack.back() + 1;
                const long area = static_cast<long>(height[top]) * (x - left);
                if (area > best_area) {
                    best_area = area;
                    best = {left, y - height[top] + 1, x - 1, y};
                }
            }
            stack.push_back(x);
        }
    }
    return best;
}

}  // namespace

RecursiveFit recursive_rectangle_fit(const Polygon& polygon, const RecursiveFitOptions& o) {
    const OrientedRectangle r0 = minimum_area_rectangle(polygon);
    RecursiveFit fit;
    fit.orientation_deg = r0.orientation_deg;
    const double area = polygon_area(polygon);
    // Frame: u along the orientation, v across, origin at the rectangle centre.
    const double a = r0.orientation_deg * std::numbers::pi / 180.0, ux = std::cos(a), uy = std::sin(a);
    const double cell = o.cell > 0 ? o.cell : std::max(std::sqrt(area) / 200.0, 1e-6);
    const int w = std::max(1, static_cast<int>(std::ceil(r0.length / cell))), h = std::max(1, static_cast<int>(std::ceil(r0.width / cell)));
    const double u0 = -0.5 * w * cell, v0 = -0.5 * h * cell;
    auto to_map = [&](double u, double v) { return MapPoint{r0.centre.x + u * ux - v * uy, r0.centre.y + u * uy + v * ux}; };
    // Raw polygon on the frame grid (cell centres).
    Polygon local;
    auto to_local = [&](const Ring& ring) {
        Ring out;
        for (const MapPoint& p : ring) {
            const double dx = p.x - r0.centre.x, dy = p.y - r0.centre.y;
            out.push_back({dx * ux + dy * uy, -dx * uy + dy * ux});
        }
        return out;
    };
    local.outer = to_local(polygon.outer);
    for (const Ring& hr : polygon.holes) local.holes.push_back(to_local(hr));
    std::vector<uint8_t> inside(static_cast<std::size_t>(w) * h), model(static_cast<std::size_t>(w) * h, 1);
    // Scanline fill at the cell centres (even-odd over all rings, the same
    // rule as point_in_polygon): O(rows x edges + cells).
    {
        std::vector<double> cross;
        for (int y = 0; y < h; ++y) {
            const double v = v0 + (y + 0.5) * cell;
            cross.clear();
            auto ring_crossings = [&](const Ring& r) {
                for (std::size_t i = 0, j = r.size() - 1; i < r.size(); j = i++) {
                    const MapPoint& p = r[i];
                    const MapPoint& q = r[j];
                    if ((p.y > v) != (q.y > v)) cross.push_back((q.x - p.x) * (v - p.y) / (q.y - p.y) + p.x);
                }
            };
            ring_crossings(local.outer);
            for (const Ring& hr : local.holes) ring_crossings(hr);
            std::sort(cross.begin(), cross.end());
            for (std::size_t c = 0; c + 1 < cross.size(); c += 2) {
                // Cells whose centre u lies in (cross[c], cross[c+1]).
                const int x_from = std::max(0, static_cast<int>(std::floor((cross[c] - u0) / cell - 0.5)) + 1);
                const int x_to = std::min(w - 1, static_cast<int>(std::ceil((cross[c + 1] - u0) / cell - 0.5)) - 1);
                for (int x = x_from; x <= x_to; ++x) inside[static_cast<std::size_t>(y) * w + x] = 1;
            }
        }
    }
    const long min_cells = std::max(1L, static_cast<long>(o.min_rectangle_area / (cell * cell)));
    auto model_error_pct = [&] {
        long diff = 0, model_cells = 0, in_cells = 0;
        for (std::size_t k = 0; k < model.size(); ++k) model_cells += model[k], in_cells += inside[k];
        diff = model_cells - in_cells;
        return in_cells ? 100.0 * static_cast<double>(diff) / static_cast<double>(in_cells) : 0.0;
    };
    std::vector<uint8_t> missing(model.size()), extra(model.size());
    for (int step = 0; step < o.max_rectangles && std::abs(model_error_pct()) > o.tolerance_pct; ++step) {
        for (std::size_t k = 0; k < model.size(); ++k) missing[k] = model[k] && !inside[k], extra[k] = !model[k] && inside[k];
        const GridRect cut = largest_rectangle(missing, w, h);
        const GridRect add = largest_rectangle(extra, w, h);
        const bool do_cut = cut.area() >= add.area();
        const GridRect& r = do_cut ? cut : add;
        if (r.area() < min_cells) break;
        for (int y = r.y0; y <= r.y1; ++y)
            for (int x = r.x0; x <= r.x1; ++x) model[static_cast<std::size_t>(y) * w + x] = do_cut ? 0 : 1;
        ++fit.rectangles;
    }
    // Outlines from rasters are staircases: every rectangle edge sits on the
    // outer stair corners, a band of constant width along the whole outline.
    // Move all edges by the same distance (erode or dilate with a square, which
    // keeps right angles) so that the model's area matches the polygon's.
    {
        long model_cells = 0, in_cells = 0, boundary = 0;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                model_cells += model[k], in_cells += inside[k];
                if (!model[k]) continue;
                boundary += (x == 0 || !model[k - 1]) + (x == w - 1 || !model[k + 1]) + (y == 0 || !model[k - static_cast<std::size_t>(w)]) +
                            (y == h - 1 || !model[k + static_cast<std::size_t>(w)]);
            }
        const int shift = boundary > 0 ? static_cast<int>(std::lround(static_cast<double>(model_cells - in_cells) / static_cast<double>(boundary))) : 0;
        if (shift != 0 && std::abs(shift) < std::min(w, h) / 4) {
            // Cells outside the frame count as empty: erosion trims the border too.
            model = morphology_square<uint8_t>(model, w, h, std::abs(shift), shift > 0, uint8_t(0));
        }
    }
    // The model grid back to a polygon: vectorise in frame coordinates, then rotate.
    Image<uint32_t> grid(w, h, 1, 0u);
    for (std::size_t k = 0; k < model.size(); ++k) grid.data[k] = model[k];
    const GeoTransform frame{u0, cell, v0 + h * cell, -cell};  // row 0 at the largest v
    // Rows run towards smaller v in the frame transform, so flip the grid rows.
    Image<uint32_t> flipped(w, h, 1, 0u);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) flipped.at(0, x, h - 1 - y) = grid.at(0, x, y);
    std::vector<Polygon> parts = vectorize_region(flipped, 1, frame);
    if (parts.empty()) throw Error("rectangle fit", "recursive fit removed the whole building");
    // Keep the largest part (cuts may split a thin model); holes come along.
    std::sort(parts.begin(), parts.end(), [](const Polygon& p, const Polygon& q) { return polygon_area(p) > polygon_area(q); });
    auto ring_to_map = [&](const Ring& ring) {
        Ring out;
        for (const MapPoint& p : ring) out.push_back(to_map(p.x, p.y));
        return out;
    };
    Polygon frame_fit = parts[0];
    // The grid edges are quantised to the working cell: place them exactly.
    if (o.match_area_max_offset > 0) frame_fit = match_area(frame_fit, polygon_area(local), o.match_area_max_offset);
    fit.polygon.outer = ring_to_map(frame_fit.outer);
    for (const Ring& hr : frame_fit.holes) fit.polygon.holes.push_back(ring_to_map(hr));
    orient_polygon(fit.polygon);
    fit.accuracy = fit_accuracy(polygon, fit.polygon);
    return fit;
}

}  // namespace cityforge
