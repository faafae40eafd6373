#include "cloud/cloud_rasters.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "core/error.hpp"
#include "core/grid_fill.hpp"
#include "core/grid_size.hpp"
#include "core/morphology.hpp"

namespace cityforge {

GridSpec grid_over_cloud(const PointCloud& c, double cell, const std::string& subject) {
    if (c.size() == 0) throw Error(subject, "cloud is empty");
    double minx = INFINITY, miny = INFINITY, maxx = -INFINITY, maxy = -INFINITY;
    for (std::size_t i = 0; i < c.size(); ++i) {
        minx = std::min(minx, c.x[i]), maxx = std::max(maxx, c.x[i]);
        miny = std::min(miny, c.y[i]), maxy = std::max(maxy, c.y[i]);
    }
    return grid_over_extent({minx, miny, maxx, maxy}, cell, kCloudRasterBytesPerCell, subject);
}

GridSpec grid_over_extent(const Extent& e, double cell, double bytes_per_cell, const std::string& subject) {
    if (!(cell > 0)) throw Error(subject, "cell size must be > 0");
    if (!(e.min_x <= e.max_x && e.min_y <= e.max_y)) throw Error(subject, "cloud is empty");
    const double minx = e.min_x, miny = e.min_y, maxx = e.max_x, maxy = e.max_y;
    const double x0 = std::floor(minx / cell) * cell, y1 = std::ceil(maxy / cell) * cell;
    const GridSize size = checked_grid_size(x0, miny, maxx, y1, cell, bytes_per_cell > 0 ? bytes_per_cell : kCloudRasterBytesPerCell, subject);
    return GridSpec{{x0, cell, y1, -cell}, size.width, size.height};
}

CloudRasters rasterize_cloud(const PointCloud& c, const std::vector<uint8_t>& keep, const std::vector<uint8_t>& is_ground,
                             const GridSpec& g, double unit_m) {
    return rasterize_cloud(c, keep, is_ground, g, 0, 0, g.width, g.height, unit_m);
}

CloudRasters rasterize_cloud(const PointCloud& c, const std::vector<uint8_t>& keep, const std::vector<uint8_t>& is_ground,
                             const GridSpec& full, int col0, int row0, int width, int height, double unit_m) {
    if (width <= 0 || height <= 0) throw Error("rasterize", "grid has no cells");
    if (is_ground.size() != c.size()) throw Error("rasterize", "ground mask size differs from the cloud");
    // The window's cells, with points placed through the full grid's transform.
    const GridSpec g{full.transform.window(col0, row0), width, height};
    const std::size_t n = static_cast<std::size_t>(g.width) * g.height;
    CloudRasters r;
    r.dsm = Image<float>(g.width, g.height, 1, NAN);
    r.density = Image<float>(g.width, g.height, 1, 0.0f);
    std::vector<double> ground_sum(n, 0.0);
    std::vector<uint32_t> ground_n(n, 0), above_n(n, 0), building_n(n, 0), vegetation_n(n, 0);
    for (std::size_t i = 0; i < c.size(); ++i) {
        if (!keep.empty() && !keep[i]) continue;
        const PixelPoint p = full.transform.map_to_pixel({c.x[i], c.y[i]});
        const auto col = static_cast<int>(std::floor(p.col)) - col0, row = static_cast<int>(std::floor(p.row)) - row0;
        if (col < 0 || row < 0 || col >= g.width || row >= g.height) continue;
        const std::size_t k = static_cast<std::size_t>(row) * g.width + col;
        const auto z = static_cast<float>(c.z[i]);
        if (std::isnan(r.dsm.data[k]) || z > r.dsm.data[k]) r.dsm.data[k] = z;
        r.density.data[k] += 1.0f;
        ++above_n[k];  // all kept points of the cell: shares are majorities of the cell
        if (is_ground[i]) {
            ground_sum[k] += c.z[i], ++ground_n[k];
        } else {
            const uint8_t cls = c.classification[i];
            building_n[k] += cls == las_class::building;
            vegetation_n[k] += cls == 3 || cls == 4 || cls == las_class::vegetation_high;
        }
    }
    r.building_share = Image<float>(g.width, g.height, 1, NAN);
    r.vegetation_share = Image<float>(g.width, g.height, 1, NAN);
    for (std::size_t k = 0; k < n; ++k)
        if (above_n[k]) {
            // Vegetation points are left out of the building share: under a
            // crown that overhangs a roof, the pulses that pierce the crown
            // still tell roof (class 6) from ground.
            if (above_n[k] > vegetation_n[k])
                r.building_share.data[k] = static_cast<float>(building_n[k]) / static_cast<float>(above_n[k] - vegetation_n[k]);
            r.vegetation_share.data[k] = static_cast<float>(vegetation_n[k]) / static_cast<float>(above_n[k]);
        }
    const double cell_m2 = std::abs(g.transform.pixel_width * g.transform.pixel_height) * unit_m * unit_m;
    for (float& d : r.density.data) d = static_cast<float>(d / cell_m2);
    std::vector<double> dtm(n);
    for (std::size_t k = 0; k < n; ++k) dtm[k] = ground_n[k] ? ground_sum[k] / ground_n[k] : NAN;
    // Filled from ground within kGapFillReach_m (a cell depends on nearby ground only: tiles agree).
    // Terrain only where the cloud saw something: a cell with no kept point
    // within the fill's reach along both axes (a square of 2 kGapFillReach_m
    // a side centred on it) lies beyond the survey (the box of a corridor, a
    // lake without returns) and stays empty, as PDAL's and LAStools' rasters
    // leave it, instead of an extrapolation from ground kilometres away.
    // Under a roof the cell holds the roof's points, so buildings of any size
    // keep their filled ground.
    const int reach = gap_fill_reach_cells(std::abs(g.transform.pixel_width) * unit_m);
    std::vector<uint8_t> seen(n);
    for (std::size_t k = 0; k < n; ++k) seen[k] = above_n[k] ? 1 : 0;
    seen = morphology_square(seen, g.width, g.height, reach, /*erode=*/false);
    fill_gaps(dtm, g.width, g.height, reach, &seen);
    r.dtm = Image<float>(g.width, g.height, 1, NAN);
    r.ndsm = Image<float>(g.width, g.height, 1, NAN);
    for (std::size_t k = 0; k < n; ++k) {
        r.dtm.data[k] = static_cast<float>(dtm[k]);
        if (!std::isnan(r.dsm.data[k]) && !std::isnan(dtm[k])) r.ndsm.data[k] = static_cast<float>(r.dsm.data[k] - dtm[k]);
    }
    return r;
}

}  // namespace cityforge
