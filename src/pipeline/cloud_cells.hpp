#pragma once
// Cloud rasters and building cells on a window of a grid (e.g. the ortho's),
// computed on coarser cells when the cloud is too sparse for the grid's
// pixels (2 pts/m² LiDAR under a 0.25 m ortho leaves most pixels empty).
// Coarse cells are anchored at multiples of the factor in global pixel
// indices, so every window of a grid uses the same cells.
#include "cloud/cloud_rasters.hpp"
#include "footprint/building_mask.hpp"
#include "pipeline/prepared_cloud.hpp"

namespace cityforge {

/// The smallest integer factor f >= 1 such that cells of f x f pixels of
/// `gsd_m` metres hold about `min_points_per_cell` points on average at
/// `points_per_m2` (5 % slack; 1 when the density is unknown, i.e. <= 0).
/// Cells with fewer points are decided from their neighbours.
int cloud_cell_factor(double points_per_m2, double gsd_m, double min_points_per_cell = 1.0);

/// Rasters on the window's own pixels (coarse values repeated over their
/// pixels) and building cells decided on the coarse cells, then repeated.
struct WindowCloudCells {
    CloudRasters rasters;
    BuildingCells cells;
};

/// `window` = the window's grid (its own origin, pixel size and size); it
/// starts at global pixel (col0, row0) of the full grid. `options.gsd_m` is
/// the window's pixel size in metres; `options.min_height_m` is in the
/// cloud's vertical units. `unit_m` = metres per horizontal CRS unit.
WindowCloudCells cloud_cells_on_window(const PreparedCloud& pc, const GridSpec& window, int col0, int row0, int factor, double unit_m,
                                       const BuildingMaskOptions& options);

/// The grid of the coarse cells cloud_cells_on_window rasterises on (the
/// window itself when factor == 1).
GridSpec cloud_cell_grid(const GridSpec& window, int col0, int row0, int factor);

/// The same from rasters already made on cloud_cell_grid(window, col0, row0,
/// factor) (e.g. window by window, rasterize_cloud_by_windows); `w` x `h` =
/// the window's size in pixels.
WindowCloudCells cloud_cells_from_rasters(CloudRasters coarse, int w, int h, int col0, int row0, int factor,
                                          const BuildingMaskOptions& options);

}  // namespace cityforge
