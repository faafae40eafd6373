#include "core/grid_fill.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

namespace cityforge {

// Directional inverse-distance fill: every gap cell takes the 1/d² weighted
// mean of the nearest valid cell along each of the 8 compass directions. One
// sweep per direction finds them all (O(cells)). The value of a cell depends
// only on cells up to its gap's edge, so filling a window of a larger grid
// gives the same values wherever the window's border is farther than the
// gap's extent; with a reach, farther than the reach (unless no valid cell lies
// within it on any ray): what tiled processing needs.
namespace {
// One pass of the 8 directional sweeps: adds 1/d^2-weighted values of the nearest
// valid cell along each ray (within `limit` cells when > 0) to num/den.
void sweep(const std::vector<double>& g, int w, int h, int limit, std::vector<double>& num, std::vector<double>& den) {
    const std::size_t cells = static_cast<std::size_t>(w) * h;
    static const std::array<std::array<int, 2>, 8> dirs{{{1, 0}, {-1, 0}, {0, 1}, {0, -1}, {1, 1}, {-1, -1}, {1, -1}, {-1, 1}}};
    // Last valid value and its position seen when walking against the direction.
    std::vector<double> last_v(cells);
    std::vector<int32_t> last_d(cells);
    for (const auto& d : dirs) {
        const int dx = d[0], dy = d[1];
        const double step = (dx && dy) ? std::sqrt(2.0) : 1.0;
        // Visit cells so that (x - dx, y - dy) comes before (x, y).
        const int y0 = dy >= 0 ? 0 : h - 1, y1 = dy >= 0 ? h : -1, ys = dy >= 0 ? 1 : -1;
        const int x0 = dx >= 0 ? 0 : w - 1, x1 = dx >= 0 ? w : -1, xs = dx >= 0 ? 1 : -1;
        for (int y = y0; y != y1; y += ys)
            for (int x = x0; x != x1; x += xs) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                if (!std::isnan(g[k])) {
                    last_v[k] = g[k], last_d[k] = 0;
                    continue;
                }
                const int px = x - dx, py = y - dy;
                if (px < 0 || py < 0 || px >= w || py >= h) {
                    last_d[k] = -1;
                    continue;
                }
                const std::size_t pk = static_cast<std::size_t>(py) * w + px;
                if (last_d[pk] < 0 || (limit > 0 && last_d[pk] + 1 > limit)) {
                    last_d[k] = -1;
                    continue;
                }
                last_d[k] = last_d[pk] + 1, last_v[k] = last_v[pk];
                const double dist = last_d[k] * step, wgt = 1.0 / (dist * dist);
                num[k] += wgt * last_v[k], den[k] += wgt;
            }
    }
}
}  // namespace

int gap_fill_reach_cells(double cell_m) { return std::max(1, static_cast<int>(std::ceil(kGapFillReach_m / cell_m))); }

void fill_gaps(std::vector<double>& g, int w, int h, int max_ray_cells) {
    bool any_gap = false, any_valid = false;
    double sum = 0.0;
    std::size_t n_valid = 0;
    for (double v : g) {
        if (std::isnan(v)) any_gap = true;
        else any_valid = true, sum += v, ++n_valid;
    }
    if (!any_gap || !any_valid) return;
    const std::size_t cells = static_cast<std::size_t>(w) * h;
    std::vector<double> num(cells, 0.0), den(cells, 0.0);
    sweep(g, w, h, max_ray_cells, num, den);
    if (max_ray_cells > 0) {
        // Cells with no valid cell within reach on any ray: the unlimited fill.
        bool far = false;
        for (std::size_t k = 0; k < cells && !far; ++k) far = std::isnan(g[k]) && !(den[k] > 0);
        if (far) {
            std::vector<double> num_all(cells, 0.0), den_all(cells, 0.0);
            sweep(g, w, h, 0, num_all, den_all);
            for (std::size_t k = 0; k < cells; ++k)
                if (std::isnan(g[k]) && !(den[k] > 0)) num[k] = num_all[k], den[k] = den_all[k];
        }
    }
    const double mean = sum / double(n_valid);
    for (std::size_t k = 0; k < cells; ++k)
        if (std::isnan(g[k])) g[k] = den[k] > 0 ? num[k] / den[k] : mean;  // enclosed on all 8 rays: the mean ground
}

}  // namespace cityforge
