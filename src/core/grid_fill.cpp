#include "core/grid_fill.hpp"

#include "core/error.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace cityforge {

// Directional inverse-distance fill: every gap cell takes the 1/d² weighted
// mean of the nearest valid cell along each of the 8 compass directions. One
// sweep per direction finds them all (O(cells)). The value of a cell depends
// only on cells up to its gap's edge, so filling a window of a larger grid
// gives the same values wherever the window's border is farther than the
// gap's extent; with a reach, farther than the reach (unless no valid cell lies
// within it on any ray): what tiled processing needs.
namespace {
// The 8 directional sweeps: adds 1/d^2-weighted values of the nearest valid
// cell along each ray (within `limit` cells when > 0) to num/den, direction
// by direction in a fixed order. With a limit, a cell's nearest valid cell on
// a ray lies at most `limit` rows back, so strips of rows are swept in
// parallel, each starting `limit` rows before its first row (the same values
// as one sweep over the whole grid, whatever the thread count); without a
// limit the grid is one strip.
void sweep(const double* g, int w, int h, int limit, double* num, double* den) {
    static const std::array<std::array<int, 2>, 8> dirs{{{1, 0}, {-1, 0}, {0, 1}, {0, -1}, {1, 1}, {-1, -1}, {1, -1}, {-1, 1}}};
    const int strip = limit > 0 ? std::max(256, 4 * limit) : h;
    const int strips = (h + strip - 1) / strip;
    tbb::parallel_for(tbb::blocked_range<int>(0, strips, 1), [&](const tbb::blocked_range<int>& range) {
        // Last valid value and its distance (cells; -1 = none within reach)
        // seen when walking against the direction: the previous row's and
        // this row's.
        std::vector<double> prev_v(static_cast<std::size_t>(w)), cur_v(static_cast<std::size_t>(w));
        std::vector<int32_t> prev_d(static_cast<std::size_t>(w)), cur_d(static_cast<std::size_t>(w));
        for (int s = range.begin(); s != range.end(); ++s) {
            const int ya = s * strip, yb = std::min(h, ya + strip);  // rows of this strip
            for (const auto& d : dirs) {
                const int dx = d[0], dy = d[1];
                const double step = (dx && dy) ? std::sqrt(2.0) : 1.0;
                // Visit cells so that (x - dx, y - dy) comes before (x, y),
                // starting `limit` rows before the strip along the ray.
                const int y_first = dy == 0 ? ya : dy > 0 ? std::max(0, ya - limit) : std::min(h, yb + limit) - 1;
                const int y_end = dy >= 0 ? yb : ya - 1, ys = dy >= 0 ? 1 : -1;
                const int x0 = dx >= 0 ? 0 : w - 1, x1 = dx >= 0 ? w : -1, xs = dx >= 0 ? 1 : -1;
                for (int y = y_first; y != y_end; y += ys) {
                    const bool first_row = y == y_first;  // the row before counts as outside the grid
                    const bool accumulate = y >= ya && y < yb;
                    const double* row = g + static_cast<std::size_t>(y) * w;
                    for (int x = x0; x != x1; x += xs) {
                        if (!std::isnan(row[x])) {
                            cur_v[x] = row[x], cur_d[x] = 0;
                            continue;
                        }
                        const int px = x - dx;
                        if (px < 0 || px >= w || (dy != 0 && first_row)) {
                            cur_d[x] = -1;
                            continue;
                        }
                        const int32_t pd = dy != 0 ? prev_d[px] : cur_d[px];
                        if (pd < 0 || (limit > 0 && pd + 1 > limit)) {
                            cur_d[x] = -1;
                            continue;
                        }
                        cur_d[x] = pd + 1, cur_v[x] = dy != 0 ? prev_v[px] : cur_v[px];
                        if (!accumulate) continue;
                        const std::size_t k = static_cast<std::size_t>(y) * w + x;
                        const double dist = cur_d[x] * step, wgt = 1.0 / (dist * dist);
                        num[k] += wgt * cur_v[x], den[k] += wgt;
                    }
                    prev_v.swap(cur_v), prev_d.swap(cur_d);
                }
            }
        }
    });
}
}  // namespace

int gap_fill_reach_cells(double cell_m) { return std::max(1, static_cast<int>(std::ceil(kGapFillReach_m / cell_m))); }

void fill_gaps(std::vector<double>& g, int w, int h, int max_ray_cells, const std::vector<uint8_t>* fill_only) {
    const std::size_t cells = static_cast<std::size_t>(w) * h;
    if (g.size() != cells) throw Error("fill_gaps", "internal: the grid's size differs from its width x height");
    if (fill_only && fill_only->size() != cells) throw Error("fill_gaps", "internal: the mask of cells to fill differs from the grid");
    std::unique_ptr<double[]> num, den;
    fill_gaps(g.data(), w, h, max_ray_cells, fill_only ? fill_only->data() : nullptr, [&] {
        num = std::make_unique_for_overwrite<double[]>(cells), den = std::make_unique_for_overwrite<double[]>(cells);
        return std::pair<double*, double*>{num.get(), den.get()};
    });
}

void fill_gaps(double* g, int w, int h, int max_ray_cells, const uint8_t* fill_only, const std::function<std::pair<double*, double*>()>& workspace) {
    const std::size_t cells = static_cast<std::size_t>(w) * h;
    bool any_gap = false, any_valid = false;
    double sum = 0.0;
    std::size_t n_valid = 0;
    for (std::size_t k = 0; k < cells; ++k) {
        const double v = g[k];
        if (std::isnan(v)) any_gap = true;
        else any_valid = true, sum += v, ++n_valid;
    }
    if (!any_gap || !any_valid) return;
    auto wanted = [&](std::size_t k) { return !fill_only || fill_only[k]; };
    const auto [num, den] = workspace();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells, 1u << 16), [&](const tbb::blocked_range<std::size_t>& r) {
        std::fill(num + r.begin(), num + r.end(), 0.0), std::fill(den + r.begin(), den + r.end(), 0.0);
    });
    sweep(g, w, h, max_ray_cells, num, den);
    if (max_ray_cells > 0) {
        // Cells with no valid cell within reach on any ray: the unlimited fill.
        bool far = false;
        for (std::size_t k = 0; k < cells && !far; ++k) far = std::isnan(g[k]) && !(den[k] > 0) && wanted(k);
        if (far) {
            std::vector<double> num_all(cells, 0.0), den_all(cells, 0.0);
            sweep(g, w, h, 0, num_all.data(), den_all.data());
            for (std::size_t k = 0; k < cells; ++k)
                if (std::isnan(g[k]) && !(den[k] > 0)) num[k] = num_all[k], den[k] = den_all[k];
        }
    }
    const double mean = sum / double(n_valid);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells, 1u << 16), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t k = r.begin(); k != r.end(); ++k)
            if (std::isnan(g[k]) && wanted(k)) g[k] = den[k] > 0 ? num[k] / den[k] : mean;  // enclosed on all 8 rays: the mean ground
    });
}

void fill_from_neighbours(std::vector<float>& v, int w, int h, int channels, int passes) {
    if (channels < 1 || channels > 4) throw Error("fill_from_neighbours", "internal: 1 to 4 values per cell");
    const std::size_t c = static_cast<std::size_t>(channels);
    for (int pass = 0; pass < passes; ++pass) {
        std::vector<float> next = v;
        bool changed = false;
        for (int r = 0; r < h; ++r)
            for (int q = 0; q < w; ++q) {
                const std::size_t u = static_cast<std::size_t>(r) * w + q;
                if (!std::isnan(v[c * u])) continue;
                double s[4] = {0, 0, 0, 0};
                int k = 0;
                for (int dr = -1; dr <= 1; ++dr)
                    for (int dq = -1; dq <= 1; ++dq) {
                        const int rr = r + dr, qq = q + dq;
                        if ((!dr && !dq) || rr < 0 || qq < 0 || rr >= h || qq >= w) continue;
                        const std::size_t t = static_cast<std::size_t>(rr) * w + qq;
                        if (std::isnan(v[c * t])) continue;
                        for (std::size_t b = 0; b < c; ++b) s[b] += v[c * t + b];
                        ++k;
                    }
                if (k < 3) continue;
                for (std::size_t b = 0; b < c; ++b) next[c * u + b] = static_cast<float>(s[b] / k);
                changed = true;
            }
        v.swap(next);
        if (!changed) break;
    }
}

}  // namespace cityforge
