#pragma once
// Cloud-only building detection on rasters: nDSM above a height threshold,
// not vegetation (point classes when the cloud has them, DSM roughness when
// it does not), cleaned by morphology, small parts dropped and small holes
// filled. Pure raster algorithm on a north-up grid (no GDAL).
#include <cstdint>
#include <string>
#include <vector>

#include "core/image.hpp"

namespace cityforge {

struct BuildingMaskOptions {
    double gsd_m = 0.5;                 ///< cell size of the rasters, metres
    double min_height_m = 2.5;          ///< nDSM threshold, metres above ground
    double min_building_share = 0.5;    ///< with classes: share of class-6 points among the cell's non-vegetation points
    int fill_passes = 6;                ///< passes deciding cells without evidence (gaps, crown-only) from their neighbours
    /// With classes: crown-only cells taken from their neighbours stay
    /// building only within this many cells of the minimum-area rectangle
    /// of the measured roof cells they joined (a crown over a roof's edge or
    /// corner completes its rectangle; one beside a wall does not); < 0 = off.
    int crown_fill_rectangle_cells = 1;
    double max_roughness_m = 0.35;      ///< without classes: local DSM plane residual (3x3) above this -> vegetation
    double min_area_m2 = 20.0;          ///< smaller components are dropped
    double min_hole_m2 = 6.0;           ///< smaller holes (data gaps) are filled; larger ones (courtyards) kept
    /// Buildings whose roofs are separated by a height step larger than this
    /// (metres, between neighbouring cells of the DSM) are split along the
    /// step (terraced houses of different heights); 0 = never split.
    double split_step_m = 1.5;
    /// Parts smaller than this, or not touching the building's outline
    /// (dormers, chimneys, roof superstructures), stay with their neighbour.
    double min_split_part_m2 = 15.0;
    /// Parts that meet across cells without heights stay one roof unless the
    /// heights each carries into the gap differ by more than this on average
    /// (metres; a roof beside a tree crown across a gap of a photogrammetric
    /// cloud) and both have heights over a quarter of min_split_part_m2;
    /// 0 = such parts always stay one roof.
    double split_gap_step_m = 3.0;
    /// Unmeasured cells (dark roofs, crowns over roofs) completed inside a
    /// building's rectangle when that grows it by at most this share of its
    /// area (complete_hidden_roofs); 0 = never.
    double hidden_completion_max_share = 0.25;
    int opening_radius_px = 0;          ///< morphological opening removing thin artefacts (0 = none; 1 shrinks outlines ~2 %)
    /// Position of the rasters' first cell in the run's global grid (in cells
    /// of these rasters): position-dependent choices (the checkerboard of
    /// exact share ties) follow global cells, so a tile's window decides its
    /// cells as the whole grid would.
    int grid_col0 = 0, grid_row0 = 0;
    /// Sides of the rasters (bits: 1 left, 2 top, 4 right, 8 bottom) where
    /// components touching them are kept whatever their area: in a window of
    /// a larger grid they are pieces of buildings that continue beyond it (a
    /// tiled run does them again on a grown window). 0 = none.
    int keep_border_sides = 0;
    /// Whether point classes (building 6, vegetation 3-5) decide building
    /// cells: -1 = when classes are present in > 10 % of these rasters' cells
    /// (point_classes_present); 0 / 1 = fixed (a tiled run decides once for
    /// all its windows).
    int use_classes = -1;
    void validate() const;
};

struct BuildingMask {
    Image<uint32_t> labels;  ///< 1..count per building component (4-connected), 0 = not building
    uint32_t count = 0;
    bool used_classes = false;  ///< true when point classes decided vegetation vs building
};

/// 4-connected components of the cells equal to `value` (labels 1..count in
/// raster order of first appearance; other cells 0). `sizes[l]` = cells of l.
uint32_t label_components(const std::vector<uint8_t>& mask, uint8_t value, int w, int h, std::vector<uint32_t>& labels,
                          std::vector<uint32_t>& sizes);

/// Building components of a binary mask (w x h, 1 = building): holes under
/// min_hole_m2 filled, optional opening, components under min_area_m2 dropped.
BuildingMask label_buildings(std::vector<uint8_t> mask, int w, int h, const BuildingMaskOptions& options);

/// Buildings (4-connected components, label_buildings with `options`) of
/// the object pixels `cut` (w x h, 1 = building) that the object rules
/// (pair groups, split level, neck and core splits) made from the building
/// pixels `whole` by taking one-pixel cuts out of them. Holes under
/// options.min_hole_m2 are filled in `whole`, not in `cut`: a cut along a
/// diagonal or ragged boundary touches the background only at corners, and
/// filled as small holes its pixels would join the buildings again.
BuildingMask label_cut_buildings(const std::vector<uint8_t>& whole, std::vector<uint8_t> cut, int w, int h, BuildingMaskOptions options);

/// Per-cell building decisions from the cloud rasters, before components are
/// formed: `cells` 1 = building; `step_dsm` = the DSM where a cell has its own
/// evidence (NaN where it was decided from its neighbours), for step splits.
struct BuildingCells {
    std::vector<uint8_t> cells;
    std::vector<uint8_t> evidence;  ///< 1 where the cell was decided by its own points (not from neighbours)
    Image<float> step_dsm;
    bool used_classes = false;
    /// Points per cell of the classified cloud (capped at 255; empty when
    /// unknown): roof = building class, ground = neither building nor
    /// vegetation. An edge decision weighs them against the roof's and the
    /// ground's return rates (refine_buildings_with_ortho).
    std::vector<uint8_t> roof_points, ground_points;
};
/// True when more than 10 % of the cells with points have building or
/// vegetation points (NaN shares = no point).
bool point_classes_present(const Image<float>& building_share, const Image<float>& vegetation_share);

/// `ndsm`, `dsm`, `building_share`, `vegetation_share` on the same grid (NaN =
/// no data); shares may be all-NaN for unclassified clouds.
BuildingCells building_cells(const Image<float>& ndsm, const Image<float>& dsm, const Image<float>& building_share,
                             const Image<float>& vegetation_share, const BuildingMaskOptions& options);

/// Buildings from decided cells: components (label_buildings), then split at
/// height steps of `cells.step_dsm` (split_at_height_steps); w x h = the grid.
BuildingMask buildings_from_cells(const BuildingCells& cells, int w, int h, const BuildingMaskOptions& options);

/// Roofs the data hides, completed. An outline stops where nothing is
/// measured: a dark roof returns a fifth of the pulses or none, a tree crown
/// covers a roof's edge or corner (the image sees the crown, few pulses reach
/// the roof), and the image's segments there take the colour of what hides
/// the roof. For each building, the cells inside its minimum-area rectangle
/// (of its cells' corners) that no building
/// holds and that are not measured as something else (no own evidence, or
/// own evidence of a roof) join it when they connect to it through such
/// cells -- unless they would grow it by more than `max_growth_share` of its
/// area (then the rectangle is no model of it). A claim that meets another
/// building's is dropped. Each building's result depends only on the cells
/// within its rectangle, not on label order. Returns the cells added.
std::size_t complete_hidden_roofs(BuildingMask& mask, const BuildingCells& cells, double max_growth_share = 0.25);

/// Each building reduced to its largest 4-connected part (ties: the part
/// met first in raster order); its other parts -- stray pixels a redrawing
/// left cut off from it -- become non-building. A building is written as one
/// polygon, so a second part would be lost or, met first, replace it.
/// Returns the pixels removed.
std::size_t keep_largest_parts(BuildingMask& mask);

/// Splits every building of `mask` into parts whose roofs are separated by
/// height steps of the DSM (see BuildingMaskOptions::split_step_m); parts are
/// relabelled 1..count in raster order of first appearance. `dsm` on the same
/// grid, NaN = no data (such cells join the neighbouring part).
void split_at_height_steps(BuildingMask& mask, const Image<float>& dsm, const BuildingMaskOptions& options);

}  // namespace cityforge
