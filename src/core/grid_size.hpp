#pragma once
// The one size check of every grid laid over data (the ground filter's SMRF
// grid, a cloud's rasters, the heights point index): a grid must be finite,
// within the absolute caps, and fit in memory. A few garbage coordinates far
// from the data (a corrupt record, 1e308, a wrong CRS) would otherwise ask for
// a grid of 10^9 cells or more and end in a bare "out of memory" after minutes.
#include <cstddef>
#include <string>

namespace cityforge {

/// Width and height (cells) of a grid of `cell`-sized square cells.
struct GridSize {
    int width = 0;
    int height = 0;
    std::size_t cells() const { return static_cast<std::size_t>(width) * static_cast<std::size_t>(height); }
};

/// Share of usable_memory_bytes() (core/memory.hpp) one grid may take with all
/// its layers: the rest is for the points, the other stages and the machine.
/// Sparse but real clouds pass (two 120 m sites 12 km apart: 1.5e8 cells of
/// 1 m for the ground filter), while a grid the machine cannot hold is refused
/// before any allocation, naming the input.
inline constexpr double kGridMemoryShare = 0.5;

/// Throws Error(subject, ...) naming the extent unless max - min is finite and
/// >= 0 on both axes (the first check of checked_grid_size).
void require_finite_extent(double min_x, double min_y, double max_x, double max_y, const std::string& subject);

/// The cells covering [min_x, max_x] x [min_y, max_y] (CRS units) with cells
/// of `cell` units: floor(extent / cell) + 1 a side. Checked before anything
/// is allocated:
/// - the extent is finite (Error, "... is not finite");
/// - at most 2e9 cells a side and `max_cells` cells (Error, "grid too large");
/// - cells x `bytes_per_cell` (bytes, every layer the caller allocates over the
///   grid counted; 0 = not known, no memory check) is at most
///   kGridMemoryShare x usable_memory_bytes() (OutOfMemory, exit 3).
/// Every error names `subject` (the input file, or the stage, which callers
/// that know the file re-throw under it), the extent, the cell count and the
/// likely cause.
GridSize checked_grid_size(double min_x, double min_y, double max_x, double max_y, double cell, double bytes_per_cell,
                           const std::string& subject, double max_cells = 2.0e9);

}  // namespace cityforge
