#include "pipeline/cloud_cells.hpp"

#include <algorithm>
#include <cmath>

#include "core/error.hpp"

namespace cityforge {

int cloud_cell_factor(double points_per_m2, double gsd_m, double min_points_per_cell) {
    if (!(points_per_m2 > 0) || !(gsd_m > 0)) return 1;
    const double f = std::ceil(std::sqrt(min_points_per_cell / points_per_m2) / gsd_m - 0.05);
    return static_cast<int>(std::clamp(f, 1.0, 64.0));
}

namespace {
// Coarse image -> window pixels: pixel (x, y) takes coarse cell
// ((col0 + x - c0) / f, (row0 + y - r0) / f).
template <typename T>
Image<T> repeat(const Image<T>& coarse, int w, int h, int dx, int dy, int f) {
    Image<T> out(w, h, 1);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) out.at(0, x, y) = coarse.at(0, (x + dx) / f, (y + dy) / f);
    return out;
}
std::vector<uint8_t> repeat(const std::vector<uint8_t>& coarse, int cw, int w, int h, int dx, int dy, int f) {
    std::vector<uint8_t> out(static_cast<std::size_t>(w) * h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) out[static_cast<std::size_t>(y) * w + x] = coarse[static_cast<std::size_t>((y + dy) / f) * cw + (x + dx) / f];
    return out;
}
}  // namespace

GridSpec cloud_cell_grid(const GridSpec& window, int col0, int row0, int factor) {
    if (factor < 1) throw Error("cloud cells", "cell factor must be >= 1");
    if (factor == 1) return window;
    const auto floor_div = [factor](int v) { return (v >= 0 ? v : v - factor + 1) / factor * factor; };
    const int dx = col0 - floor_div(col0), dy = row0 - floor_div(row0);
    const GeoTransform& t = window.transform;
    return {{t.origin_x - dx * t.pixel_width, t.pixel_width * factor, t.origin_y - dy * t.pixel_height, t.pixel_height * factor},
            (dx + window.width + factor - 1) / factor, (dy + window.height + factor - 1) / factor};
}

WindowCloudCells cloud_cells_on_window(const PreparedCloud& pc, const GridSpec& window, int col0, int row0, int factor, double unit_m,
                                       const BuildingMaskOptions& options) {
    const GridSpec coarse = cloud_cell_grid(window, col0, row0, factor);
    return cloud_cells_from_rasters(rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, coarse, unit_m), window.width, window.height, col0, row0,
                                    factor, options);
}

WindowCloudCells cloud_cells_from_rasters(CloudRasters cr, int w, int h, int col0, int row0, int factor, const BuildingMaskOptions& options) {
    if (factor < 1) throw Error("cloud cells", "cell factor must be >= 1");
    WindowCloudCells out;
    if (factor == 1) {
        BuildingMaskOptions go = options;
        go.grid_col0 = col0, go.grid_row0 = row0;
        out.rasters = std::move(cr);
        out.cells = building_cells(out.rasters.ndsm, out.rasters.dsm, out.rasters.building_share, out.rasters.vegetation_share, go);
        if (out.cells.used_classes) {
            // Point counts back from the density (points per m2) and the shares.
            const double cell_m2 = options.gsd_m * options.gsd_m;
            const std::size_t n = out.rasters.density.data.size();
            out.cells.roof_points.assign(n, 0), out.cells.ground_points.assign(n, 0);
            for (std::size_t k = 0; k < n; ++k) {
                const double all = std::round(out.rasters.density.data[k] * cell_m2);
                const float v = out.rasters.vegetation_share.data[k], b = out.rasters.building_share.data[k];
                const double other = std::isnan(v) ? all : std::round(all * (1.0 - v));  // not vegetation
                const double roof = std::isnan(b) ? 0.0 : std::round(other * b);
                out.cells.roof_points[k] = static_cast<uint8_t>(std::clamp(roof, 0.0, 255.0));
                out.cells.ground_points[k] = static_cast<uint8_t>(std::clamp(other - roof, 0.0, 255.0));
            }
        }
        return out;
    }
    // Coarse cells anchored at global multiples of the factor.
    const auto floor_div = [factor](int v) { return (v >= 0 ? v : v - factor + 1) / factor * factor; };
    const int c0 = floor_div(col0), r0 = floor_div(row0);
    const int dx = col0 - c0, dy = row0 - r0;
    const int cw = (dx + w + factor - 1) / factor;
    if (cr.dsm.width != cw || cr.dsm.height != (dy + h + factor - 1) / factor) throw Error("cloud cells", "coarse rasters differ from the cell grid");
    BuildingMaskOptions co = options;
    co.gsd_m = options.gsd_m * factor;
    co.grid_col0 = c0 / factor, co.grid_row0 = r0 / factor;
    const BuildingCells cc = building_cells(cr.ndsm, cr.dsm, cr.building_share, cr.vegetation_share, co);
    out.rasters.dsm = repeat(cr.dsm, w, h, dx, dy, factor);
    out.rasters.dtm = repeat(cr.dtm, w, h, dx, dy, factor);
    out.rasters.ndsm = repeat(cr.ndsm, w, h, dx, dy, factor);
    out.rasters.density = repeat(cr.density, w, h, dx, dy, factor);
    out.rasters.building_share = repeat(cr.building_share, w, h, dx, dy, factor);
    out.rasters.vegetation_share = repeat(cr.vegetation_share, w, h, dx, dy, factor);
    out.cells.cells = repeat(cc.cells, cw, w, h, dx, dy, factor);
    out.cells.evidence = repeat(cc.evidence, cw, w, h, dx, dy, factor);
    out.cells.step_dsm = repeat(cc.step_dsm, w, h, dx, dy, factor);
    out.cells.used_classes = cc.used_classes;
    return out;
}

}  // namespace cityforge
