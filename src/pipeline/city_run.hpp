#pragma once
// `cityforge run`, `plan` and `merge-tiles`: the whole chain (cloud ->
// ground -> nDSM -> buildings -> footprints and fits -> heights -> LOD2 roofs
// -> city models) over an area of any size, cut into tiles of the ortho's (or, without one, the footprints' or the cloud's)
// pixel grid with an overlap. A building belongs to the one tile whose core
// holds its reference pixel (its first pixel in raster order, global
// coordinates) or, for given footprints, the centre of its bounding box; so
// buildings across tile edges are whole and never duplicated, and every step
// that decides a building looks only at data within the overlap: the result
// does not depend on the tile size or the thread count. Finished tiles are
// kept in DIR/tiles/ and skipped when the run is resumed.
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cloud/cloud_rasters.hpp"
#include "core/progress.hpp"
#include "pipeline/footprints_run.hpp"
#include "pipeline/roofs_run.hpp"
#include "raster/raster.hpp"

namespace cityforge {

struct RunOptions {
    /// Defines the pixel grid and CRS of the run. Without an ortho the grid
    /// covers the given footprints (footprint_grid_m cells) or, cloud only,
    /// the cloud's points (extraction.mask.gsd_m cells, config key
    /// extraction.cloud_grid_m; the cloud's projected
    /// CRS or working_crs). Runs that extract buildings plan only the tiles
    /// whose window holds points of the cloud.
    std::string ortho;
    std::string cloud;        ///< dense cloud (LAS/LAZ/COPC/PLY/XYZ); required unless the run is ortho-only
    std::string cloud_crs;    ///< overrides/supplies the cloud's CRS
    std::string footprints;   ///< existing footprints: extraction is skipped
    /// Projected CRS the run works in ("EPSG:32723"): the ortho is read
    /// warped onto it. Empty = the ortho's own CRS, or for an ortho in a
    /// geographic CRS the UTM zone of its centre (working_crs_for).
    std::string working_crs;
    /// CRS of the city models and building tables (projected; a model in
    /// degrees is refused). Empty = the ortho's (footprints') own CRS, or
    /// the working CRS when that one is geographic.
    std::string out_crs;
    int tile_size_px = 4000;  ///< tile core edge, pixels of the grid
    double overlap_m = 100.0; ///< context around each core; must exceed the largest building plus the ground ring
    int threads = 0;          ///< 0 = all cores
    /// Tiles processed at once (each holds its window's cloud, rasters and
    /// buildings: about 1.2 GB for 2000 px tiles at 0.5 m and 8 points/m²).
    /// 0 = automatic (choose_concurrent_tiles): 2 when the run has at least
    /// 2 threads and two of its largest tiles fit in half the usable memory,
    /// else 1. The outputs do not depend on it (each tile's work is its own).
    int concurrent_tiles = 0;
    double footprint_grid_m = 1.0;  ///< grid cell when there is no ortho (footprints given), metres
    /// Write each tile core's DSM, DTM and nDSM (float32 GeoTIFF on the
    /// run's grid) to DIR/rasters/ and a VRT mosaic of each (cloud runs that extract).
    bool keep_rasters = false;
    FootprintsRunOptions extraction;  ///< detection, outline and fit options (cloud mode)
    RoofsRunOptions buildings;        ///< heights, LOD2 and export options
    void validate() const;
};

/// Options from a JSON config (schemas/run_config.schema.json); unknown keys
/// are refused with their path. Missing keys keep `base`'s values.
RunOptions run_options_from_json(const nlohmann::json& config, const std::string& where, RunOptions base = {});
/// Every option, in the config's shape (what a manifest stores).
nlohmann::json to_json(const RunOptions& options);

struct TileSpec {
    int index = 0;
    PixelWindow core;    ///< pixels this tile owns
    PixelWindow window;  ///< core + overlap, clipped to the grid
};

struct RunManifest {
    RunOptions options;
    GridSpec grid;          ///< the run's pixel grid (the ortho's, or one over the footprints or the cloud)
    std::string crs_wkt;    ///< horizontal CRS of the grid (the working CRS: projected)
    int overlap_px = 0;
    /// Tiles of the grid not planned: their window holds no point of the
    /// cloud (runs that extract buildings); said in the run report's warnings.
    int tiles_left_out = 0;
    std::vector<TileSpec> tiles;
};

/// How a run opens its ortho: on the working grid (a lon/lat ortho warped
/// onto its UTM zone, or onto `working_crs`). plan_run and every tile use it,
/// so the tiles read the grid the manifest describes.
RasterOpenOptions run_ortho_open_options(const RunOptions& options);

/// Ground metres per CRS unit of the run's grid at its centre (the nominal
/// unit, or the projection's scale in Web Mercator: ground_metres_per_unit).
double grid_metres_per_unit(const RunManifest& manifest);

/// Reads the inputs' headers and cuts the grid into tiles. Throws Error naming the file.
/// With a cloud it streams the cloud's points (its box, a 400 m sample, the
/// points per tile) and reports the box's and the tiles' passes point by
/// point to `progress` ("cloud bounds: N of M points", ...), the sample's
/// start, and 1.0 ("planned") at the end.
RunManifest plan_run(const RunOptions& options, const Progress& progress = {});
void write_manifest(const std::string& path, const RunManifest& manifest);
RunManifest read_manifest(const std::string& path);
/// Whether an earlier run's manifest (`stored`) plans the same work as `m`,
/// so its finished tiles can be kept: the same options, tiles and overlap.
/// How the work is spread (threads, concurrent_tiles) may differ: the
/// outputs do not depend on it.
bool same_plan(const RunManifest& stored, const RunManifest& m);

struct TileReport {
    int index = 0;
    std::string status;   ///< "done", "skipped" (finished earlier), "failed"
    std::string reason;   ///< why a tile failed
    std::size_t buildings = 0;
    /// Buildings whose context left the tile's window, done again on a
    /// window grown around them (the result does not depend on the tiling).
    std::size_t grown = 0;
    std::map<std::string, double> seconds;  ///< per stage
    /// The process's peak resident memory (MB) when the tile finished: with
    /// tiles at once it includes the other tiles' memory, so it bounds the
    /// tile's own from above.
    double peak_memory_mb = 0.0;
    /// Declared type of each building attribute (source layer and stages), so
    /// that the merge keeps a field's type when all its values are null.
    std::vector<std::pair<std::string, FieldType>> attribute_types;
};

/// Bytes one tile holds at its peak, estimated with room to spare: 100 bytes
/// per point of its window (a 2400 px window of 11.5 M points peaked at
/// 1.2 GB) and 50 bytes per pixel of its window.
double estimated_tile_bytes(double window_points, double window_pixels);

/// Tiles a run processes at once. `requested` > 0 is taken, capped by
/// `threads` (at least 1); 0 = automatic: 2 when `threads` >= 2, the run has
/// 2 or more `tiles` and two tiles of `tile_bytes` fit in half of
/// `usable_bytes` (0 = unknown: they are taken to fit), else 1.
int choose_concurrent_tiles(int requested, int threads, std::size_t tiles, double tile_bytes, double usable_bytes);

/// How run_tile treats an earlier report of its tile.
struct TileResume {
    /// A report saying "failed" runs the tile again (false: it is kept, as
    /// a finished one; ranks of a job without a job id, whose rank 0 could
    /// not tell an old failed report from a new one).
    bool rerun_failed = true;
    /// The launcher's job id, written into the report ("job") so that rank 0
    /// of a multi-rank run waits for this job's report of a tile run again.
    std::string job;
};
/// Runs tile `k` into `out_dir`/tiles/ (tile_K.jsonl: one building per line,
/// tile_K.json: its report). Skips a tile whose report says it is done; a
/// tile that failed (unless `resume.rerun_failed` is false) or whose report
/// cannot be read runs again, so a rerun after mending the cause (a file
/// replaced, memory freed) completes the run. Errors of the tile's data are
/// caught and reported as a failed tile.
TileReport run_tile(const RunManifest& manifest, int k, const std::string& out_dir, const Progress& progress = {}, const TileResume& resume = {});

struct RunReport {
    std::size_t buildings = 0, valid_lod1 = 0, valid_lod2 = 0;
    std::vector<TileReport> tiles;
    std::vector<std::string> warnings;
    ExportReport model;
    std::string report_path;   ///< DIR/run_report.json
    double seconds = 0.0, peak_memory_mb = 0.0;
    /// Wall seconds of the run's phases, in order: `split` (one pass over the
    /// cloud into its tiles), `tiles` (this process's tiles, one after the
    /// other), `wait` (for other ranks' tiles), `merge` (reading the tiles'
    /// buildings, completing them), `export`, `view`, and `total`. The
    /// report's `stage_seconds` are sums of the tiles' own stage seconds.
    std::map<std::string, double> wall_seconds;
};

/// Assembles DIR/tiles/* into the city models in DIR and writes
/// DIR/run_report.json. Throws Error when a tile has not run. `phases`: wall
/// seconds of the phases before the merge (run_city's split, tiles, wait),
/// written with the merge's own under `wall_seconds`.
RunReport merge_tiles(const RunManifest& manifest, const std::string& out_dir, const Progress& progress = {},
                      const std::map<std::string, double>& phases = {});

/// One process's share of a distributed run: tiles k with k % size == rank.
struct RunShare {
    int rank = 0, size = 1;
    /// The launcher's job id, the same on every rank (PMIx namespace, Open
    /// MPI job id, Slurm job and step); empty when unknown. With several
    /// ranks and no job id, failed tiles of an earlier run are not run again.
    std::string job;
    double wait_seconds = 3600.0;  ///< rank 0 waits this long for the others' tiles before merging
};

/// Plans (or takes) the manifest, runs this share's tiles, and on rank 0
/// merges when every tile is finished.
RunReport run_city(const RunManifest& manifest, const std::string& out_dir, const RunShare& share = {}, const Progress& progress = {});

}  // namespace cityforge
