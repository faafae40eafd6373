#include "roof/lod2_builder.hpp"

#include <CGAL/Arr_extended_dcel.h>
#include <CGAL/Arr_segment_traits_2.h>
#include <CGAL/Arrangement_2.h>
#include <CGAL/Exact_predicates_exact_constructions_kernel.h>
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>

#include "core/error.hpp"

namespace cityforge {

void Lod2Options::validate() const {
    planes.validate();
    if (!(line_extension_m >= 0)) throw Error("--line-extension-m", "must be >= 0");
    if (!(ridge_snap_m > 0)) throw Error("--ridge-snap-m", "must be > 0");
    if (!(flat_slope_deg >= 0)) throw Error("--flat-slope-deg", "must be >= 0");
    if (min_points < 3) throw Error("--lod2-min-points", "must be >= 3");
    if (!(max_median_residual_m > 0)) throw Error("--max-median-residual-m", "must be > 0");
    if (!(unit_m > 0) || !(z_unit_m > 0)) throw Error("units", "CRS units must be > 0 metres");
    if (!(retry_rmse_m >= 0)) throw Error("--lod2-retry-rmse-m", "must be >= 0");
    if (max_partition_lines < 1) throw Error("max_partition_lines", "must be >= 1");
}

namespace {

constexpr double kPiLod2 = 3.14159265358979323846;
// gable_ends_dip: a footprint at least this share of its box along the ridge is a rectangle ...
constexpr double kRectangularShare = 0.9;
// ... and the points at both ridge ends lie below the gable's planes by this share of its rise, on average.
constexpr double kHipDipShare = 0.25;
// Partition lines reach at least this many adjacency cells beyond their samples.
constexpr double kLineExtensionCells = 3.0;

using K = CGAL::Exact_predicates_exact_constructions_kernel;
using Traits = CGAL::Arr_segment_traits_2<K>;
using Dcel = CGAL::Arr_face_extended_dcel<Traits, int>;
using Arr = CGAL::Arrangement_2<Traits, Dcel>;
using P2 = K::Point_2;

constexpr int kOutside = -1;
constexpr int kUnlabelled = -2;

struct XY {
    double x, y;
};

// The outer CCB (or an inner one) of a face as a double ring.
template <typename Circ>
Ring ring_of(Circ start) {
    Ring r;
    Circ c = start;
    do {
        r.push_back({CGAL::to_double(c->source()->point().x()), CGAL::to_double(c->source()->point().y())});
    } while (++c != start);
    return r;
}

Polygon polygon_of(Arr::Face_const_handle f) {
    Polygon p;
    p.outer = ring_of(f->outer_ccb());
    for (auto h = f->inner_ccbs_begin(); h != f->inner_ccbs_end(); ++h) p.holes.push_back(ring_of(*h));
    return p;
}

// A point strictly inside a bounded face: just left of the middle of its longest outer edge.
XY interior_point(Arr::Face_const_handle f) {
    auto start = f->outer_ccb(), c = start, best = start;
    double best_len = -1;
    do {
        const double dx = CGAL::to_double(c->target()->point().x() - c->source()->point().x());
        const double dy = CGAL::to_double(c->target()->point().y() - c->source()->point().y());
        const double l = std::hypot(dx, dy);
        if (l > best_len) best_len = l, best = c;
    } while (++c != start);
    const double sx = CGAL::to_double(best->source()->point().x()), sy = CGAL::to_double(best->source()->point().y());
    const double tx = CGAL::to_double(best->target()->point().x()), ty = CGAL::to_double(best->target()->point().y());
    const double l = std::max(best_len, 1e-12);
    const double eps = std::min(1e-3, best_len * 1e-3);
    return {(sx + tx) / 2 - (ty - sy) / l * eps, (sy + ty) / 2 + (tx - sx) / l * eps};
}

bool segment_ok(double ax, double ay, double bx, double by) { return std::hypot(bx - ax, by - ay) > 1e-6; }

// Heights at one vertex, clustered (values within 1e-4 m are one height).
struct VertexHeights {
    std::vector<double> z;
    std::vector<std::pair<double, double>> alias;  // plane value -> the height used instead
    double canonical(double v) {
        for (const auto& [from, to] : alias)
            if (std::abs(from - v) < 1e-9) v = to;
        for (double h : z)
            if (std::abs(h - v) < 1e-4) return h;
        z.push_back(v);
        return v;
    }
    // Two roofs meet at this vertex at their mean height (each off its plane by half the gap).
    void unify(double a, double b) {
        const double m = 0.5 * (a + b);
        alias.emplace_back(a, m), alias.emplace_back(b, m);
    }
    // The heights strictly between a and b, ordered from a to b.
    std::vector<double> between(double a, double b) const {
        std::vector<double> out;
        for (double h : z)
            if ((h > std::min(a, b) + 1e-9) && (h < std::max(a, b) - 1e-9)) out.push_back(h);
        std::sort(out.begin(), out.end());
        if (a > b) std::reverse(out.begin(), out.end());
        return out;
    }
};

// `eave_spread_m`: roof z range along the footprint outline; `rake_share`:
// the share of the outline under sloped planes whose downhill direction runs
// along the outline (a gable end, a rake) rather than out of it (an eave).
// A hip has eaves all round: a level outline, or (a corner cut at an oblique
// angle, where the outline climbs the hip planes) next to no rakes.
std::string classify_roof(const std::vector<RoofPlane>& used, double eave_spread_m, double rake_share, double flat_slope_deg) {
    std::vector<const RoofPlane*> sloped;
    for (const RoofPlane& p : used)
        if (p.slope_deg >= flat_slope_deg) sloped.push_back(&p);
    if (sloped.empty()) return "flat";
    if (sloped.size() < used.size() && used.size() > 1) {
        // Flat parts beside sloped ones: a shed or gable over part of a flat roof is still complex.
        double flat_points = 0, all = 0;
        for (const RoofPlane& p : used) all += double(p.points.size()), flat_points += p.slope_deg < flat_slope_deg ? double(p.points.size()) : 0;
        if (flat_points / all > 0.1) return "complex";
    }
    bool opposite = false;
    for (std::size_t i = 0; i < sloped.size(); ++i)
        for (std::size_t j = i + 1; j < sloped.size(); ++j) {
            double d = std::abs(sloped[i]->azimuth_deg - sloped[j]->azimuth_deg);
            d = std::min(d, 360.0 - d);
            if (std::abs(d - 180.0) < 25.0 && std::abs(sloped[i]->slope_deg - sloped[j]->slope_deg) < 12.0) opposite = true;
        }
    if (!opposite) return "shed";
    if (sloped.size() >= 3 && (eave_spread_m < 0.35 || rake_share < 0.1)) return "hip";
    return "gable";
}

// A roof read as a gable whose ridge ends dip: on a hip roof with sparse
// points (dark roofs, low densities) the small end facets often find no
// plane of their own, and the two long facets cover the roof as a gable
// would. Near each end of the ridge line (within half the half-width of the
// footprint's end, and of the ridge across), a hip's points lie about half
// the rise below the gable's two planes; a gable's lie on them. Only for one
// near-rectangular footprint part (an L's ridge line runs on into the other
// wing, whose facets dip the same way). `part` and `pts` in the local frame.
bool gable_ends_dip(const std::vector<RoofPlane>& used, const Polygon& part, const std::vector<std::array<double, 3>>& pts, double flat_slope_deg) {
    // The opposite pair with the most points.
    const RoofPlane *p1 = nullptr, *p2 = nullptr;
    std::size_t best = 0;
    for (std::size_t i = 0; i < used.size(); ++i)
        for (std::size_t j = i + 1; j < used.size(); ++j) {
            const RoofPlane &a = used[i], &b = used[j];
            if (a.slope_deg < flat_slope_deg || b.slope_deg < flat_slope_deg) continue;
            double d = std::abs(a.azimuth_deg - b.azimuth_deg);
            d = std::min(d, 360.0 - d);
            if (std::abs(d - 180.0) >= 25.0 || std::abs(a.slope_deg - b.slope_deg) >= 12.0) continue;
            if (a.points.size() + b.points.size() > best) best = a.points.size() + b.points.size(), p1 = &a, p2 = &b;
        }
    if (!p1 || !part.holes.empty() || part.outer.size() < 3) return false;
    // Ridge line in plan: (a1 - a2) x + (b1 - b2) y + (c1 - c2) = 0.
    const double gx = p1->a - p2->a, gy = p1->b - p2->b, gn = std::hypot(gx, gy);
    if (!(gn > 1e-9)) return false;
    const double nx = gx / gn, ny = gy / gn, dx = -ny, dy = nx;  // across, along
    const double x0 = -(p1->c - p2->c) * gx / (gn * gn), y0 = -(p1->c - p2->c) * gy / (gn * gn);
    double t0 = INFINITY, t1 = -INFINITY, s0 = INFINITY, s1 = -INFINITY;
    for (const MapPoint& q : part.outer) {
        const double t = (q.x - x0) * dx + (q.y - y0) * dy, sv = (q.x - x0) * nx + (q.y - y0) * ny;
        t0 = std::min(t0, t), t1 = std::max(t1, t), s0 = std::min(s0, sv), s1 = std::max(s1, sv);
    }
    const double box = (t1 - t0) * (s1 - s0);
    if (!(box > 0) || std::abs(signed_area(part.outer)) < kRectangularShare * box) return false;
    // The ridge runs along the longer side, about midway across.
    const double h = 0.5 * (s1 - s0);
    if (t1 - t0 < 2 * h || std::abs(0.5 * (s0 + s1)) > 0.25 * h) return false;
    const double rise = h * 0.5 * (std::tan(p1->slope_deg * kPiLod2 / 180.0) + std::tan(p2->slope_deg * kPiLod2 / 180.0));
    double sum[2] = {0, 0}, n[2] = {0, 0};
    for (const auto& q : pts) {
        const double t = (q[0] - x0) * dx + (q[1] - y0) * dy, sv = (q[0] - x0) * nx + (q[1] - y0) * ny;
        if (std::abs(sv) > 0.5 * h) continue;
        const int end = t - t0 < 0.5 * h ? 0 : t1 - t < 0.5 * h ? 1 : -1;
        if (end < 0) continue;
        sum[end] += q[2] - std::min(p1->z(q[0], q[1]), p2->z(q[0], q[1])), n[end] += 1;
    }
    for (int e = 0; e < 2; ++e)
        if (n[e] < 3 || sum[e] / n[e] > -kHipDipShare * rise) return false;
    return true;
}

struct PartResult {
    Solid solid;
    std::vector<int> used_planes;
    double eave_min = INFINITY, eave_max = -INFINITY;  // roof z along the footprint outline (local metres)
    double sloped_outline_m = 0.0;  // outline length under sloped planes (metres)
    double rake_m = 0.0;            // of which under planes sloping along the outline (gable ends)
    std::string failure;
};

// One footprint part in local metres (origin subtracted, z in metres).
PartResult build_part(const Polygon& part, const std::vector<std::array<double, 3>>& pts, const std::vector<RoofPlane>& planes,
                      const std::vector<int>& point_plane, double ground, const Lod2Options& o) {
    PartResult res;
    Arr arr;
    std::vector<Traits::X_monotone_curve_2> curves;
    auto add_ring = [&](const Ring& r) {
        for (std::size_t i = 0; i < r.size(); ++i) {
            const MapPoint a = r[i], b = r[(i + 1) % r.size()];
            if (segment_ok(a.x, a.y, b.x, b.y)) curves.emplace_back(P2(a.x, a.y), P2(b.x, b.y));
        }
    };
    add_ring(part.outer);
    for (const Ring& h : part.holes) add_ring(h);
    const std::size_t outline_segments = curves.size();

    // Adjacent plane pairs and their common boundary samples, from a label
    // grid of 0.5 m cells, or of the mean point spacing on a sparser roof (a
    // dark roof returns a fifth of the pulses: at 4 pts/m2 its points lie
    // about 1.1 m apart, and planes meeting at a hip would not look adjacent).
    std::size_t labelled = 0;
    for (const int l : point_plane) labelled += l >= 0;
    const double cell = std::max(0.5, std::sqrt(polygon_area(part) / static_cast<double>(std::max<std::size_t>(labelled, 1))));
    std::map<std::pair<int, int>, std::vector<XY>> boundary;
    {
        Extent e = polygon_extent(part);
        const int w = static_cast<int>(std::ceil(e.width() / cell)) + 3, h = static_cast<int>(std::ceil(e.height() / cell)) + 3;
        std::vector<std::vector<int>> labels(static_cast<std::size_t>(w) * h);
        for (std::size_t i = 0; i < pts.size(); ++i) {
            if (point_plane[i] < 0) continue;
            const int cx = static_cast<int>((pts[i][0] - e.min_x) / cell) + 1, cy = static_cast<int>((pts[i][1] - e.min_y) / cell) + 1;
            if (cx < 0 || cy < 0 || cx >= w || cy >= h) continue;
            auto& v = labels[static_cast<std::size_t>(cy) * w + cx];
            if (std::find(v.begin(), v.end(), point_plane[i]) == v.end()) v.push_back(point_plane[i]);
        }
        for (int cy = 1; cy + 1 < h; ++cy)
            for (int cx = 1; cx + 1 < w; ++cx) {
                std::set<int> around;
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx)
                        for (int l : labels[static_cast<std::size_t>(cy + dy) * w + cx + dx]) around.insert(l);
                if (around.size() < 2) continue;
                const XY c{e.min_x + (cx - 1 + 0.5) * cell, e.min_y + (cy - 1 + 0.5) * cell};
                for (auto a = around.begin(); a != around.end(); ++a)
                    for (auto b = std::next(a); b != around.end(); ++b) boundary[{*a, *b}].push_back(c);
            }
    }
    for (const auto& [pair, samples] : boundary) {
        if (samples.size() < 3) continue;
        const RoofPlane& A = planes[pair.first];
        const RoofPlane& B = planes[pair.second];
        // Direction and point of the partition line.
        double px = 0, py = 0, dx = 0, dy = 0;
        const double na = A.a - B.a, nb = A.b - B.b, nc = A.c - B.c;
        bool ridge = false;
        if (std::hypot(na, nb) > 0.02) {  // planes differ in slope: intersection line na x + nb y + nc = 0
            const double len = std::hypot(na, nb);
            std::vector<double> dist;
            for (const XY& s : samples) dist.push_back(std::abs(na * s.x + nb * s.y + nc) / len);
            std::nth_element(dist.begin(), dist.begin() + dist.size() / 2, dist.end());
            if (dist[dist.size() / 2] < o.ridge_snap_m) {
                ridge = true;
                dx = -nb / len, dy = na / len;
                px = -na * nc / (len * len), py = -nb * nc / (len * len);
            }
        }
        if (!ridge) {
            // A step between the roof parts: the principal line of the boundary samples.
            double mx = 0, my = 0;
            for (const XY& s : samples) mx += s.x, my += s.y;
            mx /= double(samples.size()), my /= double(samples.size());
            double sxx = 0, sxy = 0, syy = 0;
            for (const XY& s : samples) sxx += (s.x - mx) * (s.x - mx), sxy += (s.x - mx) * (s.y - my), syy += (s.y - my) * (s.y - my);
            const double ang = 0.5 * std::atan2(2 * sxy, sxx - syy);
            dx = std::cos(ang), dy = std::sin(ang), px = mx, py = my;
        }
        double t0 = INFINITY, t1 = -INFINITY;
        for (const XY& s : samples) {
            const double t = (s.x - px) * dx + (s.y - py) * dy;
            t0 = std::min(t0, t), t1 = std::max(t1, t);
        }
        // On a sparse roof the samples stop short of a line's ends by about
        // a cell or two: the lines reach at least three cells further.
        const double extension = std::max(o.line_extension_m, kLineExtensionCells * cell);
        t0 -= extension, t1 += extension;
        // Round to a micrometre grid: keeps the exact arithmetic cheap.
        auto q = [](double v) { return std::round(v * 1e6) / 1e6; };
        const double ax = q(px + t0 * dx), ay = q(py + t0 * dy), bx = q(px + t1 * dx), by = q(py + t1 * dy);
        if (segment_ok(ax, ay, bx, by)) curves.emplace_back(P2(ax, ay), P2(bx, by));
    }
    const std::size_t partition_lines = curves.size() - outline_segments;
    if (partition_lines > static_cast<std::size_t>(o.max_partition_lines)) {
        res.failure = "roof too complex: " + std::to_string(partition_lines) + " partition lines between its " + std::to_string(planes.size()) +
                      " planes (limit " + std::to_string(o.max_partition_lines) + ")";
        return res;
    }
    CGAL::insert(arr, curves.begin(), curves.end());

    // Inside / outside the footprint part; remove edges that do not separate two inside faces from each other or from outside.
    auto classify_faces = [&]() {
        for (auto f = arr.faces_begin(); f != arr.faces_end(); ++f) {
            if (f->is_unbounded()) {
                f->set_data(kOutside);
                continue;
            }
            const XY c = interior_point(f);
            f->set_data(point_in_polygon(part, c.x, c.y) ? kUnlabelled : kOutside);
        }
    };
    classify_faces();
    for (bool again = true; again;) {
        again = false;
        std::vector<Arr::Halfedge_handle> drop;
        for (auto e = arr.edges_begin(); e != arr.edges_end(); ++e) {
            const bool same_face = e->face() == e->twin()->face();
            const bool both_out = e->face()->data() == kOutside && e->twin()->face()->data() == kOutside;
            if (same_face || both_out) drop.push_back(e);
        }
        for (auto e : drop) arr.remove_edge(e);
        again = !drop.empty();
        if (again) classify_faces();
    }

    // Label cells: the plane with most of the cell's points; cells without points take a neighbour's label.
    std::vector<Arr::Face_handle> cells;
    std::vector<Polygon> cell_poly;
    for (auto f = arr.faces_begin(); f != arr.faces_end(); ++f)
        if (f->data() != kOutside) cells.push_back(f), cell_poly.push_back(polygon_of(f));
    if (cells.empty()) {
        res.failure = "footprint partition is empty";
        return res;
    }
    std::vector<std::map<int, int>> votes(cells.size());
    std::vector<Extent> cell_ext;
    for (const Polygon& p : cell_poly) cell_ext.push_back(polygon_extent(p));
    for (std::size_t i = 0; i < pts.size(); ++i)
        for (std::size_t c = 0; c < cells.size(); ++c) {
            const Extent& e = cell_ext[c];
            if (pts[i][0] < e.min_x || pts[i][0] > e.max_x || pts[i][1] < e.min_y || pts[i][1] > e.max_y) continue;
            if (!point_in_polygon(cell_poly[c], pts[i][0], pts[i][1])) continue;
            if (point_plane[i] >= 0) ++votes[c][point_plane[i]];
            break;
        }
    for (std::size_t c = 0; c < cells.size(); ++c) {
        int best = kUnlabelled, best_votes = 0;
        for (const auto& [plane, v] : votes[c])
            if (v > best_votes) best = plane, best_votes = v;  // map order: ties go to the lower plane index
        cells[c]->set_data(best);
    }
    for (bool changed = true; changed;) {
        changed = false;
        for (auto f : cells) {
            if (f->data() != kUnlabelled) continue;
            std::map<int, double> shared;
            auto start = f->outer_ccb(), h = start;
            do {
                const int l = h->twin()->face()->data();
                if (l >= 0) shared[l] += CGAL::to_double(CGAL::squared_distance(h->source()->point(), h->target()->point()));
            } while (++h != start);
            if (shared.empty()) continue;
            const auto best = std::max_element(shared.begin(), shared.end(), [](auto& a, auto& b) { return a.second < b.second; });
            f->set_data(best->first);
            changed = true;
        }
    }
    for (auto f : cells)
        if (f->data() == kUnlabelled) {
            res.failure = "roof parts without points";
            return res;
        }

    // Merge cells of one plane: remove the edges between them.
    {
        std::vector<Arr::Halfedge_handle> drop;
        for (auto e = arr.edges_begin(); e != arr.edges_end(); ++e)
            if (e->face()->data() >= 0 && e->face()->data() == e->twin()->face()->data()) drop.push_back(e);
        for (auto e : drop) arr.remove_edge(e);
    }
    // Split step edges where the two roofs cross, so that every wall is a simple polygon.
    {
        std::vector<P2> splits;
        for (auto e = arr.edges_begin(); e != arr.edges_end(); ++e) {
            const int a = e->face()->data(), b = e->twin()->face()->data();
            if (a < 0 || b < 0) continue;
            const RoofPlane& A = planes[a];
            const RoofPlane& B = planes[b];
            const K::FT da = A.a - B.a, db = A.b - B.b, dc = A.c - B.c;
            const P2& s = e->source()->point();
            const P2& t = e->target()->point();
            const K::FT fs = da * s.x() + db * s.y() + dc, ft = da * t.x() + db * t.y() + dc;
            if (CGAL::sign(fs) * CGAL::sign(ft) < 0 && CGAL::to_double(CGAL::abs(fs)) > 1e-4 && CGAL::to_double(CGAL::abs(ft)) > 1e-4) {
                const K::FT u = fs / (fs - ft);
                splits.emplace_back(s.x() + u * (t.x() - s.x()), s.y() + u * (t.y() - s.y()));
            }
        }
        for (const P2& p : splits) CGAL::insert_point(arr, p);
    }

    // Vertices closer than snap_m are one vertex (near-coincident crossings of
    // partition lines would otherwise leave micro-edges): every face maps its
    // vertices through the same representative, so shared edges still pair.
    constexpr double snap_m = 0.005;
    // Keyed by handle for lookup only; every loop runs in the arrangement's
    // vertex order (`vs`), never in the map's (address) order.
    std::map<Arr::Vertex_const_handle, int> rep;
    std::vector<XY> rep_xy;
    std::vector<Arr::Vertex_const_handle> vs;
    {
        for (auto v = arr.vertices_begin(); v != arr.vertices_end(); ++v)
            if (!v->is_isolated()) vs.push_back(v);
        for (auto v : vs) {
            const XY p{CGAL::to_double(v->point().x()), CGAL::to_double(v->point().y())};
            int found = -1;
            for (std::size_t r = 0; r < rep_xy.size() && found < 0; ++r)
                if (std::hypot(rep_xy[r].x - p.x, rep_xy[r].y - p.y) < snap_m) found = static_cast<int>(r);
            if (found < 0) found = static_cast<int>(rep_xy.size()), rep_xy.push_back(p);
            rep[v] = found;
        }
    }
    // Heights at every vertex: ground if on the outline, and each incident roof's plane.
    std::vector<VertexHeights> heights(rep_xy.size());
    auto roof_z = [&](int r, int plane) { return heights[r].canonical(planes[plane].z(rep_xy[r].x, rep_xy[r].y)); };
    // A ring of representatives without repeated neighbours or spikes (a-b-a); empty if degenerate.
    auto clean = [](std::vector<int> ids) {
        for (bool changed = true; changed && ids.size() >= 3;) {
            changed = false;
            for (std::size_t i = 0; i < ids.size() && ids.size() >= 3; ++i) {
                const std::size_t n = ids.size(), j = (i + 1) % n, k = (i + 2) % n;
                if (ids[i] == ids[j]) {
                    ids.erase(ids.begin() + static_cast<std::ptrdiff_t>(j));
                    changed = true;
                } else if (ids[i] == ids[k]) {
                    // Spike i -> j -> i: drop j and one copy of i.
                    const std::size_t first = std::min(j, k), second = std::max(j, k);
                    ids.erase(ids.begin() + static_cast<std::ptrdiff_t>(second));
                    ids.erase(ids.begin() + static_cast<std::ptrdiff_t>(first));
                    changed = true;
                }
            }
        }
        if (ids.size() < 3) ids.clear();
        return ids;
    };
    auto ccb_ids = [&](auto start) {
        std::vector<int> ids;
        auto h = start;
        do ids.push_back(rep.at(h->source()));
        while (++h != start);
        return clean(std::move(ids));
    };
    Solid& s = res.solid;
    std::set<int> used;
    // Roof faces as rings of representatives (faces collapsed by the snapping drop out).
    struct RoofRing {
        int label;
        std::vector<int> outer;
        std::vector<std::vector<int>> holes;
    };
    std::vector<RoofRing> roofs;
    for (auto f = arr.faces_begin(); f != arr.faces_end(); ++f) {
        const int l = f->data();
        if (l < 0) continue;
        RoofRing rr{l, ccb_ids(f->outer_ccb()), {}};
        if (rr.outer.empty()) continue;
        for (auto h = f->inner_ccbs_begin(); h != f->inner_ccbs_end(); ++h) {
            std::vector<int> hole = ccb_ids(*h);
            if (!hole.empty()) rr.holes.push_back(std::move(hole));
        }
        used.insert(l);
        roofs.push_back(std::move(rr));
    }
    // Directed edges of the surviving roofs: an edge without its reverse is on the outline.
    std::map<std::pair<int, int>, int> edge_label;
    auto each_edge = [](const RoofRing& rr, auto&& fn) {
        auto ring = [&](const std::vector<int>& ids) {
            for (std::size_t i = 0; i < ids.size(); ++i) fn(ids[i], ids[(i + 1) % ids.size()]);
        };
        ring(rr.outer);
        for (const auto& h : rr.holes) ring(h);
    };
    for (const RoofRing& rr : roofs) each_edge(rr, [&](int p, int q) { edge_label[{p, q}] = rr.label; });
    // Where snapping moved a crossing of two roofs off its vertex, the step wall
    // would twist; the roofs meet at the nearer end instead (off their planes by
    // at most half a few millimetres' gap).
    for (const RoofRing& rr : roofs)
        each_edge(rr, [&](int p, int q) {
            const auto back = edge_label.find({q, p});
            if (back == edge_label.end() || back->second == rr.label || rr.label > back->second) return;
            const RoofPlane& A = planes[rr.label];
            const RoofPlane& B = planes[back->second];
            const double dp = A.z(rep_xy[p].x, rep_xy[p].y) - B.z(rep_xy[p].x, rep_xy[p].y);
            const double dq = A.z(rep_xy[q].x, rep_xy[q].y) - B.z(rep_xy[q].x, rep_xy[q].y);
            if ((dp > 1e-4 && dq < -1e-4) || (dp < -1e-4 && dq > 1e-4)) {
                const int v = std::abs(dp) < std::abs(dq) ? p : q;
                heights[v].unify(A.z(rep_xy[v].x, rep_xy[v].y), B.z(rep_xy[v].x, rep_xy[v].y));
            }
        });
    for (auto v : vs) {
        const int r = rep.at(v);
        auto start = v->incident_halfedges(), h = start;
        do {
            const int l = h->face()->data();
            if (l == kOutside) heights[r].canonical(ground);
            else roof_z(r, l);
        } while (++h != start);
    }
    for (const RoofRing& rr : roofs) {
        Face face;
        face.type = SurfaceType::roof;
        auto to3 = [&](const std::vector<int>& ids) {
            Ring3 r;
            for (int id : ids) r.push_back({rep_xy[id].x, rep_xy[id].y, roof_z(id, rr.label)});
            return r;
        };
        face.outer = to3(rr.outer);
        for (const auto& h : rr.holes) face.holes.push_back(to3(h));
        s.faces.push_back(std::move(face));
    }
    // Walls: down to the ground along the outline, and at height steps between roofs (owned by the higher side).
    std::map<int, std::vector<int>> outline_next;  // ground cycle: q -> p for every outline roof edge p -> q
    for (const RoofRing& rr : roofs)
        each_edge(rr, [&](int p, int q) {
            const int a = rr.label;
            const auto back = edge_label.find({q, p});
            const int b = back == edge_label.end() ? kOutside : back->second;
            if (b == kOutside) outline_next[q].push_back(p);
            if (b == a) return;
            const XY pp = rep_xy[p], qq = rep_xy[q];
            const double zap = roof_z(p, a), zaq = roof_z(q, a);
            const double zbp = b < 0 ? heights[p].canonical(ground) : roof_z(p, b), zbq = b < 0 ? heights[q].canonical(ground) : roof_z(q, b);
            if (b >= 0 && zap == zbp && zaq == zbq) return;  // a ridge or valley: the roofs meet
            if (b >= 0) {
                const double mid_a = zap + zaq, mid_b = zbp + zbq;
                if (mid_a < mid_b || (mid_a == mid_b && a > b)) return;
            }
            Ring3 w;
            auto push = [&](double x, double y, double z) {
                const Point3 v{x, y, z};
                if (w.empty() || !(w.back() == v)) w.push_back(v);
            };
            push(pp.x, pp.y, zbp);
            push(qq.x, qq.y, zbq);
            for (double z : heights[q].between(zbq, zaq)) push(qq.x, qq.y, z);
            push(qq.x, qq.y, zaq);
            push(pp.x, pp.y, zap);
            for (double z : heights[p].between(zap, zbp)) push(pp.x, pp.y, z);
            if (w.size() > 1 && w.front() == w.back()) w.pop_back();
            if (w.size() >= 3) s.faces.push_back({std::move(w), {}, SurfaceType::wall});
        });
    // Ground: the outline cycles, reversed (facing down). Outer cycles run clockwise seen from above, holes counter-clockwise.
    {
        std::vector<std::vector<int>> cycles;
        for (auto& [start, nexts] : outline_next) {
            while (!nexts.empty()) {
                std::vector<int> cyc{start};
                int cur = nexts.back();
                nexts.pop_back();
                while (cur != start && cyc.size() <= rep_xy.size() + 1) {
                    cyc.push_back(cur);
                    auto it = outline_next.find(cur);
                    if (it == outline_next.end() || it->second.empty()) break;
                    const int nx = it->second.back();
                    it->second.pop_back();
                    cur = nx;
                }
                if (cur == start && cyc.size() >= 3) cycles.push_back(std::move(cyc));
            }
        }
        auto to3 = [&](const std::vector<int>& ids) {
            Ring3 r;
            for (int id : ids) r.push_back({rep_xy[id].x, rep_xy[id].y, ground});
            return r;
        };
        auto area2 = [&](const std::vector<int>& ids) {
            double a2 = 0;
            for (std::size_t i = 0; i < ids.size(); ++i) {
                const XY& u = rep_xy[ids[i]];
                const XY& v = rep_xy[ids[(i + 1) % ids.size()]];
                a2 += (u.x - rep_xy[ids[0]].x) * (v.y - rep_xy[ids[0]].y) - (v.x - rep_xy[ids[0]].x) * (u.y - rep_xy[ids[0]].y);
            }
            return a2;
        };
        std::vector<Face> grounds;
        std::vector<std::vector<int>> holes;
        for (auto& c : cycles) {
            if (area2(c) < 0) grounds.push_back({to3(c), {}, SurfaceType::ground});  // clockwise from above: an outer boundary
            else holes.push_back(c);
        }
        for (const auto& h : holes) {
            // The hole goes to the outer ring that contains it.
            const XY v = rep_xy[h[0]];
            for (Face& g : grounds) {
                Polygon pg;
                for (const Point3& q : g.outer) pg.outer.push_back({q.x, q.y});
                if (point_in_ring(pg.outer, v.x + 1e-9, v.y + 1e-9) || distance_to_boundary(pg, v.x, v.y) > 0) {
                    if (point_in_ring(pg.outer, v.x, v.y)) {
                        g.holes.push_back(to3(h));
                        break;
                    }
                }
            }
        }
        for (Face& g : grounds) s.faces.push_back(std::move(g));
    }
    // Outline eaves (for the roof type), and roofs that dip below the ground.
    for (auto e = arr.halfedges_begin(); e != arr.halfedges_end(); ++e)
        if (e->face()->data() >= 0 && e->twin()->face()->data() == kOutside) {
            const int plane = e->face()->data();
            const double z = roof_z(rep.at(e->source()), plane);
            res.eave_min = std::min(res.eave_min, z), res.eave_max = std::max(res.eave_max, z);
            if (planes[plane].slope_deg >= o.flat_slope_deg) {
                // The face lies left of its halfedge, so the outward normal is the edge turned right.
                const double dx = CGAL::to_double(e->target()->point().x() - e->source()->point().x());
                const double dy = CGAL::to_double(e->target()->point().y() - e->source()->point().y());
                const double len = std::hypot(dx, dy), g = std::hypot(planes[plane].a, planes[plane].b);
                if (len > 0 && g > 0) {
                    const double outward_downhill = (dy * -planes[plane].a + -dx * -planes[plane].b) / (len * g);
                    res.sloped_outline_m += len;
                    if (std::abs(outward_downhill) < 0.34) res.rake_m += len;  // downhill within 20 deg of the edge
                }
            }
            if (z < ground + o.min_roof_height_m) res.failure = "a roof plane runs below the ground at the outline";
        }
    res.used_planes.assign(used.begin(), used.end());
    return res;
}

// RMS of the 3-D distances of the points to the solids (roofs, walls,
// ground), in metres: map coordinates moved to a local metric frame first.
double rmse_to_solids(const std::vector<Solid>& solids, const std::vector<std::array<double, 3>>& pts, double ox, double oy, double oz,
                      const Lod2Options& o) {
    if (pts.empty() || solids.empty()) return 0.0;
    std::vector<Solid> local = solids;
    for (Solid& s : local)
        for (Face& f : s.faces) {
            auto to_local = [&](Ring3& r) {
                for (Point3& q : r) q = {(q.x - ox) * o.unit_m, (q.y - oy) * o.unit_m, (q.z - oz) * o.z_unit_m};
            };
            to_local(f.outer);
            for (Ring3& h : f.holes) to_local(h);
        }
    const SolidsDistance distance(local);
    double s2 = 0;
    for (const auto& q : pts) {
        const double d = distance({(q[0] - ox) * o.unit_m, (q[1] - oy) * o.unit_m, (q[2] - oz) * o.z_unit_m});
        if (std::isfinite(d)) s2 += d * d;
    }
    return std::sqrt(s2 / double(pts.size()));
}

Lod2Result reconstruct_once(const std::vector<Polygon>& footprint, const std::vector<std::array<double, 3>>& roof_points, double ground_z,
                            double fallback_roof_z, const Lod2Options& o, bool& retryable) {
    retryable = false;
    Lod2Result r;
    auto fallback = [&](const std::string& why) {
        r = Lod2Result{};
        r.fallback = true;
        r.fallback_reason = why;
        r.roof_type = "flat";
        const double top = std::max(fallback_roof_z, ground_z + o.min_roof_height_m / o.z_unit_m);
        for (const Polygon& part : footprint) {
            Polygon p = part;
            orient_polygon(p);
            r.solids.push_back(extrude_prism(p, ground_z, top));
        }
        if (!footprint.empty() && !footprint[0].outer.empty())
            r.rmse_m = rmse_to_solids(r.solids, roof_points, footprint[0].outer[0].x, footprint[0].outer[0].y, ground_z, o);
        return r;
    };
    if (footprint.empty()) return fallback("no footprint");
    if (static_cast<int>(roof_points.size()) < o.min_points) return fallback("too few roof points for planes");
    retryable = true;  // from here on, other plane settings may do better
    // Local metric frame: origin at the first outline vertex, z from the ground.
    const double ox = footprint[0].outer[0].x, oy = footprint[0].outer[0].y;
    std::vector<std::array<double, 3>> local(roof_points.size());
    for (std::size_t i = 0; i < roof_points.size(); ++i)
        local[i] = {(roof_points[i][0] - ox) * o.unit_m, (roof_points[i][1] - oy) * o.unit_m, (roof_points[i][2] - ground_z) * o.z_unit_m};
    std::vector<RoofPlane> planes;
    try {
        planes = detect_roof_planes(local, o.planes);
    } catch (const Error& e) {
        return fallback(e.what());
    }
    if (planes.empty()) return fallback("no roof plane found");
    std::vector<int> point_plane(local.size(), -1);
    for (std::size_t k = 0; k < planes.size(); ++k)
        for (uint32_t i : planes[k].points) point_plane[i] = static_cast<int>(k);

    std::set<int> used;
    double eave_min = INFINITY, eave_max = -INFINITY, sloped_outline_m = 0.0, rake_m = 0.0;
    for (const Polygon& part_map : footprint) {
        Polygon part = part_map;
        orient_polygon(part);
        for (MapPoint& q : part.outer) q = {(q.x - ox) * o.unit_m, (q.y - oy) * o.unit_m};
        for (Ring& h : part.holes)
            for (MapPoint& q : h) q = {(q.x - ox) * o.unit_m, (q.y - oy) * o.unit_m};
        std::vector<std::array<double, 3>> pts;
        std::vector<int> pp;
        for (std::size_t i = 0; i < local.size(); ++i)
            if (point_in_polygon(part, local[i][0], local[i][1])) pts.push_back(local[i]), pp.push_back(point_plane[i]);
        // The partition with the partition lines reaching line_extension_m
        // beyond their planes' boundary; when that solid fails to close
        // (four step walls meeting in one vertical edge, sliver faces), the
        // same planes partitioned with shorter and longer lines.
        PartResult pr;
        std::string failure;
        for (const double ext : {o.line_extension_m, 0.5 * o.line_extension_m, 1.5 * o.line_extension_m + 0.5}) {
            Lod2Options oe = o;
            oe.line_extension_m = ext;
            try {
                pr = build_part(part, pts, planes, pp, 0.0, oe);
            } catch (const std::exception& e) {
                if (failure.empty()) failure = std::string("partition failed: ") + e.what();
                continue;
            }
            if (!pr.failure.empty()) {
                if (failure.empty()) failure = pr.failure;
                continue;
            }
            const auto errors = validate_solid(pr.solid);
            if (!errors.empty()) {
                if (failure.empty()) failure = "reconstructed solid invalid: " + errors.front();
                continue;
            }
            // Again in map coordinates, where the exporters check it: rounding there can make a near-touch a touch.
            Solid in_map = pr.solid;
            for (Face& f : in_map.faces) {
                auto back = [&](Ring3& ring) {
                    for (Point3& q : ring) q = {ox + q.x / o.unit_m, oy + q.y / o.unit_m, ground_z + q.z / o.z_unit_m};
                };
                back(f.outer);
                for (Ring3& h : f.holes) back(h);
            }
            const auto map_errors = validate_solid(in_map);
            if (!map_errors.empty()) {
                if (failure.empty()) failure = "reconstructed solid invalid in map coordinates: " + map_errors.front();
                continue;
            }
            pr.solid = std::move(in_map);
            failure.clear();
            break;
        }
        if (!failure.empty()) return fallback(failure);
        used.insert(pr.used_planes.begin(), pr.used_planes.end());
        eave_min = std::min(eave_min, pr.eave_min), eave_max = std::max(eave_max, pr.eave_max);
        sloped_outline_m += pr.sloped_outline_m, rake_m += pr.rake_m;
        r.solids.push_back(std::move(pr.solid));
    }
    std::vector<RoofPlane> used_planes;
    for (int k : used) used_planes.push_back(planes[k]);
    r.roof_planes = static_cast<int>(used_planes.size());
    r.roof_type = classify_roof(used_planes, eave_max - eave_min, sloped_outline_m > 0 ? rake_m / sloped_outline_m : 1.0, o.flat_slope_deg);
    if (r.roof_type == "gable" && footprint.size() == 1) {
        Polygon part = footprint[0];
        for (MapPoint& q : part.outer) q = {(q.x - ox) * o.unit_m, (q.y - oy) * o.unit_m};
        for (Ring& hr : part.holes)
            for (MapPoint& q : hr) q = {(q.x - ox) * o.unit_m, (q.y - oy) * o.unit_m};
        if (gable_ends_dip(used_planes, part, local, o.flat_slope_deg)) r.roof_type = "hip";
    }
    const RoofPlane& main = planes[*used.begin()];  // planes are ordered by support: the lowest used index is the largest
    r.roof_slope_deg = main.slope_deg, r.roof_azimuth_deg = main.azimuth_deg;
    // Median residual: each point against the roof surface above it (the first roof face containing it in plan).
    std::vector<double> residuals;
    for (const Solid& s : r.solids) {
        std::vector<FaceHeight> roofs;
        for (const Face& f : s.faces)
            if (f.type == SurfaceType::roof) roofs.emplace_back(f);
        for (const auto& q : roof_points)
            for (const FaceHeight& roof : roofs)
                if (const std::optional<double> zf = roof(q[0], q[1])) {
                    residuals.push_back(std::abs(q[2] - *zf));
                    break;
                }
    }
    // RMSE: 3-D distance of every roof point to the model (facade points lie on its walls), as roofer reports it.
    r.rmse_m = rmse_to_solids(r.solids, roof_points, ox, oy, ground_z, o);
    if (!residuals.empty()) {
        std::nth_element(residuals.begin(), residuals.begin() + residuals.size() / 2, residuals.end());
        r.median_residual_m = residuals[residuals.size() / 2] * o.z_unit_m;
    }
    if (r.median_residual_m > o.max_median_residual_m) {
        std::ostringstream why;
        why << "roof planes miss their points (median residual " << r.median_residual_m << " m)";
        return fallback(why.str());
    }
    return r;
}

}  // namespace

Lod2Result reconstruct_lod2(const std::vector<Polygon>& footprint, const std::vector<std::array<double, 3>>& roof_points, double ground_z,
                            double fallback_roof_z, const Lod2Options& o) {
    o.validate();
    bool retryable = false;
    Lod2Result best = reconstruct_once(footprint, roof_points, ground_z, fallback_roof_z, o, retryable);
    if (!o.retry_alternatives || !retryable || (!best.fallback && best.rmse_m <= o.retry_rmse_m)) return best;
    // Plane detection and the partition are sensitive to their tolerances on
    // small, steep or cluttered roofs (Delft: steep gables with dormers, low
    // annexes); a few alternative settings, tried in a fixed order, and the
    // valid model closest to the points wins (ties keep the earlier one).
    std::vector<std::pair<std::string, Lod2Options>> alternatives;
    Lod2Options a = o;
    a.planes.normal_tolerance_deg = std::max(o.planes.normal_tolerance_deg, 20.0);
    if (a.planes.normal_tolerance_deg != o.planes.normal_tolerance_deg) alternatives.emplace_back("normal_tolerance_20deg", a);
    a = o;
    a.planes.min_points = std::max(3, std::min(6, o.planes.min_points / 2));
    if (a.planes.min_points != o.planes.min_points) alternatives.emplace_back("min_support_" + std::to_string(a.planes.min_points), a);
    a = o;
    a.line_extension_m = 2.0 * o.line_extension_m;
    if (a.line_extension_m != o.line_extension_m) alternatives.emplace_back("long_partition_lines", a);
    for (const auto& [name, ao] : alternatives) {
        bool unused = false;
        Lod2Result r = reconstruct_once(footprint, roof_points, ground_z, fallback_roof_z, ao, unused);
        if (r.fallback) continue;
        // Against a fallback too: a model farther from the points than the
        // flat roof it would replace is no better than that roof.
        if (r.rmse_m < best.rmse_m) {
            best = std::move(r);
            best.attempt = name;
        }
    }
    return best;
}

}  // namespace cityforge
