#include "segment/boundary_refine.hpp"

#include <cmath>
#include <vector>

#include "core/error.hpp"

namespace cityforge {

void refine_segment_boundaries(const Image<float>& image, int bands, Image<uint32_t>& labels, uint32_t count, int passes) {
    const int w = labels.width, h = labels.height;
    const std::size_t n = labels.pixel_count();
    if (image.pixel_count() != n) throw Error("boundary refinement", "image and labels differ in size");
    if (bands < 1 || bands > image.bands) throw Error("boundary refinement", "band count out of range");
    const auto nb = static_cast<std::size_t>(bands);
    std::vector<double> mean((count + 1) * nb, 0.0);
    std::vector<double> size(count + 1, 0.0);
    for (std::size_t k = 0; k < n; ++k) {
        const uint32_t l = labels.data[k];
        if (l > count) throw Error("boundary refinement", "label larger than the segment count");
        size[l] += 1.0;
        for (int b = 0; b < bands; ++b) mean[l * nb + b] += image.band_data(b)[k];
    }
    for (uint32_t l = 1; l <= count; ++l)
        if (size[l] > 0)
            for (std::size_t b = 0; b < nb; ++b) mean[l * nb + b] /= size[l];
    auto distance = [&](std::size_t k, uint32_t l) {
        double d = 0.0;
        for (int b = 0; b < bands; ++b) {
            const double e = image.band_data(b)[k] - mean[l * nb + static_cast<std::size_t>(b)];
            d += e * e;
        }
        return d;
    };
    for (int pass = 0; pass < passes; ++pass) {
        LargeVector<uint32_t> next = labels.data;
        bool changed = false;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                const uint32_t own = labels.data[k];
                if (!own) continue;
                uint32_t cand[4];
                int c = 0;
                if (x > 0) cand[c++] = labels.data[k - 1];
                if (x + 1 < w) cand[c++] = labels.data[k + 1];
                if (y > 0) cand[c++] = labels.data[k - static_cast<std::size_t>(w)];
                if (y + 1 < h) cand[c++] = labels.data[k + static_cast<std::size_t>(w)];
                uint32_t best = own;
                double best_d = -1.0;
                for (int i = 0; i < c; ++i) {
                    const uint32_t l = cand[i];
                    if (!l || l == own) continue;
                    if (best_d < 0) best_d = distance(k, own);
                    const double d = distance(k, l);
                    if (d < best_d || (d == best_d && best != own && l < best)) best = l, best_d = d;
                }
                if (best != own) next[k] = best, changed = true;
            }
        labels.data.swap(next);
        if (!changed) break;
    }
}

}  // namespace cityforge
