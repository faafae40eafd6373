#include "core/grid_size.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/error.hpp"
#include "core/memory.hpp"

namespace cityforge {

void require_finite_extent(double min_x, double min_y, double max_x, double max_y, const std::string& subject) {
    const double ex = max_x - min_x, ey = max_y - min_y;
    if (std::isfinite(ex) && std::isfinite(ey) && ex >= 0.0 && ey >= 0.0) return;
    char b[320];
    std::snprintf(b, sizeof b, "data extent [%.6g, %.6g] x [%.6g, %.6g] is not finite: coordinates of 1e308, NaN or Inf in the input?",
                  min_x, max_x, min_y, max_y);
    throw Error(subject, b);
}

GridSize checked_grid_size(double min_x, double min_y, double max_x, double max_y, double cell, double bytes_per_cell,
                           const std::string& subject, double max_cells) {
    if (!(cell > 0.0) || !std::isfinite(cell)) throw Error(subject, "grid cell size must be a finite value > 0");
    require_finite_extent(min_x, min_y, max_x, max_y, subject);
    const double ex = max_x - min_x, ey = max_y - min_y;
    char b[400];
    const double w = std::floor(ex / cell) + 1.0, h = std::floor(ey / cell) + 1.0;
    const double cells = w * h;
    if (w > 2.0e9 || h > 2.0e9 || cells > max_cells) {
        std::snprintf(b, sizeof b,
                      "grid too large: a data extent of %.6g x %.6g units at cells of %.6g needs %.4g cells (at most %.4g): "
                      "points far from the rest (corrupt coordinates, a wrong CRS) or too fine a cell",
                      ex, ey, cell, cells, max_cells);
        throw Error(subject, b);
    }
    const double bytes = cells * std::max(0.0, bytes_per_cell);
    const double usable = usable_memory_bytes();
    if (usable > 0.0 && bytes > kGridMemoryShare * usable) {
        std::snprintf(b, sizeof b,
                      "a grid of %.0f x %.0f cells (a data extent of %.6g x %.6g units at cells of %.6g) needs %s, more than %.0f %% "
                      "of the %s this process may use: points far from the rest (corrupt coordinates, a wrong CRS), too fine a "
                      "cell, or crop the cloud",
                      w, h, ex, ey, cell, format_bytes(bytes).c_str(), kGridMemoryShare * 100.0, format_bytes(usable).c_str());
        throw OutOfMemory(subject, b);
    }
    return {static_cast<int>(w), static_cast<int>(h)};
}

}  // namespace cityforge
