#pragma once
// Filling gaps (NaN cells) of a regular grid, e.g. a DTM under buildings.
// Pyramid fill: each coarser level averages the valid cells below it; gaps
// take the value of the finest level that has one, then a few relaxation
// passes smooth the filled cells. O(cells), no GDAL.
#include <cstddef>
#include <vector>

namespace cityforge {

/// Fills every NaN cell of the row-major `w` x `h` grid from its surroundings.
/// Leaves the grid unchanged when it has no valid cell at all.
void fill_gaps(std::vector<double>& grid, int w, int h);

}  // namespace cityforge
