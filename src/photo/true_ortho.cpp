#include "photo/true_ortho.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "core/error.hpp"
#include "core/grid_fill.hpp"

namespace cityforge::photo {

void TrueOrthoOptions::validate() const {
    if (!(top_band_m >= 0 && top_band_m <= 10)) throw Error("--ortho-top-band", "must be 0..10 m");
    if (fill_passes < 0 || fill_passes > 50) throw Error("--ortho-fill", "must be 0..50 passes");
}

Image<uint8_t> true_ortho_from_cloud(const PointCloud& c, const GridSpec& g, const TrueOrthoOptions& o, const std::string& subject) {
    o.validate();
    if (!c.has_color()) throw Error(subject, "the cloud has no RGB colours: cannot make a true ortho");
    if (g.width <= 0 || g.height <= 0) throw Error(subject, "the ortho grid has no cells");
    const std::size_t n = static_cast<std::size_t>(g.width) * g.height;
    auto cell_of = [&](std::size_t i) -> long {
        const PixelPoint p = g.transform.map_to_pixel({c.x[i], c.y[i]});
        const long col = static_cast<long>(std::floor(p.col)), row = static_cast<long>(std::floor(p.row));
        if (col < 0 || row < 0 || col >= g.width || row >= g.height) return -1;
        return row * g.width + col;
    };
    // Pass 1: the top of each cell. Pass 2: mean colour of its top band.
    std::vector<double> top(n, -std::numeric_limits<double>::infinity());
    std::size_t on_grid = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
        const long k = cell_of(i);
        if (k < 0) continue;
        ++on_grid;
        top[static_cast<std::size_t>(k)] = std::max(top[static_cast<std::size_t>(k)], c.z[i]);
    }
    if (on_grid == 0) throw Error(subject, "no point of the cloud falls on the ortho grid");
    std::vector<double> sum(3 * n, 0.0);
    std::vector<uint32_t> cnt(n, 0);
    for (std::size_t i = 0; i < c.size(); ++i) {
        const long k = cell_of(i);
        if (k < 0 || c.z[i] < top[static_cast<std::size_t>(k)] - o.top_band_m) continue;
        const std::size_t u = static_cast<std::size_t>(k);
        sum[3 * u] += c.red[i] / 257.0, sum[3 * u + 1] += c.green[i] / 257.0, sum[3 * u + 2] += c.blue[i] / 257.0;
        ++cnt[u];
    }
    std::vector<float> rgb(3 * n, std::numeric_limits<float>::quiet_NaN());
    for (std::size_t u = 0; u < n; ++u)
        if (cnt[u])
            for (int b = 0; b < 3; ++b) rgb[3 * u + b] = static_cast<float>(sum[3 * u + b] / cnt[u]);
    // Small gaps between patches filled from their neighbours.
    fill_from_neighbours(rgb, g.width, g.height, 3, o.fill_passes);
    Image<uint8_t> out(g.width, g.height, 3, 0);
    for (int r = 0; r < g.height; ++r)
        for (int q = 0; q < g.width; ++q) {
            const std::size_t u = static_cast<std::size_t>(r) * g.width + q;
            if (std::isnan(rgb[3 * u])) continue;
            for (int b = 0; b < 3; ++b)
                out.at(b, q, r) = static_cast<uint8_t>(std::clamp(std::lround(rgb[3 * u + b]), 1L, 255L));
        }
    return out;
}

}  // namespace cityforge::photo
