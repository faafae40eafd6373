#pragma once
// Grey-level / binary morphology with a square window, separable (rows then
// columns): erosion = minimum, dilation = maximum over (2r+1) x (2r+1).
// Shared by the SMRF ground filter, building masks and rectangle fits.
#include <algorithm>
#include <cstddef>
#include <optional>
#include <vector>

namespace cityforge {

/// Erodes (`erode` = true) or dilates a row-major w x h grid with a square of
/// radius r. Cells outside the grid take `outside` when given; otherwise the
/// window is clipped to the grid (edge cells are not penalised).
template <typename T>
std::vector<T> morphology_square(const std::vector<T>& in, int w, int h, int r, bool erode, std::optional<T> outside = std::nullopt) {
    auto pick = [erode](T a, T b) { return erode ? std::min(a, b) : std::max(a, b); };
    std::vector<T> tmp(in.size()), out(in.size());
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            T v = in[static_cast<std::size_t>(y) * w + x];
            for (int d = -r; d <= r; ++d) {
                const int xx = x + d;
                if (xx < 0 || xx >= w) {
                    if (outside) v = pick(v, *outside);
                    continue;
                }
                v = pick(v, in[static_cast<std::size_t>(y) * w + xx]);
            }
            tmp[static_cast<std::size_t>(y) * w + x] = v;
        }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            T v = tmp[static_cast<std::size_t>(y) * w + x];
            for (int d = -r; d <= r; ++d) {
                const int yy = y + d;
                if (yy < 0 || yy >= h) {
                    if (outside) v = pick(v, *outside);
                    continue;
                }
                v = pick(v, tmp[static_cast<std::size_t>(yy) * w + x]);
            }
            out[static_cast<std::size_t>(y) * w + x] = v;
        }
    return out;
}

}  // namespace cityforge
