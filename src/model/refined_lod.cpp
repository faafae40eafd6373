#include "model/refined_lod.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <numeric>
#include <optional>
#include <utility>

#include "model/face_mesh.hpp"

namespace cityforge {
namespace {

using Key2 = std::pair<int64_t, int64_t>;
using Key3 = std::array<int64_t, 3>;

// Vertices closer than the snap tolerance are one vertex (as validate_solid sees them).
struct Snap {
    double q;
    Key2 k2(const Point3& p) const { return {std::llround(p.x / q), std::llround(p.y / q)}; }
    Key3 k3(const Point3& p) const { return {std::llround(p.x / q), std::llround(p.y / q), std::llround(p.z / q)}; }
};

template <typename Fn>
void for_each_edge(const Face& f, Fn fn) {
    auto ring = [&](const Ring3& r) {
        for (std::size_t i = 0; i < r.size(); ++i) fn(r[i], r[(i + 1) % r.size()]);
    };
    ring(f.outer);
    for (const Ring3& h : f.holes) ring(h);
}

struct UnionFind {
    std::vector<std::size_t> up;
    explicit UnionFind(std::size_t n) : up(n) { std::iota(up.begin(), up.end(), std::size_t{0}); }
    std::size_t find(std::size_t i) {
        while (up[i] != i) i = up[i] = up[up[i]];
        return i;
    }
    void join(std::size_t a, std::size_t b) {
        a = find(a), b = find(b);
        if (a != b) up[std::max(a, b)] = std::min(a, b);
    }
};

double plan_area2(const Ring3& r) {
    double a = 0;
    for (std::size_t i = 0; i < r.size(); ++i) {
        const Point3& p = r[i];
        const Point3& q = r[(i + 1) % r.size()];
        a += p.x * q.y - q.x * p.y;
    }
    return a;
}

Ring3 reversed_at(const Ring3& r, double z) {
    Ring3 out;
    for (auto it = r.rbegin(); it != r.rend(); ++it) out.push_back({it->x, it->y, z});
    return out;
}

// The q-quantile (0..1), by plan area, of the height of the roof faces: each
// triangle sampled at the centroids of its 16 sub-triangles.
double area_quantile_z(const std::vector<const Face*>& roofs, double q) {
    std::vector<std::pair<double, double>> samples;  // z, plan area
    double top = -INFINITY, total = 0;
    constexpr int n = 4;
    for (const Face* f : roofs) {
        const std::vector<Point3> v = face_vertices(*f);
        for (const Point3& p : v) top = std::max(top, p.z);
        for (const auto& t : triangulate_face(*f)) {
            const Point3 &a = v[t[0]], &b = v[t[1]], &c = v[t[2]];
            const double area = 0.5 * std::abs((b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y));
            if (!(area > 0)) continue;
            const double w = area / (n * n);
            auto sample = [&](double u, double s) { samples.emplace_back(a.z + u * (b.z - a.z) + s * (c.z - a.z), w), total += w; };
            for (int i = 0; i < n; ++i)
                for (int j = 0; i + j < n; ++j) {
                    sample((i + 1.0 / 3) / n, (j + 1.0 / 3) / n);
                    if (i + j < n - 1) sample((i + 2.0 / 3) / n, (j + 2.0 / 3) / n);
                }
        }
    }
    if (samples.empty()) return top;
    std::sort(samples.begin(), samples.end());
    double acc = 0;
    for (const auto& [z, w] : samples)
        if ((acc += w) >= q * total) return z;
    return samples.back().first;
}

struct PartShape {
    Solid solid;   // roof faces, walls to the ground, ground face
    Polygon plan;  // outline: outer counter-clockwise, holes clockwise
};

// The closed solid of a set of edge-connected roof faces: walls along the
// outline (edges no other roof face of the set has) down to `ground`, step
// walls where two faces of the set share an edge at different heights, and a
// ground face. Every wall's vertical edges are split at the heights other faces
// meet there, so that each vertical segment has exactly two faces. Fails
// (nullopt, `why`) on roofs that cross along a shared edge or an outline that
// touches itself.
std::optional<PartShape> part_shape(const std::vector<const Face*>& roofs, double ground, const Snap& s, std::string& why) {
    std::map<std::pair<Key2, Key2>, std::pair<Point3, Point3>> edges;  // directed plan edge -> its 3-D ends
    std::map<Key2, std::vector<double>> heights;                        // plan vertex -> the heights faces meet at
    for (const Face* f : roofs) {
        bool dup = false;
        for_each_edge(*f, [&](const Point3& p, const Point3& q) {
            heights[s.k2(p)].push_back(p.z);
            if (s.k2(p) != s.k2(q)) dup = !edges.emplace(std::make_pair(s.k2(p), s.k2(q)), std::make_pair(p, q)).second || dup;
        });
        if (dup) return why = "roof faces overlap in plan", std::nullopt;
    }
    auto zkey = [&](double z) { return std::llround(z / s.q); };
    std::map<Key2, std::pair<Point3, Point3>> next;  // outline: start -> edge
    struct Step {
        Point3 a, b;        // top ends (the higher face's), a -> b with the lower face on the right
        double za, zb;      // bottom heights (the lower face's) at a and b
    };
    std::vector<Step> steps;
    for (const auto& [k, e] : edges) {
        const auto rev = edges.find({k.second, k.first});
        if (rev == edges.end()) {
            heights[k.first].push_back(ground);
            if (!next.emplace(k.first, e).second) return why = "the roof part's outline touches itself", std::nullopt;
            continue;
        }
        const double la = e.first.z, lb = e.second.z, ra = rev->second.second.z, rb = rev->second.first.z;
        const int64_t dla = zkey(la) - zkey(ra), dlb = zkey(lb) - zkey(rb);
        if (dla == 0 && dlb == 0) continue;                                   // a ridge, hip, valley or flat join
        if ((dla < 0 && dlb > 0) || (dla > 0 && dlb < 0)) return why = "two roof faces cross along their shared edge", std::nullopt;
        if (dla >= 0 && dlb >= 0) steps.push_back({e.first, e.second, ra, rb});  // this side is the higher: its wall
    }
    for (auto& [k, v] : heights) {
        std::sort(v.begin(), v.end());
        v.erase(std::unique(v.begin(), v.end(), [&](double x, double y) { return zkey(x) == zkey(y); }), v.end());
    }
    // Outline rings, each with its edges' own 3-D ends: where a step fades out at an
    // outline vertex, the edges before and after it end and start there at different heights.
    using Edges3 = std::vector<std::pair<Point3, Point3>>;
    std::vector<Ring3> outers, holes;
    std::vector<Edges3> outer_edges, hole_edges;
    std::map<Key2, bool> used;
    for (const auto& [start, e0] : next) {
        if (used[start]) continue;
        Ring3 ring;
        Edges3 ring_edges;
        Key2 k = start;
        while (!used[k]) {
            used[k] = true;
            const auto it = next.find(k);
            if (it == next.end()) return why = "the roof part's outline is open", std::nullopt;
            ring.push_back(it->second.first);
            ring_edges.push_back(it->second);
            k = s.k2(it->second.second);
        }
        if (k != start) return why = "the roof part's outline is open", std::nullopt;
        const bool outer = plan_area2(ring) > 0;
        (outer ? outers : holes).push_back(std::move(ring));
        (outer ? outer_edges : hole_edges).push_back(std::move(ring_edges));
    }
    if (outers.size() != 1) return why = "the roof part has " + std::to_string(outers.size()) + " outlines", std::nullopt;
    PartShape out;
    for (const Face* f : roofs) out.solid.faces.push_back(*f);
    // A vertical wall below the edge p -> q (outside on its right), from za / zb up to p.z / q.z.
    auto wall = [&](const Point3& p, const Point3& q, double za, double zb) {
        Face w;
        w.type = SurfaceType::wall;
        auto push = [&](double x, double y, double z) {
            if (w.outer.empty() || zkey(w.outer.back().z) != zkey(z) || s.k2(w.outer.back()) != s.k2(Point3{x, y, z})) w.outer.push_back({x, y, z});
        };
        push(p.x, p.y, za), push(q.x, q.y, zb);
        for (double h : heights[s.k2(q)])
            if (zkey(h) > zkey(zb) && zkey(h) < zkey(q.z)) push(q.x, q.y, h);
        push(q.x, q.y, q.z), push(p.x, p.y, p.z);
        const std::vector<double>& hp = heights[s.k2(p)];
        for (auto it = hp.rbegin(); it != hp.rend(); ++it)
            if (zkey(*it) < zkey(p.z) && zkey(*it) > zkey(za)) push(p.x, p.y, *it);
        if (w.outer.size() > 1 && zkey(w.outer.back().z) == zkey(w.outer.front().z) && s.k2(w.outer.back()) == s.k2(w.outer.front())) w.outer.pop_back();
        if (w.outer.size() >= 3) out.solid.faces.push_back(std::move(w));
    };
    auto outline_walls = [&](const Edges3& r) {
        for (const auto& [p, q] : r) wall(p, q, ground, ground);
    };
    outline_walls(outer_edges[0]);
    for (const Edges3& h : hole_edges) outline_walls(h);
    for (const Step& st : steps) wall(st.a, st.b, st.za, st.zb);
    Face g;
    g.type = SurfaceType::ground;
    g.outer = reversed_at(outers[0], ground);
    for (const Ring3& h : holes) g.holes.push_back(reversed_at(h, ground));
    out.solid.faces.push_back(std::move(g));
    auto plan_ring = [](const Ring3& r) {
        Ring o;
        for (const Point3& p : r) o.push_back({p.x, p.y});
        return o;
    };
    out.plan.outer = plan_ring(outers[0]);
    for (const Ring3& h : holes) out.plan.holes.push_back(plan_ring(h));
    return out;
}

double ground_of(const Solid& s) {
    double g = INFINITY;
    for (const Face& f : s.faces)
        if (f.type == SurfaceType::ground)
            for (const Point3& p : f.outer) g = std::min(g, p.z);
    if (std::isfinite(g)) return g;
    for (const Face& f : s.faces)
        for (const Point3& p : f.outer) g = std::min(g, p.z);
    return g;
}

void finish(RoofPart& p, const std::vector<const Face*>& roofs, const Polygon& plan, const SolidValidityOptions& validity) {
    p.lod13_roof_z = area_quantile_z(roofs, 0.7);
    if (p.lod13_roof_z > p.ground_z) {
        p.lod13 = extrude_prism(plan, p.ground_z, p.lod13_roof_z);
        p.lod13_errors = validate_solid(p.lod13, validity);
        p.lod13_volume = solid_volume(p.lod13);
    } else {
        p.lod13_errors = {"roof part not above the ground"};
    }
    p.lod22_errors = validate_solid(p.lod22, validity);
    p.lod22_volume = solid_volume(p.lod22);
}

}  // namespace

RoofPartsResult roof_parts(const std::vector<Solid>& lod2, const SolidValidityOptions& validity) {
    RoofPartsResult res;
    const Snap snap{std::max(validity.snap_tolerance, 1e-9)};
    for (std::size_t si = 0; si < lod2.size(); ++si) {
        const Solid& solid = lod2[si];
        std::vector<const Face*> roofs;
        for (const Face& f : solid.faces)
            if (f.type == SurfaceType::roof) roofs.push_back(&f);
        if (roofs.empty()) continue;
        const double ground = ground_of(solid);
        // Join roof faces that share an edge with the same 3-D ends.
        UnionFind uf(roofs.size());
        std::map<std::pair<Key3, Key3>, std::size_t> owner;
        for (std::size_t i = 0; i < roofs.size(); ++i)
            for_each_edge(*roofs[i], [&](const Point3& p, const Point3& q) { owner.emplace(std::make_pair(snap.k3(p), snap.k3(q)), i); });
        for (std::size_t i = 0; i < roofs.size(); ++i)
            for_each_edge(*roofs[i], [&](const Point3& p, const Point3& q) {
                const auto it = owner.find({snap.k3(q), snap.k3(p)});
                if (it != owner.end()) uf.join(i, it->second);
            });
        std::vector<std::vector<const Face*>> groups;
        std::map<std::size_t, std::size_t> group_of_root;
        for (std::size_t i = 0; i < roofs.size(); ++i) {
            const auto [it, fresh] = group_of_root.emplace(uf.find(i), groups.size());
            if (fresh) groups.emplace_back();
            groups[it->second].push_back(roofs[i]);
        }
        std::vector<RoofPart> parts;
        std::string why;
        if (groups.size() > 1) {
            for (const auto& g : groups) {
                std::optional<PartShape> shape = part_shape(g, ground, snap, why);
                if (!shape) break;
                RoofPart p;
                p.solid = si, p.ground_z = ground, p.lod22 = std::move(shape->solid);
                finish(p, g, shape->plan, validity);
                if (!p.lod22_errors.empty()) {
                    why = "a roof part's solid is invalid (" + p.lod22_errors.front() + ")";
                    break;
                }
                parts.push_back(std::move(p));
            }
            if (parts.size() != groups.size()) {
                res.unsplit.push_back("solid " + std::to_string(si) + ": " + why);
                parts.clear();
            }
        }
        if (parts.empty()) {  // one part: the solid itself, its block over its outline
            RoofPart p;
            p.solid = si, p.ground_z = ground, p.lod22 = solid;
            std::string ignored;
            const std::optional<PartShape> shape = part_shape(roofs, ground, snap, ignored);
            Polygon plan;
            if (shape) {
                plan = shape->plan;
            } else {  // the ground face, seen from above
                for (const Face& f : solid.faces)
                    if (f.type == SurfaceType::ground) {
                        plan = face_plan(f);
                        std::reverse(plan.outer.begin(), plan.outer.end());
                        for (Ring& h : plan.holes) std::reverse(h.begin(), h.end());
                        break;
                    }
            }
            finish(p, roofs, plan, validity);
            parts.push_back(std::move(p));
        }
        for (RoofPart& p : parts) res.parts.push_back(std::move(p));
    }
    return res;
}

}  // namespace cityforge
