#include "synth/scene.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "core/error.hpp"
#include "core/random.hpp"

namespace cityforge::synth {
namespace {

constexpr double kPi = std::numbers::pi;

// Roof of one wing: height above the eave and its gradient in local axes.
// The ridge runs along the wing's longer side.
double wing_roof(const Wing& w, RoofType roof, double t, double u, double v, double& gu, double& gv) {
    gu = gv = 0.0;
    if (roof == RoofType::flat) return 0.0;
    const double cu = 0.5 * (w.u0 + w.u1), cv = 0.5 * (w.v0 + w.v1);
    const double hu = 0.5 * (w.u1 - w.u0), hv = 0.5 * (w.v1 - w.v0);
    const bool long_u = hu >= hv;
    const double d_short = long_u ? v - cv : u - cu;
    const double d_long = long_u ? u - cu : v - cv;
    const double half_short = long_u ? hv : hu;
    const double half_long = long_u ? hu : hv;
    double g_short = 0.0, g_long = 0.0, h = 0.0;
    switch (roof) {
        case RoofType::shed:
            h = t * (d_short + half_short);
            g_short = t;
            break;
        case RoofType::gable:
            h = t * (half_short - std::abs(d_short));
            g_short = d_short >= 0 ? -t : t;
            break;
        case RoofType::hip: {
            const double a = half_short - std::abs(d_short);
            const double b = half_long - std::abs(d_long);
            if (a <= b) {
                h = t * a;
                g_short = d_short >= 0 ? -t : t;
            } else {
                h = t * b;
                g_long = d_long >= 0 ? -t : t;
            }
            break;
        }
        case RoofType::flat: break;
    }
    gu = long_u ? g_long : g_short;
    gv = long_u ? g_short : g_long;
    return h;
}

double ring_area(const std::vector<LocalPoint>& r) {
    double a = 0.0;
    for (std::size_t i = 0; i < r.size(); ++i) {
        const auto& p = r[i];
        const auto& q = r[(i + 1) % r.size()];
        a += p.u * q.v - q.u * p.v;
    }
    return 0.5 * a;
}

using Pts = std::vector<LocalPoint>;

// Footprint outline and roof wings of each shape, centred on (0, 0), W along
// u and D along v, wing thickness t.
void make_shape(SceneBuilding& b, double W, double D, double t) {
    const double a = W / 2, c = D / 2;
    b.wings.clear();
    b.holes.clear();
    switch (b.shape) {
        case BuildingShape::rectangle:
            b.wings = {{-a, -c, a, c}};
            b.outline = Pts{{-a, -c}, {a, -c}, {a, c}, {-a, c}};
            break;
        case BuildingShape::l_shape:
            b.wings = {{-a, -c, a, -c + t}, {-a, -c, -a + t, c}};
            b.outline = Pts{{-a, -c}, {a, -c}, {a, -c + t}, {-a + t, -c + t}, {-a + t, c}, {-a, c}};
            break;
        case BuildingShape::t_shape:
            b.wings = {{-a, c - t, a, c}, {-t / 2, -c, t / 2, c}};
            b.outline = Pts{{-t / 2, -c}, {t / 2, -c}, {t / 2, c - t}, {a, c - t}, {a, c}, {-a, c}, {-a, c - t}, {-t / 2, c - t}};
            break;
        case BuildingShape::u_shape:
            b.wings = {{-a, -c, a, -c + t}, {-a, -c, -a + t, c}, {a - t, -c, a, c}};
            b.outline = Pts{{-a, -c}, {a, -c}, {a, c}, {a - t, c}, {a - t, -c + t}, {-a + t, -c + t}, {-a + t, c}, {-a, c}};
            break;
        case BuildingShape::courtyard:
            b.wings = {{-a, -c, a, -c + t}, {-a, c - t, a, c}, {-a, -c, -a + t, c}, {a - t, -c, a, c}};
            b.outline = Pts{{-a, -c}, {a, -c}, {a, c}, {-a, c}};
            b.holes = {Pts{{-a + t, -c + t}, {-a + t, c - t}, {a - t, c - t}, {a - t, -c + t}}};
            break;
    }
}

}  // namespace

std::string to_string(RoofType t) {
    switch (t) {
        case RoofType::flat: return "flat";
        case RoofType::shed: return "shed";
        case RoofType::gable: return "gable";
        case RoofType::hip: return "hip";
    }
    return "flat";
}

std::string to_string(BuildingShape s) {
    switch (s) {
        case BuildingShape::rectangle: return "rectangle";
        case BuildingShape::l_shape: return "L";
        case BuildingShape::t_shape: return "T";
        case BuildingShape::u_shape: return "U";
        case BuildingShape::courtyard: return "courtyard";
    }
    return "rectangle";
}

LocalPoint SceneBuilding::to_local(double x, double y) const {
    const double dx = x - cx, dy = y - cy;
    const double c = std::cos(angle_rad), s = std::sin(angle_rad);
    return {c * dx + s * dy, -s * dx + c * dy};
}

Polygon SceneBuilding::footprint(double ox, double oy) const {
    auto to_map = [&](const std::vector<LocalPoint>& ring) {
        Ring out;
        for (const LocalPoint& p : ring) {
            const auto xy = to_scene(p);
            out.push_back({ox + xy[0], oy + xy[1]});
        }
        return out;
    };
    Polygon p;
    p.outer = to_map(outline);
    for (const auto& hole : holes) p.holes.push_back(to_map(hole));
    return p;
}

std::array<double, 2> SceneBuilding::to_scene(LocalPoint p) const {
    const double c = std::cos(angle_rad), s = std::sin(angle_rad);
    return {cx + c * p.u - s * p.v, cy + s * p.u + c * p.v};
}

bool SceneBuilding::contains(double x, double y) const {
    const LocalPoint p = to_local(x, y);
    if (oblique) {
        bool in = false;
        for (std::size_t i = 0, j = outline.size() - 1; i < outline.size(); j = i++) {
            const LocalPoint& a = outline[i];
            const LocalPoint& b = outline[j];
            if ((a.v > p.v) != (b.v > p.v) && p.u < (b.u - a.u) * (p.v - a.v) / (b.v - a.v) + a.u) in = !in;
        }
        return in;
    }
    for (const Wing& w : wings)
        if (w.contains(p.u, p.v)) return true;
    return false;
}

double SceneBuilding::roof_height(double x, double y, double* dzdx, double* dzdy) const {
    const LocalPoint p = to_local(x, y);
    double best = -std::numeric_limits<double>::infinity(), bgu = 0, bgv = 0;
    bool inside = false;
    for (const Wing& w : wings) {
        if (!w.contains(p.u, p.v)) continue;
        inside = true;
        double gu, gv;
        const double h = wing_roof(w, roof, pitch_tan, p.u, p.v, gu, gv);
        if (h > best) best = h, bgu = gu, bgv = gv;
    }
    if (!inside) {
        // Outside every wing (a point on the boundary after rounding): use the
        // nearest wing's roof so callers near edges get a continuous value.
        const Wing& w = wings.front();
        best = wing_roof(w, roof, pitch_tan, std::clamp(p.u, w.u0, w.u1), std::clamp(p.v, w.v0, w.v1), bgu, bgv);
    }
    const double c = std::cos(angle_rad), s = std::sin(angle_rad);
    if (dzdx) *dzdx = c * bgu - s * bgv;
    if (dzdy) *dzdy = s * bgu + c * bgv;
    return eave_height_m + best;
}

double SceneBuilding::area_m2() const {
    double a = std::abs(ring_area(outline));
    for (const auto& h : holes) a -= std::abs(ring_area(h));
    return a;
}

double SceneTree::crown_z(double x, double y) const {
    const double r2 = ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / (radius * radius);
    if (r2 > 1.0) return -std::numeric_limits<double>::infinity();
    // Half-ellipsoid crown from crown_base to height.
    return ground_z + crown_base + (height - crown_base) * std::sqrt(1.0 - r2);
}

double Scene::terrain_z(double x, double y) const {
    return terrain[0] + terrain[1] * x + terrain[2] * y +
           undulation_m * std::sin(2 * kPi * x / 830.0) * std::cos(2 * kPi * y / 610.0);
}

bool Scene::on_road(double x, double y) const {
    for (const auto& r : roads_x)
        if (x >= r[0] && x <= r[1]) return true;
    for (const auto& r : roads_y)
        if (y >= r[0] && y <= r[1]) return true;
    return false;
}

namespace {

// Alternating road/block intervals along one axis covering [0, size].
void lay_roads(Rng& rng, double size, std::vector<std::array<double, 2>>& roads, std::vector<std::array<double, 2>>& blocks) {
    double pos = -rng.uniform(0.0, 40.0);
    while (pos < size) {
        const double w = rng.uniform(8.0, 14.0);
        roads.push_back({pos, pos + w});
        pos += w;
        const double b = rng.uniform(55.0, 110.0);
        blocks.push_back({pos, pos + b});
        pos += b;
    }
}

const std::array<std::array<uint8_t, 3>, 6> kPitchedColours{{{172, 82, 62}, {132, 52, 46}, {82, 86, 92}, {122, 92, 72}, {62, 62, 68}, {92, 132, 112}}};
const std::array<std::array<uint8_t, 3>, 5> kFlatColours{{{172, 172, 166}, {150, 150, 140}, {72, 72, 75}, {212, 212, 206}, {142, 132, 116}}};

std::array<uint8_t, 3> jitter_colour(Rng& rng, std::array<uint8_t, 3> c) {
    const int d = rng.integer(-12, 12);
    for (auto& v : c) v = static_cast<uint8_t>(std::clamp(int(v) + d + rng.integer(-5, 5), 0, 255));
    return c;
}

struct Lot {
    double x0, y0, x1, y1;
};

const std::array<std::array<uint8_t, 3>, 3> kGroundLikeColours{{{93, 133, 63}, {150, 130, 100}, {97, 97, 101}}};

// Area centroid of the outline minus its holes, local frame.
LocalPoint area_centroid(const SceneBuilding& b) {
    double a = 0, cu = 0, cv = 0;
    auto ring = [&](const std::vector<LocalPoint>& r) {
        for (std::size_t i = 0; i < r.size(); ++i) {
            const LocalPoint& p = r[i];
            const LocalPoint& q = r[(i + 1) % r.size()];
            const double c = p.u * q.v - q.u * p.v;
            a += c, cu += (p.u + q.u) * c, cv += (p.v + q.v) * c;
        }
    };
    ring(b.outline);
    for (const auto& h : b.holes) ring(h);  // clockwise: subtracts
    if (a == 0) return {0, 0};
    return {cu / (3 * a), cv / (3 * a)};
}

// Cuts corner k (0..3, counter-clockwise from (-a, -c)) of a rectangle W x D at an oblique angle.
void cut_corner(SceneBuilding& b, double W, double D, int k, double fu, double fv) {
    const double a = W / 2, c = D / 2;
    const Pts corners{{-a, -c}, {a, -c}, {a, c}, {-a, c}};
    Pts out;
    for (int i = 0; i < 4; ++i) {
        if (i != k) {
            out.push_back(corners[i]);
            continue;
        }
        const LocalPoint prev = corners[(i + 3) % 4], next = corners[(i + 1) % 4], p = corners[i];
        // Along the edge from prev and towards next, by the fraction of that edge's length.
        const double lp = std::hypot(p.u - prev.u, p.v - prev.v), ln = std::hypot(next.u - p.u, next.v - p.v);
        const double f_prev = (std::abs(p.u - prev.u) > 0 ? fu : fv), f_next = (std::abs(next.u - p.u) > 0 ? fu : fv);
        out.push_back({p.u + (prev.u - p.u) / lp * f_prev * lp, p.v + (prev.v - p.v) / lp * f_prev * lp});
        out.push_back({p.u + (next.u - p.u) / ln * f_next * ln, p.v + (next.v - p.v) / ln * f_next * ln});
    }
    b.outline = out;
    b.oblique = true;
}

// A round or many-sided outline inscribed in the W x D rectangle: `sides`
// vertices on the ellipse with semi-axes W/2 and D/2 (a circle of the smaller
// when `circle`), starting at angle `phase`. Uses the polygon test of
// `contains` (as cut corners do); the roof stays the rectangle's (flat).
void round_outline(SceneBuilding& b, double W, double D, bool circle, int sides, double phase) {
    const double a = circle ? std::min(W, D) / 2 : W / 2, c = circle ? std::min(W, D) / 2 : D / 2;
    Pts out;
    for (int k = 0; k < sides; ++k) {
        const double t = phase + 2 * kPi * k / sides;
        out.push_back({a * std::cos(t), c * std::sin(t)});
    }
    b.outline = out;
    b.oblique = true;
}

}  // namespace

void SceneVariation::validate() const {
    if (!(terrain_slope_max >= 0 && terrain_slope_max <= 0.5)) throw Error("--terrain-slope", "must be between 0 and 0.5");
    if (!(terrain_undulation_m >= 0 && terrain_undulation_m <= 50)) throw Error("--terrain-undulation-m", "must be between 0 and 50 m");
    for (const auto& [name, v] : {std::pair<const char*, double>{"--dark-roof-share", dark_roof_share}, {"--tree-touch-share", tree_touch_share},
                                  {"--ground-like-roof-share", ground_like_roof_share}, {"--terraced-share", terraced_block_share},
                                  {"--oblique-share", oblique_share}, {"--round-share", round_share}})
        if (!(v >= 0 && v <= 1)) throw Error(name, "must be between 0 and 1");
}

namespace {
// Plants a tree of crown radius `radius` at (x, y) when its crown lies inside
// the scene (height, crown base and colour drawn from `r`, ground from the terrain).
struct TreePlanter {
    Scene& scene;
    double size_m;
    void operator()(Rng& r, double x, double y, double radius) const {
        if (x - radius < 0 || y - radius < 0 || x + radius > size_m || y + radius > size_m) return;
        SceneTree t;
        t.cx = x, t.cy = y, t.radius = radius;
        t.height = r.uniform(6.0, 15.0);
        t.crown_base = t.height * r.uniform(0.25, 0.45);
        t.ground_z = scene.terrain_z(x, y);
        t.color = {static_cast<uint8_t>(r.integer(35, 70)), static_cast<uint8_t>(r.integer(75, 110)),
                   static_cast<uint8_t>(r.integer(28, 50))};
        scene.trees.push_back(t);
    }
};

// A park: trees on a jittered grid of 8-12 m over the block's inner lot.
void plant_park(Rng& br, const Lot& inner, const TreePlanter& add_tree) {
    const double spacing = br.uniform(8.0, 12.0);
    for (double x = inner.x0 + spacing / 2; x < inner.x1; x += spacing)
        for (double y = inner.y0 + spacing / 2; y < inner.y1; y += spacing)
            if (br.chance(0.6)) {
                // Drawn in this order (the order GCC evaluated the call's
                // arguments in when the default towns were made), named so
                // that no compiler's argument order changes the town.
                const double radius = br.uniform(2.5, 5.0);
                const double dy = br.uniform(-2, 2);
                const double dx = br.uniform(-2, 2);
                add_tree(br, x + dx, y + dy, radius);
            }
}

// The block's lots: the whole inner lot (`whole`), else one or two rows of
// 15-32 m lots along the block's longer side.
std::vector<Lot> cut_lots(Rng& br, const Lot& inner, bool whole) {
    const double iw = inner.x1 - inner.x0, ih = inner.y1 - inner.y0;
    std::vector<Lot> lots;
    if (whole) {
        lots.push_back(inner);
        return lots;
    }
    const bool along_x = iw >= ih;
    const double long_len = along_x ? iw : ih, short_len = along_x ? ih : iw;
    const int rows = short_len >= 40.0 ? 2 : 1;
    for (int r = 0; r < rows; ++r) {
        double s0 = r * short_len / rows, s1 = (r + 1) * short_len / rows;
        double pos = 0.0;
        while (long_len - pos >= 14.0) {
            double w = br.uniform(15.0, 32.0);
            if (long_len - pos - w < 14.0) w = long_len - pos;
            Lot lot = along_x ? Lot{inner.x0 + pos, inner.y0 + s0, inner.x0 + pos + w, inner.y0 + s1}
                              : Lot{inner.x0 + s0, inner.y0 + pos, inner.x0 + s1, inner.y0 + pos + w};
            lots.push_back(lot);
            pos += w;
        }
    }
    return lots;
}

// A terrace: the row's lots built wall to wall, one height, one roof type
// (drawn from `vr`); a gap to the street and at the row's ends.
void build_terrace(Scene& scene, Rng& vr, const std::vector<Lot>& lots, const Lot& inner) {
    const double iw = inner.x1 - inner.x0, ih = inner.y1 - inner.y0;
    const bool along_x = iw >= ih;
    const double gap = vr.uniform(2.0, 4.0);
    const double eave = vr.uniform(4.0, 14.0);
    const RoofType roof = vr.chance(0.5) ? RoofType::flat : RoofType::gable;
    const double pitch = std::tan(vr.uniform(25.0, 40.0) * kPi / 180.0);
    const auto base = roof == RoofType::flat ? kFlatColours[vr.integer(0, int(kFlatColours.size()) - 1)]
                                             : kPitchedColours[vr.integer(0, int(kPitchedColours.size()) - 1)];
    for (const Lot& lot : lots) {
        Lot l = lot;
        auto at = [](double v, double edge) { return std::abs(v - edge) < 1e-9; };
        if (along_x) {
            l.y0 += gap, l.y1 -= gap;
            if (at(l.x0, inner.x0)) l.x0 += gap;
            if (at(l.x1, inner.x1)) l.x1 -= gap;
        } else {
            l.x0 += gap, l.x1 -= gap;
            if (at(l.y0, inner.y0)) l.y0 += gap;
            if (at(l.y1, inner.y1)) l.y1 -= gap;
        }
        const double W = l.x1 - l.x0, D = l.y1 - l.y0;
        if (std::min(W, D) < 7.0) continue;
        SceneBuilding b;
        b.shape = BuildingShape::rectangle;
        b.roof = roof;
        b.cx = 0.5 * (l.x0 + l.x1), b.cy = 0.5 * (l.y0 + l.y1);
        b.angle_rad = 0.0;
        make_shape(b, W, D, 0.0);
        b.ground_z = scene.terrain_z(b.cx, b.cy);
        b.eave_height_m = eave;
        b.pitch_tan = roof == RoofType::flat ? 0.0 : pitch;
        b.ridge_height_m = eave + (roof == RoofType::flat ? 0.0 : 0.5 * std::min(W, D) * pitch);
        b.color = jitter_colour(vr, base);
        b.id = static_cast<int>(scene.buildings.size()) + 1;
        scene.buildings.push_back(std::move(b));
    }
}

// A detached building on `lot` (rotated by `angle`, radians), with its shape,
// roof and colour, and trees in the lot's free space (sometimes one touching
// it). Draws from `br` in the order the default town was made with; the
// variations draw from their own streams (per building index), so the
// default town stays the same whatever variations are on.
void build_detached(Scene& scene, Rng& br, const Lot& lot, double angle, const SceneLayout& layout, const TreePlanter& add_tree) {
    const SceneVariation& var = layout.variation;
    const double lw = lot.x1 - lot.x0, lh = lot.y1 - lot.y0;
    const double gap = br.uniform(2.0, 4.0);
    const double avail_w = lw - 2 * gap, avail_h = lh - 2 * gap;
    if (avail_w < 8.0 || avail_h < 8.0) return;
    SceneBuilding b;
    const double c = std::abs(std::cos(angle)), s = std::abs(std::sin(angle));
    // Pick dimensions in the building frame, then shrink to fit the rotated box.
    double W = br.uniform(0.6, 1.0) * (c >= s ? avail_w : avail_h);
    double D = br.uniform(0.6, 1.0) * (c >= s ? avail_h : avail_w);
    const double ex = W * c + D * s, ey = W * s + D * c;
    const double k = std::min({1.0, avail_w / ex, avail_h / ey});
    W *= k, D *= k;
    if (std::min(W, D) < 7.0) return;
    const double shape_roll = br.uniform();
    const bool big = std::min(W, D) >= 24.0;
    if (big && shape_roll < 0.4) b.shape = BuildingShape::courtyard;
    else if (shape_roll < 0.45) b.shape = BuildingShape::rectangle;
    else if (shape_roll < 0.67) b.shape = BuildingShape::l_shape;
    else if (shape_roll < 0.82) b.shape = BuildingShape::t_shape;
    else b.shape = BuildingShape::u_shape;
    if (std::min(W, D) < 14.0) b.shape = BuildingShape::rectangle;
    double t = 0.0;
    if (b.shape == BuildingShape::courtyard) t = br.uniform(6.0, std::min(W, D) / 2 - 4.0);
    else if (b.shape != BuildingShape::rectangle) t = br.uniform(5.5, std::min(W, D) * 0.45);
    const double roof_roll = br.uniform();
    if (b.shape == BuildingShape::rectangle)
        b.roof = roof_roll < 0.3 ? RoofType::flat : roof_roll < 0.45 ? RoofType::shed : roof_roll < 0.75 ? RoofType::gable : RoofType::hip;
    else
        b.roof = roof_roll < 0.4 ? RoofType::flat : roof_roll < 0.75 ? RoofType::gable : RoofType::hip;
    // Variations: own random stream per building, so the default town stays the same.
    Rng bv(layout.seed, 5000000 + static_cast<uint64_t>(scene.buildings.size()));
    if (var.all_roof_families) {
        const RoofType families[] = {RoofType::flat, RoofType::shed, RoofType::gable, RoofType::hip};
        b.roof = families[bv.integer(0, 3)];
    }
    const double slack_x = avail_w - (W * c + D * s), slack_y = avail_h - (W * s + D * c);
    b.cx = lot.x0 + gap + (W * c + D * s) / 2 + br.uniform(0.0, std::max(0.0, slack_x));
    b.cy = lot.y0 + gap + (W * s + D * c) / 2 + br.uniform(0.0, std::max(0.0, slack_y));
    b.angle_rad = angle;
    make_shape(b, W, D, t);
    if (b.shape == BuildingShape::rectangle && var.oblique_share > 0 && bv.chance(var.oblique_share)) {
        // Drawn in the order GCC evaluated the call's arguments in when the
        // towns were first made, named so that no compiler changes them.
        const double cut_v = bv.uniform(0.25, 0.7), cut_u = bv.uniform(0.25, 0.7);
        const int corner = bv.integer(0, 3);
        cut_corner(b, W, D, corner, cut_u, cut_v);
    }
    // Round and many-sided buildings: own random stream, flat roofs.
    Rng rv(layout.seed, 6000000 + static_cast<uint64_t>(scene.buildings.size()));
    const bool round = b.shape == BuildingShape::rectangle && !b.oblique && var.round_share > 0 && rv.chance(var.round_share);
    if (round) {
        const int kind = rv.integer(0, 3);  // circle, ellipse, octagon, hexagon
        round_outline(b, W, D, kind == 0, kind <= 1 ? 48 : kind == 2 ? 8 : 6, rv.uniform(0.0, 2 * kPi));
        b.roof = RoofType::flat;
    }
    if (var.base_at_area_centroid) {
        const auto xy = b.to_scene(area_centroid(b));
        b.ground_z = scene.terrain_z(xy[0], xy[1]);
    } else {
        b.ground_z = scene.terrain_z(b.cx, b.cy);
    }
    if (b.roof == RoofType::flat) {
        b.eave_height_m = br.uniform(3.5, 24.0);
        b.pitch_tan = 0.0;
        b.color = jitter_colour(br, kFlatColours[br.integer(0, int(kFlatColours.size()) - 1)]);
    } else {
        b.eave_height_m = br.uniform(3.0, 14.0);
        const double pitch_deg = b.roof == RoofType::shed ? br.uniform(6.0, 15.0) : br.uniform(22.0, 42.0);
        b.pitch_tan = std::tan(pitch_deg * kPi / 180.0);
        b.color = jitter_colour(br, kPitchedColours[br.integer(0, int(kPitchedColours.size()) - 1)]);
    }
    double ridge = 0.0;
    for (const Wing& w : b.wings) {
        const double half_short = 0.5 * std::min(w.u1 - w.u0, w.v1 - w.v0);
        ridge = std::max(ridge, b.roof == RoofType::shed ? 2 * half_short * b.pitch_tan : half_short * b.pitch_tan);
    }
    b.ridge_height_m = b.eave_height_m + ridge;
    if (var.ground_like_roof_share > 0 && bv.chance(var.ground_like_roof_share))
        b.color = jitter_colour(bv, kGroundLikeColours[bv.integer(0, int(kGroundLikeColours.size()) - 1)]);
    b.dark_roof = br.chance(var.dark_roof_share);
    b.id = static_cast<int>(scene.buildings.size()) + 1;

    // Trees in the lot's free space, and sometimes one touching the building.
    const int n_trees = br.integer(0, 3);
    for (int i = 0; i < n_trees; ++i) {
        const double r = br.uniform(2.0, 4.5);
        const double x = br.uniform(lot.x0 + r, std::max(lot.x0 + r, lot.x1 - r));
        const double y = br.uniform(lot.y0 + r, std::max(lot.y0 + r, lot.y1 - r));
        const LocalPoint p = b.to_local(x, y);
        if (std::abs(p.u) < W / 2 + r * 0.8 && std::abs(p.v) < D / 2 + r * 0.8) continue;
        add_tree(br, x, y, r);
    }
    if (br.chance(var.tree_touch_share)) {
        const double r = br.uniform(2.5, 4.5);
        const double side = br.chance(0.5) ? 1.0 : -1.0;
        const auto xy = b.to_scene({side * (W / 2 + 0.6 * r), br.uniform(-D / 3, D / 3)});
        add_tree(br, xy[0], xy[1], r);
    }
    scene.buildings.push_back(std::move(b));
}
}  // namespace

Scene generate_scene(const SceneLayout& layout) {
    Scene scene;
    scene.size_m = layout.size_m;
    scene.seed = layout.seed;
    const SceneVariation& var = layout.variation;
    var.validate();
    Rng rng(layout.seed, 1);
    const double slope = var.terrain_slope_max;
    scene.terrain = {rng.uniform(20.0, 60.0), rng.uniform(-slope, slope), rng.uniform(-slope, slope)};
    scene.undulation_m = var.terrain_undulation_m;

    std::vector<std::array<double, 2>> bx, by;
    lay_roads(rng, layout.size_m, scene.roads_x, bx);
    lay_roads(rng, layout.size_m, scene.roads_y, by);

    const double size = layout.size_m;
    const double margin = 2.0;  // buildings stay this far inside the scene
    const TreePlanter add_tree{scene, size};
    uint64_t block_index = 0;
    for (const auto& xb : bx) {
        for (const auto& yb : by) {
            Rng br(layout.seed, 1000 + block_index++);
            const double sidewalk = 3.0;
            const Lot inner{std::max(xb[0] + sidewalk, margin), std::max(yb[0] + sidewalk, margin),
                            std::min(xb[1] - sidewalk, size - margin), std::min(yb[1] - sidewalk, size - margin)};
            const double iw = inner.x1 - inner.x0, ih = inner.y1 - inner.y0;
            if (iw < 16.0 || ih < 16.0) continue;
            const double roll = br.uniform();
            if (roll < 0.07) {
                plant_park(br, inner, add_tree);
                continue;
            }
            const double angle = br.chance(0.65) ? 0.0 : (br.chance(0.5) ? 1 : -1) * br.uniform(10.0, 45.0) * kPi / 180.0;
            const bool whole = roll < 0.19 && iw >= 45.0 && ih >= 45.0;
            const std::vector<Lot> lots = cut_lots(br, inner, whole);
            Rng vr(layout.seed, 700000 + block_index);
            if (var.terraced_block_share > 0 && lots.size() >= 2 && !whole && vr.chance(var.terraced_block_share)) {
                build_terrace(scene, vr, lots, inner);
                continue;
            }
            for (const Lot& lot : lots) build_detached(scene, br, lot, angle, layout, add_tree);
        }
    }
    return scene;
}

std::vector<std::array<double, 3>> sample_roof_points(const SceneBuilding& b, double density, double sigma, uint64_t seed) {
    std::vector<std::array<double, 3>> pts;
    double x0 = INFINITY, y0 = INFINITY, x1 = -INFINITY, y1 = -INFINITY;
    for (const LocalPoint& q : b.outline) {
        const auto xy = b.to_scene(q);
        x0 = std::min(x0, xy[0]), x1 = std::max(x1, xy[0]), y0 = std::min(y0, xy[1]), y1 = std::max(y1, xy[1]);
    }
    const double step = 1.0 / std::sqrt(density);
    Rng rng(seed, static_cast<uint64_t>(b.id));
    for (double y = y0; y < y1; y += step)
        for (double x = x0; x < x1; x += step) {
            const double px = x + rng.uniform(0, step), py = y + rng.uniform(0, step);
            if (!b.contains(px, py)) continue;
            pts.push_back({px, py, b.ground_z + b.roof_height(px, py) + sigma * rng.normal()});
        }
    return pts;
}

}  // namespace cityforge::synth
