#include "model/solid.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <tuple>

#include "core/error.hpp"

namespace cityforge {

const char* citygml_name(SurfaceType t) {
    switch (t) {
        case SurfaceType::ground: return "GroundSurface";
        case SurfaceType::wall: return "WallSurface";
        case SurfaceType::roof: return "RoofSurface";
    }
    return "WallSurface";
}

Solid extrude_prism(const Polygon& footprint, double z0, double z1) {
    if (!(z1 > z0)) throw Error("extrusion", "top must be above bottom");
    Solid s;
    auto lift = [](const Ring& r, double z) {
        Ring3 out;
        out.reserve(r.size());
        for (const MapPoint& p : r) out.push_back({p.x, p.y, z});
        return out;
    };
    Face roof{lift(footprint.outer, z1), {}, SurfaceType::roof};
    for (const Ring& h : footprint.holes) roof.holes.push_back(lift(h, z1));
    Face ground{lift(footprint.outer, z0), {}, SurfaceType::ground};
    std::reverse(ground.outer.begin(), ground.outer.end());
    for (const Ring& h : footprint.holes) {
        ground.holes.push_back(lift(h, z0));
        std::reverse(ground.holes.back().begin(), ground.holes.back().end());
    }
    s.faces.push_back(std::move(ground));
    auto walls = [&](const Ring& r) {
        for (std::size_t i = 0; i < r.size(); ++i) {
            const MapPoint a = r[i], b = r[(i + 1) % r.size()];
            s.faces.push_back({{{a.x, a.y, z0}, {b.x, b.y, z0}, {b.x, b.y, z1}, {a.x, a.y, z1}}, {}, SurfaceType::wall});
        }
    };
    walls(footprint.outer);
    for (const Ring& h : footprint.holes) walls(h);
    s.faces.push_back(std::move(roof));
    return s;
}

namespace {

// Newell's normal of a ring (length = 2 x area of its projection).
std::array<double, 3> newell(const Ring3& r) {
    std::array<double, 3> n{0, 0, 0};
    for (std::size_t i = 0; i < r.size(); ++i) {
        const Point3& a = r[i];
        const Point3& b = r[(i + 1) % r.size()];
        n[0] += (a.y - b.y) * (a.z + b.z);
        n[1] += (a.z - b.z) * (a.x + b.x);
        n[2] += (a.x - b.x) * (a.y + b.y);
    }
    return n;
}

double norm(const std::array<double, 3>& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

}  // namespace

Polygon face_plan(const Face& f) {
    Polygon p;
    for (const Point3& v : f.outer) p.outer.push_back({v.x, v.y});
    for (const Ring3& h : f.holes) {
        p.holes.emplace_back();
        for (const Point3& v : h) p.holes.back().push_back({v.x, v.y});
    }
    return p;
}

FaceHeight::FaceHeight(const Face& f) {
    if (f.outer.size() < 3) return;
    n_ = newell(f.outer);
    if (std::abs(n_[2]) < 1e-12 * (std::abs(n_[0]) + std::abs(n_[1]) + 1.0)) return;
    usable_ = true;
    plan_ = face_plan(f);
    for (const Point3& v : f.outer) cx_ += v.x, cy_ += v.y, cz_ += v.z;
    const double k = double(f.outer.size());
    cx_ /= k, cy_ /= k, cz_ /= k;
    min_x_ = max_x_ = f.outer[0].x, min_y_ = max_y_ = f.outer[0].y;
    for (const Point3& v : f.outer)
        min_x_ = std::min(min_x_, v.x), max_x_ = std::max(max_x_, v.x), min_y_ = std::min(min_y_, v.y), max_y_ = std::max(max_y_, v.y);
}

std::optional<double> FaceHeight::operator()(double x, double y) const {
    if (!usable_ || x < min_x_ || x > max_x_ || y < min_y_ || y > max_y_) return std::nullopt;
    if (!point_in_polygon(plan_, x, y)) return std::nullopt;
    return cz_ - (n_[0] * (x - cx_) + n_[1] * (y - cy_)) / n_[2];
}

std::optional<double> face_z_at(const Face& f, double x, double y) { return FaceHeight(f)(x, y); }

SolidsDistance::PreparedFace::PreparedFace(const Face& f) : face(&f) {
    if (f.outer.size() < 3) return;
    const auto n = newell(f.outer);
    const double len = norm(n);
    min[0] = min[1] = min[2] = INFINITY, max[0] = max[1] = max[2] = -INFINITY;
    auto grow = [&](const Ring3& r) {
        for (const Point3& q : r) {
            min[0] = std::min(min[0], q.x), min[1] = std::min(min[1], q.y), min[2] = std::min(min[2], q.z);
            max[0] = std::max(max[0], q.x), max[1] = std::max(max[1], q.y), max[2] = std::max(max[2], q.z);
        }
    };
    grow(f.outer);
    for (const Ring3& h : f.holes) grow(h);
    if (!(len > 0)) return;
    has_plane = true;
    nx = n[0] / len, ny = n[1] / len, nz = n[2] / len;
    // Inside test in the plane of the two axes the normal is least along.
    drop = std::abs(nx) >= std::abs(ny) && std::abs(nx) >= std::abs(nz) ? 0 : std::abs(ny) >= std::abs(nz) ? 1 : 2;
    auto uv = [&](const Point3& q) { return drop == 0 ? MapPoint{q.y, q.z} : drop == 1 ? MapPoint{q.z, q.x} : MapPoint{q.x, q.y}; };
    for (const Point3& q : f.outer) plan.outer.push_back(uv(q));
    for (const Ring3& h : f.holes) {
        plan.holes.emplace_back();
        for (const Point3& q : h) plan.holes.back().push_back(uv(q));
    }
}

double SolidsDistance::PreparedFace::distance(const Point3& p) const {
    const Face& f = *face;
    if (f.outer.size() < 3) return INFINITY;
    auto segment = [&](const Point3& a, const Point3& b) {
        const double ux = b.x - a.x, uy = b.y - a.y, uz = b.z - a.z;
        const double l2 = ux * ux + uy * uy + uz * uz;
        double t = l2 > 0 ? ((p.x - a.x) * ux + (p.y - a.y) * uy + (p.z - a.z) * uz) / l2 : 0.0;
        t = std::clamp(t, 0.0, 1.0);
        const double dx = p.x - (a.x + t * ux), dy = p.y - (a.y + t * uy), dz = p.z - (a.z + t * uz);
        return std::sqrt(dx * dx + dy * dy + dz * dz);
    };
    if (has_plane) {
        const Point3& o = f.outer[0];
        const double d = (p.x - o.x) * nx + (p.y - o.y) * ny + (p.z - o.z) * nz;
        const Point3 proj{p.x - d * nx, p.y - d * ny, p.z - d * nz};
        const MapPoint pp = drop == 0 ? MapPoint{proj.y, proj.z} : drop == 1 ? MapPoint{proj.z, proj.x} : MapPoint{proj.x, proj.y};
        if (point_in_polygon(plan, pp.x, pp.y)) return std::abs(d);
    }
    double best = INFINITY;
    auto ring = [&](const Ring3& r) {
        for (std::size_t i = 0; i < r.size(); ++i) best = std::min(best, segment(r[i], r[(i + 1) % r.size()]));
    };
    ring(f.outer);
    for (const Ring3& h : f.holes) ring(h);
    return best;
}

double SolidsDistance::PreparedFace::lower_bound(const Point3& p) const {
    if (face->outer.size() < 3) return INFINITY;
    const double bx = std::max({min[0] - p.x, 0.0, p.x - max[0]});
    const double by = std::max({min[1] - p.y, 0.0, p.y - max[1]});
    const double bz = std::max({min[2] - p.z, 0.0, p.z - max[2]});
    double lb = std::sqrt(bx * bx + by * by + bz * bz);
    if (has_plane) {
        const Point3& o = face->outer[0];
        lb = std::max(lb, std::abs((p.x - o.x) * nx + (p.y - o.y) * ny + (p.z - o.z) * nz));
    }
    return lb;
}

SolidsDistance::SolidsDistance(const std::vector<Solid>& solids) {
    for (const Solid& s : solids)
        for (const Face& f : s.faces) faces_.emplace_back(f);
}

double SolidsDistance::operator()(const Point3& p) const {
    double best = INFINITY;
    for (const PreparedFace& f : faces_) {
        // The bound and the distance round differently: a face is skipped only
        // when its bound clears the best by far more than rounding, so the
        // minimum is the one every face would give.
        if (f.lower_bound(p) > best + 1e-6 * (1.0 + best)) continue;
        best = std::min(best, f.distance(p));
    }
    return best;
}

double distance_to_face(const Face& f, const Point3& p) { return SolidsDistance::PreparedFace(f).distance(p); }

double distance_to_solid(const Solid& s, const Point3& p) {
    double best = INFINITY;
    for (const Face& f : s.faces) best = std::min(best, distance_to_face(f, p));
    return best;
}

double face_area(const Face& f) {
    const auto n = newell(f.outer);
    const double len = norm(n);
    if (len == 0) return 0.0;
    double a = len / 2.0;
    for (const Ring3& h : f.holes) {
        const auto m = newell(h);
        a -= std::abs(m[0] * n[0] + m[1] * n[1] + m[2] * n[2]) / len / 2.0;
    }
    return a;
}

double solid_volume(const Solid& s) {
    // Sum over faces of (centroid-free) signed tetrahedra from the origin; a
    // local origin keeps the sums exact for projected coordinates.
    if (s.faces.empty() || s.faces[0].outer.empty()) return 0.0;
    const Point3 o = s.faces[0].outer[0];
    double v = 0.0;
    auto ring = [&](const Ring3& r) {
        for (std::size_t i = 1; i + 1 < r.size(); ++i) {
            const double ax = r[0].x - o.x, ay = r[0].y - o.y, az = r[0].z - o.z;
            const double bx = r[i].x - o.x, by = r[i].y - o.y, bz = r[i].z - o.z;
            const double cx = r[i + 1].x - o.x, cy = r[i + 1].y - o.y, cz = r[i + 1].z - o.z;
            v += ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx);
        }
    };
    // Fan triangulation is exact for the signed volume of any planar ring
    // (convex or not); holes are wound the other way and subtract.
    for (const Face& f : s.faces) {
        ring(f.outer);
        for (const Ring3& h : f.holes) ring(h);
    }
    return v / 6.0;
}

namespace {

bool segments_cross(double ax, double ay, double bx, double by, double cx, double cy, double dx, double dy, double tol) {
    // Orientation with a tolerance: a point within `tol` (a few ulps of the
    // coordinates) or 1e-9 of its distance from the line counts as on it, so rounding (map coordinates, an outline edge split by
    // partition lines) cannot make disjoint collinear pieces of one edge "cross".
    auto orient = [tol](double px, double py, double qx, double qy, double rx, double ry) {
        const double v = (qx - px) * (ry - py) - (qy - py) * (rx - px);
        const double pq = std::hypot(qx - px, qy - py), pr = std::hypot(rx - px, ry - py);
        if (std::abs(v) <= std::max(tol * (pq + pr), 1e-9 * pq * pr)) return 0;
        return (v > 0) - (v < 0);
    };
    auto on = [](double px, double py, double qx, double qy, double rx, double ry) {
        return std::min(px, qx) <= rx && rx <= std::max(px, qx) && std::min(py, qy) <= ry && ry <= std::max(py, qy);
    };
    const int o1 = orient(ax, ay, bx, by, cx, cy), o2 = orient(ax, ay, bx, by, dx, dy);
    const int o3 = orient(cx, cy, dx, dy, ax, ay), o4 = orient(cx, cy, dx, dy, bx, by);
    if (o1 != o2 && o3 != o4) return true;
    return (o1 == 0 && on(ax, ay, bx, by, cx, cy)) || (o2 == 0 && on(ax, ay, bx, by, dx, dy)) ||
           (o3 == 0 && on(cx, cy, dx, dy, ax, ay)) || (o4 == 0 && on(cx, cy, dx, dy, bx, by));
}

// True when two non-adjacent edges of the ring (projected on the plane most
// parallel to it) touch or cross.
bool ring_self_intersects(const Ring3& r, int drop_axis) {
    const std::size_t n = r.size();
    auto uv = [&](const Point3& p) {
        return drop_axis == 0 ? std::pair{p.y, p.z} : drop_axis == 1 ? std::pair{p.z, p.x} : std::pair{p.x, p.y};
    };
    double magnitude = 0;
    for (const Point3& p : r) {
        const auto [u, v] = uv(p);
        magnitude = std::max({magnitude, std::abs(u), std::abs(v)});
    }
    const double tol = 16 * std::numeric_limits<double>::epsilon() * magnitude;  // rounding of the stored coordinates
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = i + 1; j < n; ++j) {
            if (j == i + 1 || (i == 0 && j == n - 1)) continue;  // adjacent edges share a vertex
            const auto [ax, ay] = uv(r[i]);
            const auto [bx, by] = uv(r[(i + 1) % n]);
            const auto [cx, cy] = uv(r[j]);
            const auto [dx, dy] = uv(r[(j + 1) % n]);
            if (segments_cross(ax, ay, bx, by, cx, cy, dx, dy, tol)) return true;
        }
    return false;
}

}  // namespace

std::vector<std::string> validate_solid(const Solid& s, const SolidValidityOptions& o) {
    std::vector<std::string> errors;
    std::set<std::string> seen;  // one message per kind and face keeps the list short
    auto add = [&](const std::string& e) {
        if (seen.insert(e).second) errors.push_back(e);
    };
    if (s.faces.size() < 4) add("301 TOO_FEW_POLYGONS: a shell needs at least 4 faces, has " + std::to_string(s.faces.size()));
    // Vertices snapped to a grid of snap_tolerance become ids; edges pair up by id.
    std::map<std::array<int64_t, 3>, std::size_t> ids;
    auto id_of = [&](const Point3& p) {
        const std::array<int64_t, 3> k{std::llround(p.x / o.snap_tolerance), std::llround(p.y / o.snap_tolerance),
                                       std::llround(p.z / o.snap_tolerance)};
        return ids.emplace(k, ids.size()).first->second;
    };
    std::map<std::pair<std::size_t, std::size_t>, int> directed;
    for (std::size_t fi = 0; fi < s.faces.size(); ++fi) {
        const Face& f = s.faces[fi];
        const std::string face = "face " + std::to_string(fi) + " (" + citygml_name(f.type) + ")";
        const auto n = newell(f.outer);
        const double len = norm(n);
        if (face_area(f) < o.min_face_area || len == 0) add("DEGENERATE_POLYGON: " + face + " has no area");
        const int drop = len == 0 ? 2
                         : std::abs(n[0]) >= std::abs(n[1]) && std::abs(n[0]) >= std::abs(n[2]) ? 0
                         : std::abs(n[1]) >= std::abs(n[2])                                       ? 1
                                                                                                   : 2;
        std::vector<const Ring3*> rings{&f.outer};
        for (const Ring3& h : f.holes) rings.push_back(&h);
        for (const Ring3* r : rings) {
            if (r->size() < 3) {
                add("101 TOO_FEW_POINTS: " + face + " has a ring of " + std::to_string(r->size()) + " vertices");
                continue;
            }
            std::vector<std::size_t> rid;
            for (const Point3& p : *r) rid.push_back(id_of(p));
            for (std::size_t i = 0; i < rid.size(); ++i) {
                const std::size_t a = rid[i], b = rid[(i + 1) % rid.size()];
                if (a == b) {
                    add("102 CONSECUTIVE_POINTS_SAME: " + face);
                    continue;
                }
                ++directed[{a, b}];
            }
            if (ring_self_intersects(*r, drop)) add("104 RING_SELF_INTERSECTION: " + face);
            if (len > 0) {
                // Plane through the outer ring's centroid with Newell's normal.
                double cx = 0, cy = 0, cz = 0;
                for (const Point3& p : f.outer) cx += p.x, cy += p.y, cz += p.z;
                const double k = double(f.outer.size());
                cx /= k, cy /= k, cz /= k;
                for (const Point3& p : *r) {
                    const double d = std::abs((p.x - cx) * n[0] + (p.y - cy) * n[1] + (p.z - cz) * n[2]) / len;
                    if (d > o.planarity_tolerance) {
                        add("203 NON_PLANAR_POLYGON_DISTANCE_PLANE: " + face);
                        break;
                    }
                }
            }
        }
    }
    // A closed, consistently oriented 2-manifold shell uses every edge exactly
    // once in each direction.
    bool open = false, wrong = false, nonmanifold = false;
    for (const auto& [edge, count] : directed) {
        const auto back = directed.find({edge.second, edge.first});
        const int reverse = back == directed.end() ? 0 : back->second;
        if (count > 1) (reverse == count ? nonmanifold : wrong) = true;
        else if (reverse == 0) open = true;
        if (count + reverse > 2) nonmanifold = true;
    }
    if (open) add("302 SHELL_NOT_CLOSED: some edges belong to only one face");
    if (nonmanifold) add("303 NON_MANIFOLD_CASE: an edge is shared by more than two faces");
    if (wrong) add("307 POLYGON_WRONG_ORIENTATION: faces sharing an edge run it the same way");
    if (!open && !wrong && solid_volume(s) <= 0) add("307 POLYGON_WRONG_ORIENTATION: the shell is oriented inwards");
    return errors;
}

}  // namespace cityforge
