#pragma once
// The ortho + heights detection mode, building by building: each building
// found in the heights (cloud cells) is redrawn along the ortho's edges by
// segmenting a crop around it. Each result depends only on the ortho and the
// cells inside that building's own crop, so any tiling of a grid gives the
// same buildings (used by `footprints` and by every tile of `run`).
#include <cstdint>
#include <vector>

#include "core/image.hpp"
#include "footprint/building_mask.hpp"
#include "segment/watershed.hpp"

namespace cityforge {

struct OrthoRefineOptions {
    WatershedOptions watershed;           ///< over-segmentation of each crop (band weights: colours; the nDSM band is added)
    double segment_scale = 30.0;          ///< merging scale of each crop (cost < scale^2)
    int refine_passes = 2;                ///< boundary pixels moved to the closest-colour segment
    double ndsm_band_weight = 2.0;        ///< weight of the nDSM band (0..20 m -> 0..255)
    double min_segment_building_share = 0.5;  ///< share of a segment's cells (measured or inferred) that must be building, when some are measured
    /// With a classified cloud rasterised on the ortho's own pixels, outline
    /// pixels keep the cloud's decision; off when the cloud cells are coarser.
    bool cloud_edges = true;
    /// Prior odds that the ortho's edge is right where the cloud's evidence
    /// at an outline pixel is only ground points, weighed by the roof's and
    /// the ground's return rates (sparse, dark roofs); 0 = the cloud decides.
    double ortho_edge_odds = 2.0;
    /// With a classified cloud on the ortho's pixels: pixels the ortho's
    /// segments took but the cloud measured as not building are peeled off
    /// from the outline inward, up to this many pixel rings (0 = the
    /// outline only, as cloud_edges).
    int cloud_peel_rings = 50;
    int margin_px = 20;                   ///< crop = the building's bounding box grown by this many pixels
    /// A redrawn building whose IoU with its heights' outline is below this
    /// keeps the heights' outline (the image merged or lost the roof).
    double min_iou_with_heights = 0.7;
    /// A segment mostly of vegetation colours, weak ones included (levels 1
    /// and 2 of vegetation_pixels), is a crown when its nDSM scatters about
    /// its roof by more than this (metres; the least of one robust plane and
    /// two split along either principal axis, as for a gable's ridge; sigma =
    /// 1.4826 x the median absolute residual after refits on the inliers, so
    /// wall or ground pixels along its edge do not count): roof facets are planar,
    /// crowns are not (photo clouds have no point classes and smooth crowns
    /// too much for the cells' 3 x 3 roughness). 0 = off.
    double max_crown_plane_sigma_m = 0.3;
    /// ... and when its heights are also rough locally: the median over its
    /// samples of the RMS residual about the plane of the samples within
    /// crown_local_radius_m (metres; LiDAR crowns are rough, a hip roof's
    /// facets are planar, so only its hips and ridge are rough).
    double min_crown_local_roughness_m = 0.12;
    double crown_local_radius_m = 0.5;
    double gsd_m = 0.5;  ///< pixel size of the rasters, metres (for crown_local_radius_m)
    /// A building whose heights' outline lies mostly (this share) in
    /// vegetation segments is a crown and is dropped; it is not given back
    /// its heights' outline.
    double max_vegetation_share = 0.5;
    /// A building whose cells the ortho sees are this share or more of
    /// vegetation colours (weak ones included) and whose heights, taken over
    /// all its cells, exceed both crown limits above (not planar, and rough
    /// locally) is a crown and is dropped: a photo cloud's tree has a few
    /// points in a cell and most cells empty, so its segments are too sparse
    /// to be judged one by one. (0, 1]; above 1 = off.
    double min_crown_building_colour_share = 0.5;
    void validate() const;
};

/// Redraws every building of `mask` (labels on the window's grid, 1..count
/// in raster order) along the ortho: a crop of the bounding box plus margin is
/// normalised on its own, segmented with the nDSM as one more band (gaps
/// filled), and its segments are voted building by the cells of `cells` that
/// have their own evidence; the building becomes the voted pixels connected
/// to its own cells, never taking another building's cells, and stays one
/// 4-connected part (keep_largest_parts). With a
/// classified cloud (`cells.used_classes`), pixels along the new outline keep
/// the cloud's own decision (the share of roof points places an edge inside a
/// pixel). `colours` = the ortho's colour bands (raw values) on the window,
/// `valid` its data mask, `ndsm` the heights (vertical units; `full_scale` =
/// the height mapped to 255). `segments` (may be empty): labels made
/// beforehand on the same window, used instead of segmenting each crop.
/// `vegetation` (may be empty): levels of vegetation_pixels (2 = vegetation
/// colours, 1 = weak ones); segments mostly of level-2 pixels, or mostly of
/// level 1 and more and not planar, are never building (heights without
/// point classes cannot tell crowns from roofs). Returns the number of
/// buildings dropped as crowns (their labels left empty).
std::size_t refine_buildings_with_ortho(BuildingMask& mask, const BuildingCells& cells, const Image<float>& colours,
                                 const std::vector<uint8_t>& valid, const Image<float>& ndsm, double full_scale,
                                 const Image<uint32_t>& segments, const std::vector<uint8_t>& vegetation,
                                 const OrthoRefineOptions& options);

}  // namespace cityforge
