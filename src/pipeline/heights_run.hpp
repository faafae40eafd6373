#pragma once
// `cityforge heights`: footprints (any OGR polygon layer) + a dense cloud
// (LAS/PLY/XYZ) -> the footprints with per-building heights, in the
// footprints' CRS plus the cloud's vertical datum.
#include <map>
#include <string>

#include "cloud/cloud_filters.hpp"
#include "core/progress.hpp"
#include "heights/building_heights.hpp"
#include "io/vector.hpp"
#include "pipeline/prepared_cloud.hpp"

namespace cityforge {

struct HeightsRunOptions {
    std::string cloud_crs;            ///< CRS of the cloud (overrides the file's; needed when it has none)
    std::string footprint_layer;      ///< layer name (empty = first)
    OutlierFilterOptions outliers;    ///< radii in metres here; converted to CRS units
    GroundFilterOptions ground;       ///< lengths in metres here; converted to CRS units
    HeightOptions heights;            ///< unit_m / z_unit_m are set from the CRSs
    /// A cloud announcing more points is never held whole: footprints are
    /// grouped in square tiles of `tile_m` and each group reads only its
    /// window of the cloud (streamed), grown by `tile_margin_m`. The outlier
    /// filter's limit is then measured once on the footprints' central 400 m.
    uint64_t max_points_in_memory = 20'000'000;
    double tile_m = 1000.0;           ///< tile edge, metres
    double tile_margin_m = 30.0;      ///< window margin around a tile's footprints (>= 4 x the ground buffer), metres
    /// Fields a later stage writes (roofs, export): input fields of these
    /// names are replaced too, like those of heights_output_fields().
    std::vector<std::string> later_fields;
};

/// The fields `heights` adds to the footprints' own (source_fid, ground_z,
/// roof_z_*, height_m, ..., z_crs). Input fields of these names are replaced
/// (drop_colliding_fields) so that heights runs on its own output.
const std::vector<std::string>& heights_output_fields();

/// The footprints of `path` (layer o.footprint_layer) ready for heights: a
/// projected CRS (lon/lat footprints are moved onto the horizontal CRS of the
/// cloud `cloud_path` when that is projected, else onto the UTM zone of their
/// centre; the output is then written in that CRS), input fields that collide
/// with ours left out (a warning).
PolygonLayer read_footprints_for_heights(const std::string& path, const std::string& cloud_path, const HeightsRunOptions& o);

struct HeightsRunReport {
    std::string output_path;
    std::string crs;                  ///< output CRS label (horizontal + vertical)
    uint64_t points_read = 0;
    std::size_t removed_statistical = 0, removed_isolated = 0;
    std::size_t restored_surface = 0;  ///< points the statistical test removed and restore_surface_points put back
    std::size_t ground_points = 0;
    bool ground_from_classification = false;
    bool reprojected = false;
    std::size_t buildings = 0;
    std::map<std::string, std::size_t> quality_counts;
    std::size_t tiles = 1;            ///< footprint groups the cloud was read in (1 = whole cloud at once)
    double seconds = 0.0;
};

/// The heights stage without writing: footprints read, cloud prepared,
/// heights computed and the output table built (the footprints' fields, then
/// source_fid, ground_z, roof_z_*, height_m, ... as `cityforge heights` writes).
struct HeightsStage {
    PolygonLayer footprints;
    PreparedCloud cloud;
    std::vector<BuildingHeight> heights;
    PolygonLayer table;  ///< output rows in `cloud.crs`; fids = the footprints' fids
    HeightsRunReport report;
};
HeightsStage compute_heights_stage(const std::string& footprints_path, const std::string& cloud_path, const HeightsRunOptions& options,
                                   const Progress& progress = {});
/// The same on footprints and a cloud already in memory (the cloud prepared
/// in the footprints' CRS), e.g. one tile of `cityforge run`.
HeightsStage compute_heights_stage(PolygonLayer footprints, PreparedCloud cloud, const HeightsRunOptions& options,
                                   const Progress& progress = {});

/// Runs the whole height tool. Throws Error naming the file on a missing or
/// empty cloud, a cloud without CRS (and no cloud_crs), footprints without
/// CRS or with invalid polygons, or CRSs PROJ cannot relate. The output
/// (.gpkg layer "buildings", .geojson, .fgb, .shp) appears only when complete.
HeightsRunReport run_heights(const std::string& footprints_path, const std::string& cloud_path,
                             const std::string& output_path, const HeightsRunOptions& options,
                             const Progress& progress = {});

}  // namespace cityforge
