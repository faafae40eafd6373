#include "core/grid_fill.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace cityforge {

void fill_gaps(std::vector<double>& g, int w, int h) {
    bool any_gap = false, any_valid = false;
    for (double v : g) (std::isnan(v) ? any_gap : any_valid) = true;
    if (!any_gap || !any_valid) return;
    if (w <= 1 && h <= 1) return;
    // Coarser level: 2x2 averages of valid cells.
    const int cw = (w + 1) / 2, ch = (h + 1) / 2;
    std::vector<double> coarse(static_cast<std::size_t>(cw) * ch, NAN);
    for (int y = 0; y < ch; ++y)
        for (int x = 0; x < cw; ++x) {
            double s = 0.0;
            int n = 0;
            for (int dy = 0; dy < 2; ++dy)
                for (int dx = 0; dx < 2; ++dx) {
                    const int xx = 2 * x + dx, yy = 2 * y + dy;
                    if (xx >= w || yy >= h) continue;
                    const double v = g[static_cast<std::size_t>(yy) * w + xx];
                    if (!std::isnan(v)) s += v, ++n;
                }
            if (n) coarse[static_cast<std::size_t>(y) * cw + x] = s / n;
        }
    fill_gaps(coarse, cw, ch);
    std::vector<uint8_t> was_gap(g.size(), 0);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * w + x;
            if (!std::isnan(g[k])) continue;
            was_gap[k] = 1;
            // Bilinear interpolation of the coarse level at this cell's centre.
            const double fx = std::clamp((x + 0.5) / 2.0 - 0.5, 0.0, cw - 1.0), fy = std::clamp((y + 0.5) / 2.0 - 0.5, 0.0, ch - 1.0);
            const int x0 = static_cast<int>(fx), y0 = static_cast<int>(fy);
            const int x1 = std::min(x0 + 1, cw - 1), y1 = std::min(y0 + 1, ch - 1);
            const double tx = fx - x0, ty = fy - y0;
            auto c = [&](int xx, int yy) { return coarse[static_cast<std::size_t>(yy) * cw + xx]; };
            g[k] = (c(x0, y0) * (1 - tx) + c(x1, y0) * tx) * (1 - ty) + (c(x0, y1) * (1 - tx) + c(x1, y1) * tx) * ty;
        }
    // Relaxation of the filled cells towards the mean of their 4 neighbours.
    for (int pass = 0; pass < 4; ++pass)
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                if (!was_gap[k]) continue;
                double s = 0.0;
                int n = 0;
                if (x > 0) s += g[k - 1], ++n;
                if (x < w - 1) s += g[k + 1], ++n;
                if (y > 0) s += g[k - static_cast<std::size_t>(w)], ++n;
                if (y < h - 1) s += g[k + static_cast<std::size_t>(w)], ++n;
                if (n) g[k] = s / n;
            }
}

}  // namespace cityforge
