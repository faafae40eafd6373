#pragma once
// Filling gaps (NaN cells) of a regular grid, e.g. a DTM under buildings.
// Directional inverse-distance fill: each gap takes the 1/d² weighted mean of
// the nearest valid cell in each of the 8 compass directions; local (a cell
// depends only on its gap), so windows of a grid fill alike. O(cells), no GDAL.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

namespace cityforge {

/// How far (metres) the terrain fills of the cloud stages reach (the DTM under
/// buildings, SMRF's minimum surface): a filled cell depends on the ground
/// within this distance only, unless no ground lies that close in any of the 8
/// directions. Tiled runs add it to the context every window keeps around a
/// building, so a building's result does not depend on where tiles end.
inline constexpr double kGapFillReach_m = 40.0;

/// Fills every NaN cell of the row-major `w` x `h` grid from its surroundings.
/// Leaves the grid unchanged when it has no valid cell at all.
/// `max_ray_cells` > 0: each ray stops after that many cells; a cell whose 8
/// rays all stop without meeting a valid cell is filled as with no limit (the
/// nearest valid cells at any distance, else the mean of the grid).
/// `fill_only` (one byte per cell, when given): only cells marked nonzero are
/// filled, the others stay NaN (and need no unlimited fill); the filled
/// cells get the values they get without it.
void fill_gaps(std::vector<double>& grid, int w, int h, int max_ray_cells = 0, const std::vector<uint8_t>* fill_only = nullptr);

/// The same on a caller-owned row-major array of `w` x `h` values (and mask
/// of as many bytes, or null). `workspace()` is called only when the grid has
/// gaps to fill and returns two arrays of w * h doubles (contents stale:
/// they are overwritten), distinct from `grid`: for a caller that reuses its
/// buffers (no fresh memory per fill).
void fill_gaps(double* grid, int w, int h, int max_ray_cells, const uint8_t* fill_only, const std::function<std::pair<double*, double*>()>& workspace);

/// Grows values into NaN cells of the row-major `w` x `h` grid of
/// `channels` interleaved values per cell (a cell is empty when its first
/// value is NaN): each pass, an empty cell with at least 3 filled cells among
/// its 8 neighbours takes their mean, from the state before the pass (so the
/// result does not depend on the order of the cells); at most `passes`
/// passes, each growing the filled area by one cell; stops early when a pass
/// fills nothing. Small gaps close, large empty areas stay empty.
void fill_from_neighbours(std::vector<float>& grid, int w, int h, int channels, int passes);

/// kGapFillReach_m in cells of `cell_m` metres (at least 1).
int gap_fill_reach_cells(double cell_m);

}  // namespace cityforge
