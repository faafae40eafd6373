#pragma once
// The one size check of every grid laid over data (the ground filter's SMRF
// grid, a cloud's rasters, the heights point index): a grid must be finite and
// in proportion to the points it holds. A few garbage coordinates far from the
// data (a corrupt record, 1e308, a wrong CRS) would otherwise ask for a grid of
// 10^9 cells or more and end in "out of memory" after minutes.
#include <cstddef>
#include <string>

namespace cityforge {

/// Width and height (cells) of a grid of `cell`-sized square cells.
struct GridSize {
    int width = 0;
    int height = 0;
    std::size_t cells() const { return static_cast<std::size_t>(width) * static_cast<std::size_t>(height); }
};

/// At most this many cells per point the grid holds, beyond a floor of
/// kGridFreeCells. The floor is set by memory, not by density: 64 M cells
/// (8,000 x 8,000, 4 km at 0.5 m; a few hundred MB per raster layer) are
/// always allowed, so sparse but real clouds (1,065 points over 1 x 1.4 km
/// rasterised at 0.5 m) pass, while garbage coordinates thousands of
/// kilometres away (10^14 cells) are still refused before any allocation.
inline constexpr double kGridCellsPerPoint = 256.0;
inline constexpr double kGridFreeCells = 64.0e6;

/// The cells covering [min_x, max_x] x [min_y, max_y] (CRS units) with cells
/// of `cell` units: floor(extent / cell) + 1 a side. Throws Error(subject, ...)
/// with the extent, the cell count and the likely cause when the extent is
/// not finite, or the grid would have more than `max_cells` cells or more than
/// kGridFreeCells + kGridCellsPerPoint x `points` cells (`points` = 0: not
/// known, only `max_cells` applies).
/// Throws Error(subject, ...) naming the extent unless max - min is finite and
/// >= 0 on both axes (the first check of checked_grid_size).
void require_finite_extent(double min_x, double min_y, double max_x, double max_y, const std::string& subject);

GridSize checked_grid_size(double min_x, double min_y, double max_x, double max_y, double cell, std::size_t points,
                           const std::string& subject, double max_cells = 2.0e9);

}  // namespace cityforge
