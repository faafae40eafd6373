#include "heights/building_heights.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <tbb/parallel_for.h>

#include "core/error.hpp"
#include "core/grid_size.hpp"

namespace cityforge {

std::string to_string(GroundMethod m) { return m == GroundMethod::plane ? "plane" : "percentile"; }

GroundMethod ground_method_from_string(const std::string& s, const std::string& option) {
    if (s == "plane") return GroundMethod::plane;
    if (s == "percentile") return GroundMethod::percentile;
    throw Error(option, "must be 'plane' or 'percentile', not '" + s + "'");
}

void HeightOptions::validate() const {
    if (!(ground_buffer_m > 0.0)) throw Error("--ground-buffer-m", "must be > 0");
    if (!(ground_outlier_m > 0.0)) throw Error("--ground-outlier-m", "must be > 0");
    if (!(ground_percentile >= 0.0 && ground_percentile <= 100.0)) throw Error("--ground-percentile", "must be between 0 and 100");
    if (!(roof_percentile >= 0.0 && roof_percentile <= 100.0)) throw Error("--roof-percentile", "must be between 0 and 100");
    if (min_ground_points < 1) throw Error("--min-ground-points", "must be >= 1");
    if (min_roof_points < 1) throw Error("--min-roof-points", "must be >= 1");
    if (!(coverage_cell_m > 0.0)) throw Error("--coverage-cell-m", "must be > 0");
    if (!(unit_m > 0.0) || !(z_unit_m > 0.0)) throw Error("units", "CRS units must be > 0 metres");
}

namespace {

// Points binned in a regular grid (CSR layout) for bounding-box queries.
class PointGrid {
public:
    PointGrid(const PointCloud& c, const std::vector<uint8_t>& keep, double cell) : cell_(cell) {
        minx_ = miny_ = INFINITY;
        double maxx = -INFINITY, maxy = -INFINITY;
        for (std::size_t i = 0; i < c.size(); ++i) {
            if (!keep.empty() && !keep[i]) continue;
            minx_ = std::min(minx_, c.x[i]), maxx = std::max(maxx, c.x[i]);
            miny_ = std::min(miny_, c.y[i]), maxy = std::max(maxy, c.y[i]);
        }
        if (minx_ == INFINITY) return;  // no kept point
        const GridSize size = checked_grid_size(minx_, miny_, maxx, maxy, cell_, kBytesPerCell, "heights point index");
        w_ = size.width, h_ = size.height;
        start_.assign(size.cells() + 1, 0);
        for (std::size_t i = 0; i < c.size(); ++i)
            if (keep.empty() || keep[i]) ++start_[cell_of(c.x[i], c.y[i]) + 1];
        for (std::size_t k = 1; k < start_.size(); ++k) start_[k] += start_[k - 1];
        ids_.resize(start_.back());
        std::vector<uint32_t> fill(start_.begin(), start_.end() - 1);
        for (std::size_t i = 0; i < c.size(); ++i)
            if (keep.empty() || keep[i]) ids_[fill[cell_of(c.x[i], c.y[i])]++] = static_cast<uint32_t>(i);
    }
    template <typename F>
    void for_each_in(const Extent& e, F&& f) const {
        if (w_ == 0) return;
        if (!(e.min_x <= e.max_x) || !(e.min_y <= e.max_y)) return;  // NaN extent
        // Clamped in double before the cast: a footprint far from the cloud
        // (1e300) must not overflow an int.
        auto clamp_cell = [](double v, int hi) { return static_cast<int>(std::clamp(std::floor(v), -1.0, static_cast<double>(hi))); };
        const int x0 = std::max(0, clamp_cell((e.min_x - minx_) / cell_, w_));
        const int x1 = std::min(w_ - 1, clamp_cell((e.max_x - minx_) / cell_, w_));
        const int y0 = std::max(0, clamp_cell((e.min_y - miny_) / cell_, h_));
        const int y1 = std::min(h_ - 1, clamp_cell((e.max_y - miny_) / cell_, h_));
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w_ + x;
                for (uint32_t j = start_[k]; j < start_[k + 1]; ++j) f(ids_[j]);
            }
    }

    /// Bytes per cell while the index is built: start_ and its fill copy (uint32 each).
    static constexpr double kBytesPerCell = 8.0;

private:
    std::size_t cell_of(double x, double y) const {
        const int cx = std::min(w_ - 1, static_cast<int>((x - minx_) / cell_));
        const int cy = std::min(h_ - 1, static_cast<int>((y - miny_) / cell_));
        return static_cast<std::size_t>(cy) * w_ + cx;
    }
    double cell_, minx_ = 0, miny_ = 0;
    int w_ = 0, h_ = 0;
    std::vector<uint32_t> start_, ids_;
};

bool inside_any(const std::vector<Polygon>& parts, double x, double y) {
    for (const Polygon& p : parts)
        if (point_in_polygon(p, x, y)) return true;
    return false;
}

double distance_to_parts(const std::vector<Polygon>& parts, double x, double y) {
    double d = INFINITY;
    for (const Polygon& p : parts) d = std::min(d, distance_to_boundary(p, x, y));
    return d;
}

Extent extent_of(const std::vector<Polygon>& parts, double grow) {
    Extent e = parts_extent(parts);
    e.min_x -= grow, e.min_y -= grow, e.max_x += grow, e.max_y += grow;
    return e;
}

// Area centroid of the footprint parts (holes subtracted), CRS units.
std::array<double, 2> area_centroid(const std::vector<Polygon>& parts) {
    double a = 0, cx = 0, cy = 0;
    auto ring = [&](const Ring& r, double sign) {
        if (r.size() < 3) return;
        const double x0 = r[0].x, y0 = r[0].y;  // relative to a vertex: no cancellation in map coordinates
        double ra = 0, rx = 0, ry = 0;
        for (std::size_t i = 0; i < r.size(); ++i) {
            const double px = r[i].x - x0, py = r[i].y - y0;
            const double qx = r[(i + 1) % r.size()].x - x0, qy = r[(i + 1) % r.size()].y - y0;
            const double c = px * qy - qx * py;
            ra += c, rx += (px + qx) * c, ry += (py + qy) * c;
        }
        if (ra == 0) return;
        const double ar = std::abs(ra) / 2;
        const double gx = x0 + rx / (3 * ra), gy = y0 + ry / (3 * ra);
        a += sign * ar, cx += sign * ar * gx, cy += sign * ar * gy;
    };
    for (const Polygon& p : parts) {
        ring(p.outer, 1.0);
        for (const Ring& h : p.holes) ring(h, -1.0);
    }
    if (!(a > 0)) {
        const Extent e = parts_extent(parts);
        return {0.5 * (e.min_x + e.max_x), 0.5 * (e.min_y + e.max_y)};
    }
    return {cx / a, cy / a};
}

struct GroundFit {
    double z = 0, rmse_m = 0, slope_deg = 0;
    int64_t outliers = 0;
    bool plane = false;
};

// Robust ground under the footprint from ring points (x, y relative to the
// footprint centroid, metres; z in metres). Plane by least squares, trimmed
// three times at max(outlier_m, 3 x 1.4826 MAD); evaluated at (0, 0). A ring
// that cannot hold a plane (fewer than 6 points, spread under 1 m across, or
// a value outside the ring's z range) gives the median.
GroundFit fit_ground(const std::vector<std::array<double, 3>>& q, double outlier_m) {
    GroundFit g;
    std::vector<double> zs;
    for (const auto& p : q) zs.push_back(p[2]);
    std::vector<double> zsorted = zs;
    const double med = *percentile(zsorted, 50.0);
    const double zmin = zsorted.front(), zmax = zsorted.back();
    auto median_fit = [&]() {
        GroundFit m;
        m.z = med;
        std::vector<double> dev;
        for (double z : zs) dev.push_back(std::abs(z - med));
        const double mad = *percentile(dev, 50.0);
        const double lim = std::max(outlier_m, 3.0 * 1.4826 * mad);
        double s2 = 0;
        std::size_t n = 0;
        for (double z : zs)
            if (std::abs(z - med) <= lim) s2 += (z - med) * (z - med), ++n;
            else ++m.outliers;
        m.rmse_m = n ? std::sqrt(s2 / double(n)) : 0.0;
        return m;
    };
    TrimmedPlaneOptions po;
    po.min_trim = outlier_m, po.trim_sigmas = 3.0, po.min_points = 6;
    po.min_spread_sq = 1.0;  // std < 1 m across: the ring is a line
    const std::optional<TrimmedPlane> fit = fit_trimmed_plane(q, po);
    if (!fit) return median_fit();
    const double a = fit->a, b = fit->b, c = fit->c;
    const std::vector<uint8_t>& use = fit->inlier;
    if (!(c >= zmin - 0.5 && c <= zmax + 0.5) || !std::isfinite(c)) return median_fit();
    g.plane = true;
    g.z = c;
    g.slope_deg = std::atan(std::hypot(a, b)) * 180.0 / 3.14159265358979323846;
    double s2 = 0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < q.size(); ++i) {
        if (!use[i]) {
            ++g.outliers;
            continue;
        }
        const double r = q[i][2] - (a * q[i][0] + b * q[i][1] + c);
        s2 += r * r, ++n;
    }
    g.rmse_m = n ? std::sqrt(s2 / double(n)) : 0.0;
    return g;
}

bool is_roof_candidate(uint8_t cls) {
    return cls != las_class::ground && cls != las_class::water && cls != las_class::low_noise && cls != las_class::high_noise;
}

}  // namespace

std::vector<BuildingHeight> compute_building_heights(const PointCloud& c, const std::vector<uint8_t>& keep,
                                                     const std::vector<uint8_t>& is_ground,
                                                     const std::vector<std::vector<Polygon>>& footprints,
                                                     const HeightOptions& o, const Progress& progress) {
    o.validate();
    if (!keep.empty() && keep.size() != c.size()) throw Error("heights", "keep mask size differs from the cloud");
    if (is_ground.size() != c.size()) throw Error("heights", "ground mask size differs from the cloud");
    const double max_buffer = o.ground_buffer_m * 4.0 / o.unit_m;  // CRS units
    const PointGrid grid(c, keep, std::max(2.0 / o.unit_m, 1e-9));
    std::vector<BuildingHeight> out(footprints.size());
    std::atomic<std::size_t> done{0};
    tbb::parallel_for(std::size_t(0), footprints.size(), [&](std::size_t f) {
        const std::vector<Polygon>& parts = footprints[f];
        BuildingHeight& b = out[f];
        {
            const Extent fe = parts_extent(parts);
            if (!((fe.max_x - fe.min_x) * o.unit_m <= kMaxFootprintSide_m && (fe.max_y - fe.min_y) * o.unit_m <= kMaxFootprintSide_m)) {
                b.height_quality = "footprint_too_large";  // its coverage grid alone would not fit in memory
                ++done;
                return;
            }
        }
        const double area_m2 = parts_area(parts) * o.unit_m * o.unit_m;
        // Candidates: points in the bounding box grown by a ground ring. The
        // narrowest ring first; the widest (4x) only when the narrowest lacks
        // ground points. A smaller box visits a subset of the same cells in
        // the same order, so the narrowest ring's points come in the same
        // order either way, and the results are those of the widest box.
        std::vector<double> roof, ground_dist, ground_z;
        std::vector<std::array<double, 2>> ground_xy;
        std::vector<std::pair<double, double>> roof_xy;
        std::vector<uint32_t> roof_id;
        std::vector<uint8_t> roof_is_building;
        const double first_ring = o.ground_buffer_m / o.unit_m;  // the loop's first ring below
        auto gather = [&](double reach) {
            roof.clear(), ground_dist.clear(), ground_z.clear(), ground_xy.clear(), roof_xy.clear(), roof_id.clear(), roof_is_building.clear();
            // The box is grown a little beyond `reach`: every point within `reach` of the parts is in it.
            grid.for_each_in(extent_of(parts, reach * (1.0 + 1e-9) + 1e-9), [&](uint32_t i) {
                const double x = c.x[i], y = c.y[i];
                const bool inside = inside_any(parts, x, y);
                if (is_ground[i]) {
                    if (!inside) {
                        const double d = distance_to_parts(parts, x, y);
                        if (d <= reach) ground_dist.push_back(d), ground_z.push_back(c.z[i]), ground_xy.push_back({x, y});
                    }
                } else if (inside && is_roof_candidate(c.classification[i])) {
                    roof.push_back(c.z[i]);
                    roof_xy.emplace_back(x, y);
                    roof_id.push_back(i);
                    roof_is_building.push_back(c.classification[i] == las_class::building);
                }
            });
        };
        gather(first_ring);
        if (static_cast<int>(ground_z.size()) < o.min_ground_points) gather(max_buffer);
        // Ground: the narrowest ring (1x, 2x, 4x the buffer) with enough points.
        const std::array<double, 2> centroid = area_centroid(parts);
        std::string quality = "good";
        for (int widen = 0; widen < 3; ++widen) {
            const double ring = o.ground_buffer_m * (1 << widen) / o.unit_m;
            std::vector<double> z;
            std::vector<std::size_t> in_ring;
            for (std::size_t k = 0; k < ground_z.size(); ++k)
                if (ground_dist[k] <= ring) z.push_back(ground_z[k]), in_ring.push_back(k);
            if (static_cast<int>(z.size()) >= o.min_ground_points || (widen == 2 && !z.empty())) {
                b.n_points_ground = static_cast<int64_t>(z.size());
                if (o.ground_method == GroundMethod::percentile) {
                    b.ground_z = percentile(z, o.ground_percentile);
                    b.ground_method = "ring_percentile";
                    double s2 = 0;
                    for (double v : z) s2 += (v - *b.ground_z) * (v - *b.ground_z);
                    b.ground_rmse_m = std::sqrt(s2 / double(z.size())) * o.z_unit_m;
                } else {
                    std::vector<std::array<double, 3>> q;
                    q.reserve(in_ring.size());
                    for (std::size_t k : in_ring)
                        q.push_back({(ground_xy[k][0] - centroid[0]) * o.unit_m, (ground_xy[k][1] - centroid[1]) * o.unit_m, ground_z[k] * o.z_unit_m});
                    // Sums in coordinate order, not in the grid index's cell order (which depends on
                    // the cloud window): the same ring gives the same bits in any tile.
                    std::sort(q.begin(), q.end());
                    const GroundFit g = fit_ground(q, o.ground_outlier_m);
                    b.ground_z = g.z / o.z_unit_m;
                    b.ground_method = g.plane ? "ring_plane" : "ring_median";
                    b.ground_rmse_m = g.rmse_m;
                    if (g.plane) b.ground_slope_deg = g.slope_deg;
                    b.n_points_ground_outliers = g.outliers;
                }
                b.ground_buffer_used_m = ring * o.unit_m;
                if (static_cast<int>(z.size()) < o.min_ground_points) quality = "few_ground_points";
                else if (widen > 0) quality = "ground_buffer_widened";
                break;
            }
        }
        if (!b.ground_z) quality = "no_ground";
        // Roof points: above ground by the margin (when the ground is known).
        std::vector<double> roof_kept;
        std::vector<std::pair<double, double>> roof_kept_xy;
        const double margin = o.min_height_above_ground_m / o.z_unit_m;
        std::size_t building_points = 0;
        for (uint8_t v : roof_is_building) building_points += v;
        const bool only_building = o.prefer_building_class && static_cast<int>(building_points) >= o.min_roof_points;
        for (std::size_t k = 0; k < roof.size(); ++k)
            if ((!only_building || roof_is_building[k]) && (!b.ground_z || roof[k] > *b.ground_z + margin))
            {
                roof_kept.push_back(roof[k]), roof_kept_xy.push_back(roof_xy[k]);
                if (o.keep_roof_points) b.roof_points.push_back(roof_id[k]);
            }
        std::sort(b.roof_points.begin(), b.roof_points.end());  // cloud order, whatever the index's cells
        b.n_points_roof = static_cast<int64_t>(roof_kept.size());
        b.point_density_m2 = area_m2 > 0 ? static_cast<double>(roof_kept.size()) / area_m2 : 0.0;
        // Coverage: cells of coverage_cell_m whose centre is inside the footprint.
        {
            const double cell = o.coverage_cell_m / o.unit_m;
            const Extent e = extent_of(parts, 0.0);
            const int w = std::max(1, static_cast<int>(std::ceil((e.max_x - e.min_x) / cell)));
            const int h = std::max(1, static_cast<int>(std::ceil((e.max_y - e.min_y) / cell)));
            std::vector<uint8_t> hit(static_cast<std::size_t>(w) * h, 0);
            for (const auto& [x, y] : roof_kept_xy) {
                const int cx = std::min(w - 1, static_cast<int>((x - e.min_x) / cell));
                const int cy = std::min(h - 1, static_cast<int>((y - e.min_y) / cell));
                hit[static_cast<std::size_t>(cy) * w + cx] = 1;
            }
            std::size_t cells = 0, empty = 0;
            for (int cy = 0; cy < h; ++cy)
                for (int cx = 0; cx < w; ++cx)
                    if (inside_any(parts, e.min_x + (cx + 0.5) * cell, e.min_y + (cy + 0.5) * cell)) {
                        ++cells;
                        empty += !hit[static_cast<std::size_t>(cy) * w + cx];
                    }
            b.nodata_fraction = cells ? static_cast<double>(empty) / static_cast<double>(cells) : 1.0;
        }
        if (roof_kept.empty()) {
            if (quality == "good" || quality == "ground_buffer_widened") quality = "no_roof_points";
        } else if (static_cast<int>(roof_kept.size()) < o.min_roof_points) {
            if (quality == "good" || quality == "ground_buffer_widened") quality = "few_roof_points";
        } else {
            b.roof_z_min = *std::min_element(roof_kept.begin(), roof_kept.end());
            b.roof_z_max = *std::max_element(roof_kept.begin(), roof_kept.end());
            b.roof_z_50p = percentile(roof_kept, 50.0);
            b.roof_z_70p = percentile(roof_kept, 70.0);
            b.roof_z_90p = percentile(roof_kept, 90.0);
            const std::optional<double> chosen = percentile(roof_kept, o.roof_percentile);
            if (chosen && b.ground_z) b.height_m = (*chosen - *b.ground_z) * o.z_unit_m;
            if (quality == "good" && b.point_density_m2 < 1.0) quality = "sparse";
        }
        b.height_quality = quality;
        const std::size_t d = ++done;
        if ((d & 255) == 0) progress(static_cast<double>(d) / static_cast<double>(footprints.size()), "heights");
    });
    progress(1.0, "heights");
    return out;
}

}  // namespace cityforge
