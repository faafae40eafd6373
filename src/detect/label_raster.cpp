#include "detect/label_raster.hpp"

#include <algorithm>
#include <cmath>

#include "core/error.hpp"
#include "core/random.hpp"

namespace cityforge::detect {

std::vector<uint8_t> rasterize_polygons(const std::vector<Polygon>& polygons, int w, int h) {
    std::vector<uint8_t> mask(std::size_t(w) * h, 0);
    std::vector<double> xs;
    for (const Polygon& p : polygons) {
        const Extent e = polygon_extent(p);
        const int r0 = std::max(0, int(std::floor(e.min_y - 0.5))), r1 = std::min(h - 1, int(std::ceil(e.max_y + 0.5)));
        std::vector<const Ring*> rings{&p.outer};
        for (const Ring& hole : p.holes) rings.push_back(&hole);
        for (int r = r0; r <= r1; ++r) {
            const double y = r + 0.5;
            xs.clear();
            for (const Ring* ring : rings) {
                const std::size_t n = ring->size();
                for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
                    const MapPoint& a = (*ring)[i];
                    const MapPoint& b = (*ring)[j];
                    if ((a.y > y) != (b.y > y)) xs.push_back(a.x + (y - a.y) * (b.x - a.x) / (b.y - a.y));
                }
            }
            std::sort(xs.begin(), xs.end());
            for (std::size_t k = 0; k + 1 < xs.size(); k += 2) {
                // Pixels whose centre c + 0.5 lies in [xs[k], xs[k+1]).
                const int c0 = std::max(0, int(std::ceil(xs[k] - 0.5))), c1 = std::min(w - 1, int(std::ceil(xs[k + 1] - 0.5)) - 1);
                for (int c = c0; c <= c1; ++c) mask[std::size_t(r) * w + c] = 1;
            }
        }
    }
    return mask;
}

int FoldBlocks::fold_at(std::size_t image, double col, double row) const {
    const int bx = std::clamp(int(std::floor(col / block_px[image])), 0, blocks_x[image] - 1);
    const int by = std::clamp(int(std::floor(row / block_px[image])), 0, blocks_y[image] - 1);
    return fold[image][std::size_t(by) * blocks_x[image] + bx];
}

FoldBlocks make_folds(const std::vector<int>& widths, const std::vector<int>& heights, const std::vector<int>& block_px, int folds,
                      uint64_t seed) {
    for (const int b : block_px)
        if (b < 1) throw Error("--fold-block-m", "blocks must be at least one pixel");
    if (folds < 2) throw Error("--folds", "cross-validation needs at least 2 folds");
    FoldBlocks f;
    f.block_px = block_px;
    struct Key {
        uint64_t hash;
        std::size_t image;
        std::size_t block;
    };
    std::vector<Key> keys;
    for (std::size_t i = 0; i < widths.size(); ++i) {
        f.blocks_x.push_back(std::max(1, (widths[i] + block_px[i] - 1) / block_px[i]));
        f.blocks_y.push_back(std::max(1, (heights[i] + block_px[i] - 1) / block_px[i]));
        f.fold.emplace_back(std::size_t(f.blocks_x[i]) * f.blocks_y[i], 0);
        for (std::size_t b = 0; b < f.fold[i].size(); ++b) keys.push_back({hash64(seed, i, b, 0xf01d), i, b});
    }
    if (keys.size() < std::size_t(folds))
        throw Error("--folds", std::to_string(folds) + " folds need at least as many blocks; the images give " + std::to_string(keys.size()) +
                                   " (use smaller --fold-block-m)");
    std::sort(keys.begin(), keys.end(), [](const Key& a, const Key& b) {
        return a.hash != b.hash ? a.hash < b.hash : (a.image != b.image ? a.image < b.image : a.block < b.block);
    });
    for (std::size_t k = 0; k < keys.size(); ++k) f.fold[keys[k].image][keys[k].block] = int(k % std::size_t(folds));
    return f;
}

}  // namespace cityforge::detect
