#include "cloud/cloud_filters.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <tuple>
#include <tbb/parallel_for.h>

#include "cloud/kd_tree.hpp"
#include "core/error.hpp"
#include "core/grid_fill.hpp"
#include "core/morphology.hpp"

namespace cityforge {

void OutlierFilterOptions::validate() const {
    if (k_neighbours < 1 || k_neighbours > 100) throw Error("--sor-k", "must be between 1 and 100");
    if (!(std_multiplier > 0.0)) throw Error("--sor-std", "must be > 0");
    if (!(max_mean_distance >= 0.0)) throw Error("outlier_limit_m", "must be >= 0");
    if (!(isolated_radius >= 0.0)) throw Error("--isolated-radius", "must be >= 0");
    if (isolated_min_neighbours < 0) throw Error("--isolated-min", "must be >= 0");
}

void GroundFilterOptions::validate() const {
    if (!(cell > 0.0)) throw Error("--smrf-cell", "must be > 0");
    if (!(slope >= 0.0)) throw Error("--smrf-slope", "must be >= 0");
    if (!(window >= cell)) throw Error("--smrf-window", "must be at least one cell");
    if (!(elevation_threshold > 0.0)) throw Error("--smrf-threshold", "must be > 0");
}


void canonical_order(PointCloud& c) {
    const std::size_t n = c.size();
    std::vector<std::size_t> order(n);
    std::iota(order.begin(), order.end(), std::size_t(0));
    const bool gps = c.has_gps_time(), rgb = c.has_color();
    auto key = [&](std::size_t i) {
        return std::make_tuple(c.x[i], c.y[i], c.z[i], gps ? c.gps_time[i] : 0.0, c.intensity[i], c.classification[i], c.return_number[i],
                               c.number_of_returns[i], rgb ? c.red[i] : 0, rgb ? c.green[i] : 0, rgb ? c.blue[i] : 0);
    };
    bool sorted = true;
    for (std::size_t i = 1; i < n && sorted; ++i) sorted = !(key(i) < key(i - 1));
    if (sorted) return;
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return key(a) < key(b); });
    auto permute = [&](auto& v) {
        if (v.empty()) return;
        std::remove_reference_t<decltype(v)> out(n);
        for (std::size_t i = 0; i < n; ++i) out[i] = v[order[i]];
        v.swap(out);
    };
    permute(c.x), permute(c.y), permute(c.z), permute(c.gps_time), permute(c.intensity), permute(c.classification);
    permute(c.return_number), permute(c.number_of_returns), permute(c.red), permute(c.green), permute(c.blue);
}

OutlierFilterResult filter_outliers(const PointCloud& c, const OutlierFilterOptions& o) {
    o.validate();
    OutlierFilterResult r;
    const std::size_t n = c.size();
    r.keep.assign(n, 1);
    for (std::size_t i = 0; i < n; ++i)
        if (c.classification[i] == las_class::low_noise || c.classification[i] == las_class::high_noise) r.keep[i] = 0, ++r.removed_statistical;
    if (!o.enabled || n < static_cast<std::size_t>(o.k_neighbours) + 1) return r;
    double ox = INFINITY, oy = INFINITY, oz = INFINITY;
    for (std::size_t i = 0; i < n; ++i) ox = std::min(ox, c.x[i]), oy = std::min(oy, c.y[i]), oz = std::min(oz, c.z[i]);
    // A local origin at multiples of 256 units: windows of one cloud mostly round alike.
    ox = std::floor(ox / 256.0) * 256.0, oy = std::floor(oy / 256.0) * 256.0, oz = std::floor(oz / 256.0) * 256.0;
    const LocalPoints local = local_points(c, ox, oy, oz);
    PointTree tree(3, local, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    tree.buildIndex();
    // One k-nearest-neighbour pass serves both filters: the isolated-point test
    // only needs the distance to the m-th neighbour (m = isolated_min_neighbours).
    // A few more candidates than needed are asked of the float tree and ranked
    // again by (double distance, index): with points in canonical order the
    // neighbours do not depend on the tree's shape (the window), not even at ties.
    const std::size_t want = static_cast<std::size_t>(std::max(o.k_neighbours, o.isolated_min_neighbours)) + 1;  // self first
    const std::size_t k = std::min(n, want + 4);
    const auto m = static_cast<std::size_t>(o.isolated_min_neighbours);
    std::vector<double> mean_dist(n, 0.0);
    std::vector<uint8_t> isolated(n, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const tbb::blocked_range<std::size_t>& range) {
        std::vector<uint32_t> idx(k);
        std::vector<float> d2(k);
        std::vector<std::pair<double, uint32_t>> ranked(k);
        for (std::size_t i = range.begin(); i != range.end(); ++i) {
            const float* q = &local.xyz[3 * i];
            const std::size_t found = tree.knnSearch(q, k, idx.data(), d2.data());
            ranked.clear();
            for (std::size_t j = 0; j < found; ++j) {
                const std::size_t a = idx[j];
                const double dx = c.x[a] - c.x[i], dy = c.y[a] - c.y[i], dz = c.z[a] - c.z[i];
                // The point itself first, whatever the rounding.
                ranked.emplace_back(a == i ? -1.0 : std::sqrt(dx * dx + dy * dy + dz * dz), idx[j]);
            }
            std::sort(ranked.begin(), ranked.end());
            const std::size_t have = std::min(found, want);
            double s = 0.0;
            const std::size_t used = std::min(have, static_cast<std::size_t>(o.k_neighbours) + 1);
            for (std::size_t j = 1; j < used; ++j) s += ranked[j].first;
            mean_dist[i] = used > 1 ? s / static_cast<double>(used - 1) : 0.0;
            if (o.isolated_radius > 0.0 && m > 0) isolated[i] = have <= m || ranked[m].first > o.isolated_radius;
        }
    });
    // Sums in index order: the threshold does not depend on the thread count.
    double sum = 0.0, sum2 = 0.0;
    for (double d : mean_dist) sum += d, sum2 += d * d;
    const double mean = sum / static_cast<double>(n);
    const double sigma = std::sqrt(std::max(0.0, sum2 / static_cast<double>(n) - mean * mean));
    const double limit = o.max_mean_distance > 0 ? o.max_mean_distance : mean + o.std_multiplier * sigma;
    r.limit = limit;
    for (std::size_t i = 0; i < n; ++i)
        if (r.keep[i] && mean_dist[i] > limit) r.keep[i] = 0, ++r.removed_statistical;
    for (std::size_t i = 0; i < n; ++i)
        if (r.keep[i] && isolated[i]) r.keep[i] = 0, ++r.removed_isolated;
    return r;
}

GroundResult classify_ground(const PointCloud& c, const std::vector<uint8_t>& keep, const GroundFilterOptions& o) {
    o.validate();
    GroundResult g;
    const std::size_t n = c.size();
    g.is_ground.assign(n, 0);
    auto kept = [&](std::size_t i) { return keep.empty() || keep[i]; };
    if (o.trust_classification) {
        std::size_t class2 = 0;
        for (std::size_t i = 0; i < n; ++i) class2 += c.classification[i] == las_class::ground && kept(i);
        if (class2 > 0) {
            for (std::size_t i = 0; i < n; ++i) g.is_ground[i] = c.classification[i] == las_class::ground && kept(i);
            g.from_classification = true;
            g.ground_points = class2;
            return g;
        }
    }
    if (n == 0) return g;
    // SMRF: minimum surface on a grid, holes filled from neighbours, then
    // progressive openings with growing windows; cells whose height drops by
    // more than slope * window * cell are non-ground.
    double minx = INFINITY, miny = INFINITY, maxx = -INFINITY, maxy = -INFINITY;
    for (std::size_t i = 0; i < n; ++i)
        if (kept(i)) minx = std::min(minx, c.x[i]), maxx = std::max(maxx, c.x[i]), miny = std::min(miny, c.y[i]), maxy = std::max(maxy, c.y[i]);
    if (!std::isfinite(minx)) return g;
    // Cells anchored at multiples of the cell size: every window of a cloud
    // uses the same cells, so its ground does not depend on where it starts.
    minx = std::floor(minx / o.cell) * o.cell, miny = std::floor(miny / o.cell) * o.cell;
    const int w = static_cast<int>((maxx - minx) / o.cell) + 1, h = static_cast<int>((maxy - miny) / o.cell) + 1;
    if (static_cast<double>(w) * h > 4e8) throw Error("ground filter", "cloud extent too large for one SMRF grid; tile it first");
    std::vector<double> zmin(static_cast<std::size_t>(w) * h, INFINITY);
    auto cell_of = [&](std::size_t i) {
        const int cx = std::min(w - 1, static_cast<int>((c.x[i] - minx) / o.cell));
        const int cy = std::min(h - 1, static_cast<int>((c.y[i] - miny) / o.cell));
        return static_cast<std::size_t>(cy) * w + cx;
    };
    for (std::size_t i = 0; i < n; ++i)
        if (kept(i)) zmin[cell_of(i)] = std::min(zmin[cell_of(i)], c.z[i]);
    for (double& v : zmin)
        if (!std::isfinite(v)) v = NAN;
    fill_gaps(zmin, w, h);
    std::vector<uint8_t> object(zmin.size(), 0);
    std::vector<double> surface = zmin;
    const int max_r = std::max(1, static_cast<int>(std::ceil(o.window / o.cell)));
    for (int r = 1; r <= max_r; ++r) {
        const std::vector<double> opened = morphology_square(morphology_square(surface, w, h, r, true), w, h, r, false);
        const double threshold = o.slope * r * o.cell;
        for (std::size_t k = 0; k < surface.size(); ++k)
            if (surface[k] - opened[k] > threshold) object[k] = 1;
        surface = opened;
    }
    // Provisional DTM: minimum surface at ground cells, object cells inpainted.
    std::vector<double> dtm = zmin;
    for (std::size_t k = 0; k < dtm.size(); ++k)
        if (object[k]) dtm[k] = NAN;
    fill_gaps(dtm, w, h);
    // Local slope of the DTM scales the threshold (steep terrain tolerates more).
    for (std::size_t i = 0; i < n; ++i) {
        if (!kept(i)) continue;
        const std::size_t k = cell_of(i);
        const int x = static_cast<int>(k % static_cast<std::size_t>(w)), y = static_cast<int>(k / static_cast<std::size_t>(w));
        const double gx = (dtm[static_cast<std::size_t>(y) * w + std::min(w - 1, x + 1)] - dtm[static_cast<std::size_t>(y) * w + std::max(0, x - 1)]) / (2 * o.cell);
        const double gy = (dtm[static_cast<std::size_t>(std::min(h - 1, y + 1)) * w + x] - dtm[static_cast<std::size_t>(std::max(0, y - 1)) * w + x]) / (2 * o.cell);
        const double threshold = o.elevation_threshold + o.elevation_scalar * std::sqrt(gx * gx + gy * gy);
        if (std::isfinite(dtm[k]) && std::abs(c.z[i] - dtm[k]) <= threshold) g.is_ground[i] = 1, ++g.ground_points;
    }
    return g;
}

}  // namespace cityforge
