#include "heights/building_heights.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <tbb/parallel_for.h>

#include "core/error.hpp"

namespace cityforge {

void HeightOptions::validate() const {
    if (!(ground_buffer_m > 0.0)) throw Error("--ground-buffer-m", "must be > 0");
    if (!(ground_percentile >= 0.0 && ground_percentile <= 100.0)) throw Error("--ground-percentile", "must be between 0 and 100");
    if (!(roof_percentile >= 0.0 && roof_percentile <= 100.0)) throw Error("--roof-percentile", "must be between 0 and 100");
    if (min_ground_points < 1) throw Error("--min-ground-points", "must be >= 1");
    if (min_roof_points < 1) throw Error("--min-roof-points", "must be >= 1");
    if (!(coverage_cell_m > 0.0)) throw Error("--coverage-cell-m", "must be > 0");
    if (!(unit_m > 0.0) || !(z_unit_m > 0.0)) throw Error("units", "CRS units must be > 0 metres");
}

std::optional<double> percentile(std::vector<double>& v, double p) {
    if (v.empty()) return std::nullopt;
    std::sort(v.begin(), v.end());
    const double pos = p / 100.0 * static_cast<double>(v.size() - 1);
    const auto lo = static_cast<std::size_t>(std::floor(pos));
    const std::size_t hi = std::min(lo + 1, v.size() - 1);
    return v[lo] + (v[hi] - v[lo]) * (pos - static_cast<double>(lo));
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
        if (!std::isfinite(minx_)) return;
        w_ = static_cast<int>((maxx - minx_) / cell_) + 1;
        h_ = static_cast<int>((maxy - miny_) / cell_) + 1;
        start_.assign(static_cast<std::size_t>(w_) * h_ + 1, 0);
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
        const int x0 = std::max(0, static_cast<int>(std::floor((e.min_x - minx_) / cell_)));
        const int x1 = std::min(w_ - 1, static_cast<int>(std::floor((e.max_x - minx_) / cell_)));
        const int y0 = std::max(0, static_cast<int>(std::floor((e.min_y - miny_) / cell_)));
        const int y1 = std::min(h_ - 1, static_cast<int>(std::floor((e.max_y - miny_) / cell_)));
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w_ + x;
                for (uint32_t j = start_[k]; j < start_[k + 1]; ++j) f(ids_[j]);
            }
    }

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
        const double area_m2 = parts_area(parts) * o.unit_m * o.unit_m;
        // Candidates: points in the bounding box grown by the widest ground ring.
        std::vector<double> roof, ground_dist, ground_z;
        std::vector<std::pair<double, double>> roof_xy;
        std::vector<uint32_t> roof_id;
        std::vector<uint8_t> roof_is_building;
        grid.for_each_in(extent_of(parts, max_buffer), [&](uint32_t i) {
            const double x = c.x[i], y = c.y[i];
            const bool inside = inside_any(parts, x, y);
            if (is_ground[i]) {
                if (!inside) {
                    const double d = distance_to_parts(parts, x, y);
                    if (d <= max_buffer) ground_dist.push_back(d), ground_z.push_back(c.z[i]);
                }
            } else if (inside && is_roof_candidate(c.classification[i])) {
                roof.push_back(c.z[i]);
                roof_xy.emplace_back(x, y);
                roof_id.push_back(i);
                roof_is_building.push_back(c.classification[i] == las_class::building);
            }
        });
        // Ground: the narrowest ring (1x, 2x, 4x the buffer) with enough points.
        std::string quality = "good";
        for (int widen = 0; widen < 3; ++widen) {
            const double ring = o.ground_buffer_m * (1 << widen) / o.unit_m;
            std::vector<double> z;
            for (std::size_t k = 0; k < ground_z.size(); ++k)
                if (ground_dist[k] <= ring) z.push_back(ground_z[k]);
            if (static_cast<int>(z.size()) >= o.min_ground_points || (widen == 2 && !z.empty())) {
                b.n_points_ground = static_cast<int64_t>(z.size());
                b.ground_z = percentile(z, o.ground_percentile);
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
