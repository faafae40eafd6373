#include "footprint/vectorize.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <unordered_map>

namespace cityforge {
namespace {

// Directed pixel-edge boundary: the region lies on the right when walking in
// pixel coordinates (x right, y down). dir: 0 east, 1 south, 2 west, 3 north.
struct Edge {
    int x, y, dir;
};
constexpr int kDx[4] = {1, 0, -1, 0};
constexpr int kDy[4] = {0, 1, 0, -1};

std::vector<std::vector<std::array<int, 2>>> trace_rings(std::vector<Edge>& edges, int w) {
    // Outgoing edges per start vertex (at most 2: pinch vertices).
    std::unordered_map<int64_t, std::array<int, 2>> out;
    out.reserve(edges.size() * 2);
    auto key = [w](int x, int y) { return static_cast<int64_t>(y) * (w + 1) + x; };
    for (int i = 0; i < static_cast<int>(edges.size()); ++i) {
        auto [it, inserted] = out.try_emplace(key(edges[i].x, edges[i].y), std::array<int, 2>{i, -1});
        if (!inserted) it->second[1] = i;
    }
    std::vector<uint8_t> used(edges.size(), 0);
    std::vector<std::vector<std::array<int, 2>>> rings;
    for (int start = 0; start < static_cast<int>(edges.size()); ++start) {
        if (used[start]) continue;
        std::vector<std::array<int, 2>> ring;
        int e = start;
        while (!used[e]) {
            used[e] = 1;
            const Edge& cur = edges[e];
            const int nx = cur.x + kDx[cur.dir], ny = cur.y + kDy[cur.dir];
            const auto& cand = out.at(key(nx, ny));
            int next = cand[0];
            if (cand[1] >= 0) {
                // Pinch vertex: turn right (towards the region) so that diagonal
                // pixels stay apart and rings touch without crossing.
                const int right = (cur.dir + 1) % 4;
                next = edges[cand[0]].dir == right ? cand[0] : cand[1];
                if (used[next]) next = next == cand[0] ? cand[1] : cand[0];
            }
            // Keep only corners: a vertex where the direction changes.
            if (edges[next].dir != cur.dir) ring.push_back({nx, ny});
            e = next;
        }
        rings.push_back(std::move(ring));
    }
    return rings;
}

std::vector<Polygon> assemble(const std::vector<std::vector<std::array<int, 2>>>& rings, const GeoTransform& t) {
    std::vector<Polygon> outers;
    std::vector<Ring> holes;
    for (const auto& r : rings) {
        Ring ring;
        ring.reserve(r.size());
        for (const auto& p : r) ring.push_back(t.pixel_to_map({double(p[0]), double(p[1])}));
        // Walking with the region on the right (E, S, W, N around a pixel) gives
        // exterior rings of negative signed area on a north-up map; holes positive.
        const double a = signed_area(ring) * (t.pixel_height < 0 ? 1.0 : -1.0);
        if (a < 0) outers.push_back({ring, {}});
        else holes.push_back(ring);
    }
    for (Ring& h : holes) {
        // A hole belongs to the smallest exterior containing the midpoint of its
        // first edge (a pixel edge strictly inside that exterior).
        const MapPoint m{0.5 * (h[0].x + h[1].x), 0.5 * (h[0].y + h[1].y)};
        int best = -1;
        double best_area = INFINITY;
        for (int i = 0; i < static_cast<int>(outers.size()); ++i) {
            if (!point_in_ring(outers[i].outer, m.x, m.y)) continue;
            const double a = std::abs(signed_area(outers[i].outer));
            if (a < best_area) best_area = a, best = i;
        }
        if (best >= 0) outers[best].holes.push_back(std::move(h));
    }
    for (Polygon& p : outers) orient_polygon(p);
    // Deterministic order: by the exterior's first vertex (top-left corner first).
    std::sort(outers.begin(), outers.end(), [](const Polygon& a, const Polygon& b) {
        return a.outer[0].y != b.outer[0].y ? a.outer[0].y > b.outer[0].y : a.outer[0].x < b.outer[0].x;
    });
    return outers;
}

void emit_edges(const Image<uint32_t>& labels, int x, int y, uint32_t v, std::vector<Edge>& edges) {
    const int w = labels.width, h = labels.height;
    const uint32_t* l = labels.band_data(0);
    auto at = [&](int xx, int yy) { return (xx < 0 || yy < 0 || xx >= w || yy >= h) ? 0u : l[static_cast<std::size_t>(yy) * w + xx]; };
    if (at(x, y - 1) != v) edges.push_back({x, y, 0});
    if (at(x + 1, y) != v) edges.push_back({x + 1, y, 1});
    if (at(x, y + 1) != v) edges.push_back({x + 1, y + 1, 2});
    if (at(x - 1, y) != v) edges.push_back({x, y + 1, 3});
}

}  // namespace

Polygon fill_pinched_pockets(const Polygon& polygon) {
    const Ring& ring = polygon.outer;
    const double sign = signed_area(ring) < 0 ? -1.0 : 1.0;
    auto same = [](const MapPoint& a, const MapPoint& b) { return a.x == b.x && a.y == b.y; };
    // Cut at every repeated vertex (a stack of the vertices since each one's
    // first visit): each loop closed there is a ring of its own.
    std::vector<Ring> loops;
    Ring stack;
    for (const MapPoint& p : ring) {
        std::size_t at = stack.size();
        for (std::size_t i = 0; i < stack.size(); ++i)
            if (same(stack[i], p)) {
                at = i;
                break;
            }
        if (at == stack.size()) {
            stack.push_back(p);
            continue;
        }
        loops.emplace_back(stack.begin() + static_cast<std::ptrdiff_t>(at), stack.end());
        stack.resize(at + 1);
    }
    if (loops.empty()) return polygon;
    loops.push_back(std::move(stack));
    // One loop of the exterior's orientation (the outline), the others
    // pockets (the opposite one) or degenerate; anything else, e.g. two
    // pieces touching at a corner, is left unchanged (not ours to drop).
    std::size_t outline = loops.size();
    for (std::size_t i = 0; i < loops.size(); ++i) {
        if (loops[i].size() < 3) continue;
        const double a = signed_area(loops[i]) * sign;
        if (a > 0) {
            if (outline != loops.size()) return polygon;
            outline = i;
        }
    }
    if (outline == loops.size()) return polygon;
    Polygon out = polygon;
    out.outer = std::move(loops[outline]);
    return out;
}

std::vector<Polygon> vectorize_region(const Image<uint32_t>& labels, uint32_t region, const GeoTransform& t) {
    std::vector<Edge> edges;
    const uint32_t* l = labels.band_data(0);
    for (int y = 0; y < labels.height; ++y)
        for (int x = 0; x < labels.width; ++x)
            if (l[static_cast<std::size_t>(y) * labels.width + x] == region) emit_edges(labels, x, y, region, edges);
    if (edges.empty()) return {};
    return assemble(trace_rings(edges, labels.width), t);
}

std::vector<std::vector<Polygon>> vectorize_all(const Image<uint32_t>& labels, const GeoTransform& t) {
    uint32_t max_label = 0;
    for (uint32_t v : labels.data) max_label = std::max(max_label, v);
    std::vector<std::vector<Edge>> edges(max_label + 1);
    const uint32_t* l = labels.band_data(0);
    for (int y = 0; y < labels.height; ++y)
        for (int x = 0; x < labels.width; ++x) {
            const uint32_t v = l[static_cast<std::size_t>(y) * labels.width + x];
            if (v) emit_edges(labels, x, y, v, edges[v]);
        }
    std::vector<std::vector<Polygon>> out(max_label + 1);
    for (uint32_t v = 1; v <= max_label; ++v)
        if (!edges[v].empty()) out[v] = assemble(trace_rings(edges[v], labels.width), t);
    return out;
}

namespace {
void douglas_peucker(const Ring& r, std::size_t a, std::size_t b, double tol2, std::vector<uint8_t>& keep) {
    if (b <= a + 1) return;
    const MapPoint& p = r[a];
    const MapPoint& q = r[b % r.size()];
    const double dx = q.x - p.x, dy = q.y - p.y, len2 = dx * dx + dy * dy;
    double best = -1.0;
    std::size_t idx = a;
    for (std::size_t i = a + 1; i < b; ++i) {
        const double ex = r[i].x - p.x, ey = r[i].y - p.y;
        const double d2 = len2 > 0 ? std::pow(ex * dy - ey * dx, 2) / len2 : ex * ex + ey * ey;
        if (d2 > best) best = d2, idx = i;
    }
    if (best > tol2) {
        keep[idx] = 1;
        douglas_peucker(r, a, idx, tol2, keep);
        douglas_peucker(r, idx, b, tol2, keep);
    }
}

Ring simplify_ring(const Ring& r, double tol) {
    if (r.size() <= 4 || tol <= 0) return r;
    // Anchor at vertex 0 and the vertex farthest from it, then simplify both halves.
    std::size_t far = 0;
    double best = -1;
    for (std::size_t i = 1; i < r.size(); ++i) {
        const double d = std::hypot(r[i].x - r[0].x, r[i].y - r[0].y);
        if (d > best) best = d, far = i;
    }
    std::vector<uint8_t> keep(r.size(), 0);
    keep[0] = keep[far] = 1;
    douglas_peucker(r, 0, far, tol * tol, keep);
    douglas_peucker(r, far, r.size(), tol * tol, keep);
    Ring out;
    for (std::size_t i = 0; i < r.size(); ++i)
        if (keep[i]) out.push_back(r[i]);
    return out.size() >= 3 ? out : r;
}
}  // namespace

Polygon simplify_polygon(const Polygon& p, double tolerance) {
    Polygon out;
    out.outer = simplify_ring(p.outer, tolerance);
    for (const Ring& h : p.holes) out.holes.push_back(simplify_ring(h, tolerance));
    return out;
}

}  // namespace cityforge
