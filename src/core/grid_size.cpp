#include "core/grid_size.hpp"

#include <cmath>
#include <cstdio>

#include "core/error.hpp"

namespace cityforge {

void require_finite_extent(double min_x, double min_y, double max_x, double max_y, const std::string& subject) {
    const double ex = max_x - min_x, ey = max_y - min_y;
    if (std::isfinite(ex) && std::isfinite(ey) && ex >= 0.0 && ey >= 0.0) return;
    char b[320];
    std::snprintf(b, sizeof b, "data extent [%.6g, %.6g] x [%.6g, %.6g] is not finite: coordinates of 1e308, NaN or Inf in the input?",
                  min_x, max_x, min_y, max_y);
    throw Error(subject, b);
}

GridSize checked_grid_size(double min_x, double min_y, double max_x, double max_y, double cell, std::size_t points,
                           const std::string& subject, double max_cells) {
    if (!(cell > 0.0) || !std::isfinite(cell)) throw Error(subject, "grid cell size must be a finite value > 0");
    require_finite_extent(min_x, min_y, max_x, max_y, subject);
    const double ex = max_x - min_x, ey = max_y - min_y;
    char b[320];
    const double w = std::floor(ex / cell) + 1.0, h = std::floor(ey / cell) + 1.0;
    const double cells = w * h;
    const double density_cap = points == 0 ? max_cells : kGridFreeCells + kGridCellsPerPoint * static_cast<double>(points);  // 0: unknown
    if (w > 2.0e9 || h > 2.0e9 || cells > max_cells || cells > density_cap) {
        std::snprintf(b, sizeof b,
                      "grid too large: a data extent of %.6g x %.6g units at cells of %.6g needs %.4g cells for %zu points "
                      "(at most %.4g): points far from the rest (corrupt coordinates, a wrong CRS) or too fine a cell",
                      ex, ey, cell, cells, points, std::min(max_cells, density_cap));
        throw Error(subject, b);
    }
    return {static_cast<int>(w), static_cast<int>(h)};
}

}  // namespace cityforge
