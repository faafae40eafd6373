#include "cloud/surface_support.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/error.hpp"
#include "core/parallel.hpp"

namespace cityforge {

void SurfaceSupportOptions::validate() const {
    if (!(radius > 0.0)) throw Error("surface support radius", "must be > 0");
    if (min_support < 1 || min_support > 64) throw Error("surface support", "must be between 1 and 64 neighbours");
    if (!(z_tolerance >= 0.0)) throw Error("surface support z tolerance", "must be >= 0");
    if (!(max_slope >= 0.0)) throw Error("surface support slope", "must be >= 0");
}

namespace {
bool is_noise(uint8_t c) { return c == las_class::low_noise || c == las_class::high_noise; }
}  // namespace

std::size_t restore_surface_points(const PointCloud& c, std::vector<uint8_t>& keep, const SurfaceSupportOptions& o) {
    o.validate();
    const std::size_t n = c.size();
    if (n == 0) return 0;
    if (keep.size() != n) throw Error("surface support", "keep flags differ in count from the points");
    if (n > std::numeric_limits<uint32_t>::max()) throw Error("surface support", "more than 4,294,967,295 points held at once");
    std::vector<uint32_t> candidates;
    for (std::size_t i = 0; i < n; ++i)
        if (!keep[i] && !is_noise(c.classification[i])) candidates.push_back(static_cast<uint32_t>(i));
    if (candidates.empty()) return 0;
    // A grid over the candidates (cells at least the radius wide, so a point's
    // neighbours lie in its 3 x 3 block), holding only the points of the cells
    // around a candidate.
    double minx = INFINITY, miny = INFINITY, maxx = -INFINITY, maxy = -INFINITY;
    for (const uint32_t i : candidates)
        minx = std::min(minx, c.x[i]), maxx = std::max(maxx, c.x[i]), miny = std::min(miny, c.y[i]), maxy = std::max(maxy, c.y[i]);
    const double extent = std::max(maxx - minx, maxy - miny);
    const double cell = std::max(o.radius, extent / 8000.0);  // at most ~64 M cells
    minx -= cell, miny -= cell;
    const auto nx = static_cast<std::size_t>((maxx + cell - minx) / cell) + 1, ny = static_cast<std::size_t>((maxy + cell - miny) / cell) + 1;
    auto cell_of = [&](double x, double y, std::size_t& k) {
        const double fx = (x - minx) / cell, fy = (y - miny) / cell;
        if (!(fx >= 0.0 && fy >= 0.0 && fx < double(nx) && fy < double(ny))) return false;
        k = static_cast<std::size_t>(fy) * nx + static_cast<std::size_t>(fx);
        return true;
    };
    std::vector<uint8_t> needed(nx * ny, 0);
    for (const uint32_t i : candidates) {
        const auto cx = static_cast<std::size_t>((c.x[i] - minx) / cell), cy = static_cast<std::size_t>((c.y[i] - miny) / cell);
        for (std::size_t y = cy - 1; y <= cy + 1; ++y)
            for (std::size_t x = cx - 1; x <= cx + 1; ++x) needed[y * nx + x] = 1;
    }
    std::vector<uint32_t> start(nx * ny + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
        std::size_t k;
        if (!is_noise(c.classification[i]) && cell_of(c.x[i], c.y[i], k) && needed[k]) ++start[k + 1];
    }
    for (std::size_t k = 0; k < nx * ny; ++k) start[k + 1] += start[k];
    std::vector<uint32_t> members(start.back());
    {
        std::vector<uint32_t> fill(start.begin(), start.end() - 1);
        for (std::size_t i = 0; i < n; ++i) {
            std::size_t k;
            if (!is_noise(c.classification[i]) && cell_of(c.x[i], c.y[i], k) && needed[k]) members[fill[k]++] = static_cast<uint32_t>(i);
        }
    }
    // Each candidate on its own: the flags of the others are not read.
    const double r2 = o.radius * o.radius;
    std::vector<uint8_t> restore(candidates.size(), 0);
    parallel_for_each_index(candidates.size(), [&](std::size_t ci) {
        const uint32_t i = candidates[ci];
        const double px = c.x[i], py = c.y[i], pz = c.z[i];
        const auto cx = static_cast<std::size_t>((px - minx) / cell), cy = static_cast<std::size_t>((py - miny) / cell);
        int support = 0;
        for (std::size_t y = cy - 1; y <= cy + 1 && support < o.min_support; ++y)
            for (std::size_t x = cx - 1; x <= cx + 1 && support < o.min_support; ++x) {
                const std::size_t k = y * nx + x;
                for (uint32_t m = start[k]; m < start[k + 1]; ++m) {
                    const uint32_t j = members[m];
                    if (j == i) continue;
                    const double dx = c.x[j] - px, dy = c.y[j] - py, dz = c.z[j] - pz;
                    const double h2 = dx * dx + dy * dy;
                    if (h2 + dz * dz > r2) continue;
                    if (std::abs(dz) > o.z_tolerance + o.max_slope * std::sqrt(h2)) continue;
                    if (++support >= o.min_support) break;
                }
            }
        restore[ci] = support >= o.min_support;
    });
    std::size_t restored = 0;
    for (std::size_t ci = 0; ci < candidates.size(); ++ci)
        if (restore[ci]) keep[candidates[ci]] = 1, ++restored;
    return restored;
}

}  // namespace cityforge
