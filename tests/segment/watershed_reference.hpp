#pragma once
// The watershed as specified, written out plainly (no parallelism, no
// cleverness): the oracle the library's watershed must equal to the pixel.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <numeric>
#include <vector>

#include "segment/watershed.hpp"

namespace cityforge::test {

// The flooding with dynamics as specified, plainly: gradient levels (1/4
// grey level), valid pixels in (level, index) order; a pixel's flooded
// neighbours (up, left, right, down) give their basins (union-find roots,
// each through its first neighbour): none, a new basin with its minimum at
// this level; one, that basin; several, the basin of the neighbour closest
// in colour (the first on ties), after the basins shallower than h below
// this level are absorbed into the deepest (lowest minimum, then lowest
// root index), the closest one's absorber if it was absorbed. Labels in
// raster order of first appearance.
inline Oversegmentation reference_dynamics(const Image<float>& img, const std::vector<uint8_t>& valid, const WatershedOptions& wo) {
    const Image<float> g = multiband_gradient(img, wo);
    const int w = img.width, h = img.height;
    const std::size_t n = img.pixel_count();
    const auto h_levels = static_cast<uint32_t>(std::lround(wo.h_minima * 4.0));
    std::vector<std::pair<uint16_t, uint32_t>> order;
    for (std::size_t i = 0; i < n; ++i)
        if (valid.empty() || valid[i])
            order.push_back({static_cast<uint16_t>(std::min(65535.0f, g.data[i] * 4.0f)), static_cast<uint32_t>(i)});
    std::sort(order.begin(), order.end());
    constexpr uint32_t none = 0xFFFFFFFFu;
    std::vector<uint32_t> parent(n, none), minimum(n, 0);
    auto find = [&](uint32_t x) {
        while (parent[x] != x) x = parent[x];
        return x;
    };
    for (const auto& [lv, p] : order) {
        const int x = static_cast<int>(p % w), y = static_cast<int>(p / w);
        std::vector<uint32_t> roots, via;
        auto visit = [&](int qx, int qy) {
            if (qx < 0 || qy < 0 || qx >= w || qy >= h) return;
            const uint32_t q = static_cast<uint32_t>(qy * w + qx);
            if (parent[q] == none) return;
            const uint32_t r = find(q);
            if (std::find(roots.begin(), roots.end(), r) != roots.end()) return;
            roots.push_back(r), via.push_back(q);
        };
        visit(x, y - 1), visit(x - 1, y), visit(x + 1, y), visit(x, y + 1);
        if (roots.empty()) {
            parent[p] = p, minimum[p] = lv;
            continue;
        }
        uint32_t closest_root = roots[0];
        float closest = INFINITY;
        for (std::size_t k = 0; k < roots.size(); ++k) {
            float d = 0.0f;
            for (int b = 0; b < img.bands; ++b) {
                const float diff = img.band_data(b)[p] - img.band_data(b)[via[k]];
                d += diff * diff;
            }
            if (d < closest) closest = d, closest_root = roots[k];
        }
        const uint32_t deepest = *std::min_element(roots.begin(), roots.end(), [&](uint32_t a, uint32_t b) {
            return minimum[a] != minimum[b] ? minimum[a] < minimum[b] : a < b;
        });
        for (uint32_t r : roots)
            if (r != deepest && static_cast<uint32_t>(lv - minimum[r]) < h_levels) parent[r] = deepest;
        parent[p] = find(closest_root);
    }
    Oversegmentation out;
    out.labels = Image<uint32_t>(w, h, 1, 0u);
    std::map<uint32_t, uint32_t> label;
    for (std::size_t i = 0; i < n; ++i)
        if (parent[i] != none) out.labels.data[i] = label.emplace(find(static_cast<uint32_t>(i)), static_cast<uint32_t>(label.size() + 1)).first->second;
    out.region_count = static_cast<uint32_t>(label.size());
    return out;
}

// Band normalisation as specified: per band, over a regular sample (every
// max(1, n / 1e6)-th pixel, valid ones only), the 0.5th and then the 99.5th
// percentile by std::nth_element on that sample in order (with NaN the
// library's nth_element order decides, so the sample is the same one), and
// each value stretched (v - lo) * 255 / (hi - lo), clamped to 0..255.
inline Image<float> reference_normalisation(Image<float> img, const std::vector<uint8_t>& valid) {
    const std::size_t n = img.pixel_count(), step = std::max<std::size_t>(1, n / 1000000);
    for (int b = 0; b < img.bands; ++b) {
        float* v = img.band_data(b);
        std::vector<float> sample;
        for (std::size_t i = 0; i < n; i += step)
            if (valid.empty() || valid[i]) sample.push_back(v[i]);
        auto pct = [&](double q) {
            const auto k = static_cast<std::size_t>(q * static_cast<double>(sample.size() - 1));
            std::nth_element(sample.begin(), sample.begin() + static_cast<std::ptrdiff_t>(k), sample.end());
            return sample[k];
        };
        const float lo = pct(0.005), hi = pct(0.995);
        const float scale = hi > lo ? 255.0f / (hi - lo) : 0.0f;
        for (std::size_t i = 0; i < n; ++i) v[i] = std::clamp((v[i] - lo) * scale, 0.0f, 255.0f);
    }
    return img;
}

}  // namespace cityforge::test

