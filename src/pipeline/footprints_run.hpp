#pragma once
// `cityforge footprints`: building footprints with rectangle fits, in three
// detection modes chosen from the inputs: ortho + cloud (segments of the
// ortho and nDSM voted building by the cloud's cells), ortho only (segments
// classified by spectra and shape) and cloud only (nDSM and point classes).
#include <map>
#include <string>

#include "cloud/cloud_filters.hpp"
#include "cloud/cloud_rasters.hpp"
#include "core/image.hpp"
#include "crs/crs.hpp"
#include "detect/self_training.hpp"
#include "io/vector.hpp"
#include "core/progress.hpp"
#include "footprint/building_mask.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/regularize.hpp"
#include "footprint/curved_outline.hpp"
#include "footprint/roof_seams.hpp"
#include "footprint/segment_classifier.hpp"
#include "footprint/ortho_refine.hpp"
#include "footprint/outline_fit.hpp"

namespace cityforge {

/// Detection mode; `automatic` picks ortho_cloud with an ortho and heights,
/// otherwise the one input's mode. "cloud" stands for the height source: a
/// point cloud, an nDSM raster or an nDSM band of the ortho.
enum class DetectionMode { automatic, ortho_cloud, ortho_only, cloud_only };
DetectionMode detection_mode_from_string(const std::string& s);
std::string to_string(DetectionMode m);

/// Ortho-only detector: a learned model (src/detect; the shipped default
/// model for the image's bands unless one is given) or the hand-set
/// segment rules (footprint/segment_classifier); `automatic` = the model,
/// or the rules when segments made beforehand are given (--segments: the
/// model segments the ortho itself, at its own scales).
enum class OrthoDetector { automatic, model, rules };
OrthoDetector ortho_detector_from_string(const std::string& s);
std::string to_string(OrthoDetector d);

struct FootprintsRunOptions {
    std::string cloud;             ///< point cloud (LAS, PLY, XYZ)
    std::string cloud_crs;         ///< overrides/supplies the cloud's CRS
    /// Heights without a cloud: an nDSM raster (heights above ground, vertical
    /// CRS units; in the ortho's CRS on a grid aligned with it, or alone) ...
    std::string ndsm;
    /// ... or the 1-based band of the ortho that holds the nDSM (0 = none);
    /// that band is then left out of the colours.
    int ndsm_band = 0;
    /// 1-based band of the ortho holding near infrared (0 = none): NDVI then
    /// marks vegetation segments (red is the first band).
    int nir_band = 0;
    /// Cloud rasters on cells of this many ortho pixels a side (0 = chosen
    /// from the cloud's density: at least 2 points per cell on average).
    int cloud_cell_factor = 0;
    std::string ortho;             ///< ortho: its grid and CRS are used
    /// CRS the work is done in (metres): empty = the ortho's own, or for an
    /// ortho in a geographic CRS the UTM zone of its centre (the ortho is then
    /// read warped onto it).
    std::string working_crs;
    /// CRS of the written footprints: empty = the input's (the ortho's own
    /// CRS, else the cloud's or the nDSM's).
    std::string out_crs;
    DetectionMode mode = DetectionMode::automatic;
    /// ortho modes: segments made beforehand by `cityforge segment` (a label
    /// GeoTIFF on the ortho's grid, or its output folder: the level of
    /// segmentation.segment_scale, or its only level) instead of segmenting here.
    std::string segments;
    /// Segmentation of the ortho (watershed, scale, boundary refinement: both
    /// ortho modes) and the per-building voting of the ortho_cloud mode.
    OrthoRefineOptions segmentation;
    SegmentClassifierOptions classifier;  ///< ortho-only: segment rules (--detector rules)
    OrthoDetector detector = OrthoDetector::automatic;  ///< ortho-only detector
    /// ortho-only, --detector model: the model file (`cityforge train`);
    /// empty = the shipped default for the ortho's bands.
    std::string model;
    /// ortho_cloud: where the heights cover only part of the ortho, an image
    /// model trained on the buildings found under the heights detects the
    /// buildings outside them (src/detect/self_training.hpp).
    detect::SelfTrainingOptions self_training;
    BuildingMaskOptions mask;      ///< detection thresholds (gsd_m is the raster cell)
    RoofSeamOptions seams;         ///< ortho_cloud: terraces split at roof seams (gsd_m is the raster cell)
    double simplify_m = 0.25;      ///< Douglas–Peucker tolerance of the raw outline, metres
    FootprintFit fit = FootprintFit::recursive;  ///< geometry written
    RecursiveFitOptions recursive;     ///< tolerance etc. of the recursive fit (areas in m2)
    RegularizeOptions regularize;      ///< snapping of the regularised fit (lengths in metres)
    /// Recursive and regularised fits: a round or many-sided outline (see
    /// footprint/curved_outline.hpp) is written smoothed instead, its `fit`
    /// field "curved".
    CurvedOutlineOptions curved;
    OutlierFilterOptions outliers;
    GroundFilterOptions ground;
    /// A cloud announcing more points is never held whole: its rasters are
    /// made window by window (tiles of at most `cloud_tile_m`, smaller when
    /// the density asks, read as windows grown by `cloud_overlap_m`,
    /// streamed) and joined; the footprints are the same as a whole-cloud
    /// run's (see pipeline/cloud_windows.hpp).
    uint64_t max_points_in_memory = 20'000'000;
    double cloud_tile_m = 1000.0;
    double cloud_overlap_m = 100.0;
    void validate() const;
};

/// Every region of a label raster as polygons in map coordinates, index =
/// label. `labels` is the window of `grid` starting at pixel (col0, row0);
/// coordinates are computed from global pixel indices, so the same pixels give
/// the same coordinates in any window.
std::vector<std::vector<Polygon>> vectorize_window(const Image<uint32_t>& labels, const GeoTransform& grid, int col0, int row0);

/// The rows of `cityforge footprints` for the buildings of a mask: simplified
/// outline, fit, areas, orientation, fit error and IoU, median nDSM height.
struct FootprintTable {
    std::vector<FieldDefinition> fields;
    std::vector<Feature> features;
    double mean_abs_fit_area_error_pct = 0.0;
};
/// `ids[label]` names each building (empty: 1, 2, ... in label order);
/// `ndsm` may be empty (no height cue). `sources[label]` = what found the
/// building (the `source` field: "cloud", "ndsm", "image_model",
/// "image_rules"); missing or empty: "image_model" in ortho_only mode,
/// otherwise "cloud".
FootprintTable footprint_table(const BuildingMask& mask, const Image<float>& ndsm, const GeoTransform& grid, int col0, int row0,
                               const std::vector<int64_t>& ids, const std::string& mode, double unit, double z_unit, const CrsInfo& crs,
                               const FootprintsRunOptions& options, const std::vector<std::string>& sources = {});

/// An nDSM raster (heights above ground, vertical CRS units; nodata = NaN)
/// on `grid` when `grid` has cells (same horizontal CRS as `crs`, pixel
/// edges aligned, covering it; resampled to its cells), else on its own grid
/// (then `grid` and `crs` are set). Throws Error naming the file otherwise.
Image<float> read_ndsm_raster(const std::string& path, GridSpec& grid, CrsInfo& crs);

struct FootprintsReport {
    std::string mode;              ///< "ortho_cloud", "ortho_only" or "cloud_only"
    std::string detector;          ///< ortho_only: "model FILE" or "rules"
    std::string height_source;     ///< "point cloud", "nDSM raster", "ortho band N" or "" (ortho only)
    int cloud_cell_factor = 1;     ///< cloud rasters on cells of this many pixels a side
    std::size_t cloud_windows = 0; ///< windows the cloud was read in (0 = held whole)
    uint32_t segments = 0;         ///< ortho modes: merged segments
    std::string segments_path;     ///< the label raster read for --segments (empty: segmented here)
    std::string crs;               ///< CRS of the written footprints
    std::string working_crs;       ///< CRS the detection worked in (metres)
    std::size_t buildings = 0;
    int seam_splits = 0;           ///< ortho_cloud: seams cut between touching roofs (terraces)
    int crowns_dropped = 0;        ///< ortho_cloud without point classes: buildings dropped as tree crowns (colours + no plane)
    std::size_t hidden_completed_cells = 0;  ///< unmeasured cells completed inside buildings' rectangles (complete_hidden_roofs)
    bool used_classes = false;
    int width = 0, height = 0;
    double seconds = 0.0;
    double mean_abs_fit_area_error_pct = 0.0;
    std::size_t from_heights = 0;  ///< buildings with source "cloud" or "ndsm"
    std::size_t from_image = 0;    ///< buildings with source "image_model" or "image_rules"
    /// ortho_cloud: what the self-training did ("" in other modes).
    std::string self_training;
    double uncovered_share = 0.0;  ///< ortho_cloud: share of the ortho's valid pixels outside the heights' coverage
};

/// Writes the footprints (.gpkg layer "buildings", .geojson, ...) with
/// id, mode, source, fit, area_m2, raw_area_m2, geodesic_area_m2, perimeter_m,
/// orientation_deg, fit_area_error_pct, fit_iou, n_vertices, height_p50_m.
FootprintsReport run_footprints(const std::string& output_path, const FootprintsRunOptions& options,
                                const Progress& progress = {});

}  // namespace cityforge
