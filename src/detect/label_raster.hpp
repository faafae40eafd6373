#pragma once
// Training labels on the image grid: polygons (in pixel coordinates) burnt
// with the pixel-centre rule, and the spatially disjoint folds of a
// cross-validation. Pure algorithm; no GDAL.
#include <cstdint>
#include <vector>

#include "core/geometry.hpp"

namespace cityforge::detect {

/// 1 for every pixel of a w x h grid whose centre lies inside a polygon
/// (outside its holes); polygon coordinates are (x = column, y = row) with
/// (0, 0) the top-left corner of the grid.
std::vector<uint8_t> rasterize_polygons(const std::vector<Polygon>& polygons, int w, int h);

/// Spatial folds: each image is cut into square blocks of `block_px[i]`
/// pixels (one size per image: blocks of the same ground size); all blocks of all images are shuffled by `seed` and dealt to
/// `folds` folds in turn, so folds are balanced and never share a block.
struct FoldBlocks {
    std::vector<int> block_px;             ///< per image
    std::vector<int> blocks_x, blocks_y;   ///< per image
    std::vector<std::vector<int>> fold;    ///< per image, per block (row-major): fold index
    /// Fold of a pixel position of image `i` (clamped into the image).
    int fold_at(std::size_t image, double col, double row) const;
};
FoldBlocks make_folds(const std::vector<int>& widths, const std::vector<int>& heights, const std::vector<int>& block_px, int folds,
                      uint64_t seed);

}  // namespace cityforge::detect
