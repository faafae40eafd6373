#pragma once
// Filling gaps (NaN cells) of a regular grid, e.g. a DTM under buildings.
// Directional inverse-distance fill: each gap takes the 1/d² weighted mean of
// the nearest valid cell in each of the 8 compass directions; local (a cell
// depends only on its gap), so windows of a grid fill alike. O(cells), no GDAL.
#include <cstddef>
#include <vector>

namespace cityforge {

/// Fills every NaN cell of the row-major `w` x `h` grid from its surroundings.
/// Leaves the grid unchanged when it has no valid cell at all.
void fill_gaps(std::vector<double>& grid, int w, int h);

}  // namespace cityforge
