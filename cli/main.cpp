// The `cityforge` command: parses options, sets up logging and progress, calls
// one library function per subcommand and maps errors to exit codes. No
// algorithm lives here.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>

#include "core/error.hpp"
#include "core/log.hpp"
#include "core/progress.hpp"
#include "core/version.hpp"
#include "io/inspect.hpp"
#include "pipeline/audit_run.hpp"
#include "pipeline/city_run.hpp"
#include "pipeline/export_run.hpp"
#include "pipeline/footprints_run.hpp"
#include "pipeline/heights_run.hpp"
#include "pipeline/rasterize_run.hpp"
#include "pipeline/roofs_run.hpp"
#include "pipeline/segment_raster.hpp"
#include <fstream>
#include <nlohmann/json.hpp>
#include "synth/synth.hpp"


namespace cf = cityforge;

namespace {

// {"a", "b"} -> "a b".
std::string join_words(const std::vector<std::string>& words) {
    std::string out;
    for (const std::string& w : words) out += (out.empty() ? "" : " ") + w;
    return out;
}

// "a,b,,c" -> {"a", "b", "c"}.
std::vector<std::string> split_list(const std::string& text) {
    std::vector<std::string> out;
    std::string item;
    std::stringstream ss(text);
    while (std::getline(ss, item, ','))
        if (!item.empty()) out.push_back(item);
    return out;
}

// The rank and size of this process under mpirun (Open MPI, MPICH/PMI, PMIx).
cf::RunShare mpi_share() {
    auto env = [](const char* a, const char* b, const char* c) -> const char* {
        for (const char* k : {a, b, c})
            if (const char* v = std::getenv(k)) return v;
        return nullptr;
    };
    const char* rank = env("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK");
    const char* size = env("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "MPI_LOCALNRANKS");
    if (!rank || !size) throw cf::Error("--mpi", "no MPI rank in the environment; start with mpirun -np N");
    cf::RunShare s;
    s.rank = std::atoi(rank), s.size = std::atoi(size);
    return s;
}

// Parses a JSON file or throws Error naming it.
nlohmann::json read_json_file(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw cf::Error(path, "cannot open config file");
    try {
        return nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
        throw cf::Error(path, std::string("invalid JSON: ") + e.what());
    }
}

// "0,1,2" -> {0, 1, 2}; anything else is refused.
std::vector<int> parse_lods(const std::string& text) {
    std::vector<int> lods;
    for (const std::string& l : split_list(text)) {
        if (l != "0" && l != "1" && l != "2") throw cf::Error("--lod", "levels of detail are 0, 1 and 2, got '" + l + "'");
        lods.push_back(std::stoi(l));
    }
    return lods;
}

// Exit status 4 when an audit's gates failed (said on stderr), else 0.
int gate_exit(const cf::AuditOutput& out) {
    if (out.gates.passed) return 0;
    std::string why;
    for (const auto& f : out.gates.failed) why += (why.empty() ? "" : ", ") + f;
    std::fprintf(stderr, "cityforge: audit failed its gates: %s\n", why.c_str());
    return 4;
}

struct GlobalFlags {
    bool quiet = false;
    bool verbose = false;
    bool progress = false;  // force progress even when stderr is not a terminal
};

cf::Progress make_progress(const GlobalFlags& g) {
    if (g.quiet) return {};
    return cf::Progress(cf::make_terminal_progress(g.progress));
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"cityforge: building extraction, heights and city models from aerial images and point clouds"};
    app.set_version_flag("--version", std::string("cityforge ") + cf::version());
    app.require_subcommand(1);
    app.fallthrough();  // global flags (--quiet, ...) may also follow the subcommand
    app.failure_message([](const CLI::App*, const CLI::Error& e) {
        return std::string("cityforge: error: ") + e.what() + " (see --help)\n";
    });
    GlobalFlags g;
    app.add_flag("-q,--quiet", g.quiet, "No progress and no messages except errors");
    app.add_flag("-v,--verbose", g.verbose, "More messages on stderr");
    app.add_flag("--progress", g.progress, "Show progress even when stderr is not a terminal");

    // info ------------------------------------------------------------------
    auto* info = app.add_subcommand("info", "Describe a raster, point cloud (LAS) or vector file");
    std::string info_path;
    bool info_json = false;
    cf::InspectOptions inspect_options;
    info->add_option("file", info_path, "Raster, LAS or vector file")->required();
    info->add_flag("--json", info_json, "Print JSON instead of text");
    info->add_flag("--stats", inspect_options.cloud_statistics, "Point clouds: read all points for class counts and bounds");
    info->add_option("--crs", inspect_options.assume_crs, "Assume this CRS (e.g. EPSG:7415) when the file has none");

    // synth -----------------------------------------------------------------
    auto* synth = app.add_subcommand("synth", "Generate a synthetic town with exact ground truth");
    std::string synth_out;
    cf::SynthOptions synth_options;
    std::string cloud_mode = "lidar";
    std::vector<double> origin;
    synth->add_option("--out", synth_out, "Output folder")->required();
    synth->add_option("--size-m", synth_options.size_m, "Scene edge length in metres")->capture_default_str();
    synth->add_option("--gsd", synth_options.gsd_m, "Ortho ground sample distance in metres")->capture_default_str();
    synth->add_option("--seed", synth_options.seed, "Random seed (same seed, same bytes)")->capture_default_str();
    synth->add_option("--epsg", synth_options.epsg, "Projected CRS (metres) of the outputs")->capture_default_str();
    synth->add_option("--origin", origin, "Lower-left corner X Y in the CRS")->expected(2);
    synth->add_option("--cloud-density", synth_options.cloud_density_m2, "Points per m2 (0 = no cloud)")->capture_default_str();
    synth->add_option("--cloud-mode", cloud_mode, "lidar or photo (dense image matching: noisier, gaps)")
        ->check(CLI::IsMember({"lidar", "photo"}))
        ->capture_default_str();

    // segment ---------------------------------------------------------------
    auto* segment = app.add_subcommand("segment", "Watershed over-segmentation and multi-scale region merging");
    std::string seg_in, seg_out, seg_config, seg_strategy;
    cf::SegmentOptions seg;
    std::vector<double> seg_scales, seg_band_weights;
    std::optional<double> seg_color, seg_compact, seg_h, seg_sigma, seg_gsd;
    segment->add_option("--ortho", seg_in, "Input raster (any GDAL format, georeferenced)")->required();
    segment->add_option("--out", seg_out, "Output folder")->required();
    segment->add_option("--config", seg_config, "JSON config (schemas/segment_config.schema.json); options given here override it");
    segment->add_option("--scales", seg_scales, "Increasing scale parameters; merge while cost < scale^2")->delimiter(',');
    segment->add_option("--strategy", seg_strategy, "Queue strategy: rag, nng or mutual (default mutual)")
        ->check(CLI::IsMember({"rag", "nng", "mutual"}));
    segment->add_option("--color-weight", seg_color, "Weight of colour vs shape heterogeneity, 0..1 (default 0.9)");
    segment->add_option("--compactness", seg_compact, "Weight of compactness vs smoothness in the shape term, 0..1 (default 0.5)");
    segment->add_option("--band-weights", seg_band_weights, "One weight per band, for the gradient and the colour term")->delimiter(',');
    segment->add_option("--h-minima", seg_h, "Watershed dynamics threshold, grey levels of the 0..255-normalised image (default 4)");
    segment->add_option("--smoothing", seg_sigma, "Gaussian smoothing before the gradient, sigma in pixels (default 1)");
    segment->add_option("--gsd", seg_gsd, "Working GSD in metres (default 0.5; 0 = keep the input's)");
    segment->add_flag("--allow-pixel-coordinates", seg.allow_pixel_coordinates, "Accept a raster without georeferencing");

    // heights ---------------------------------------------------------------
    auto* heights = app.add_subcommand("heights", "Per-building heights from a dense point cloud (LOD1 attributes)");
    std::string h_footprints, h_cloud, h_out;
    cf::HeightsRunOptions hopt;
    bool h_recompute_ground = false, h_no_outliers = false;
    heights->add_option("--footprints", h_footprints, "Footprint polygons (GeoPackage, Shapefile, GeoJSON, ...)")->required();
    heights->add_option("--cloud", h_cloud, "Point cloud (LAS 1.0-1.4, PLY, XYZ/CSV)")->required();
    heights->add_option("--out", h_out, "Output .gpkg (layer buildings), .geojson, .fgb or .shp")->required();
    heights->add_option("--cloud-crs", hopt.cloud_crs, "CRS of the cloud, e.g. EPSG:7415 (overrides the file's)");
    heights->add_option("--layer", hopt.footprint_layer, "Footprint layer name (default: first)");
    heights->add_option("--roof-percentile", hopt.heights.roof_percentile, "Roof percentile used for height_m")->capture_default_str();
    heights->add_option("--ground-percentile", hopt.heights.ground_percentile, "Percentile of ground z around the footprint")->capture_default_str();
    heights->add_option("--ground-buffer-m", hopt.heights.ground_buffer_m, "Width of the ring searched for ground points, metres")->capture_default_str();
    heights->add_option("--min-height-m", hopt.heights.min_height_above_ground_m, "Roof points must be this far above the ground, metres")->capture_default_str();
    heights->add_option("--min-roof-points", hopt.heights.min_roof_points, "Fewer roof points -> null percentiles")->capture_default_str();
    heights->add_option("--max-points-in-memory", hopt.max_points_in_memory, "Larger clouds are read window by window (tiles of --tile-m)")
        ->capture_default_str();
    heights->add_option("--tile-m", hopt.tile_m, "Tile edge of windowed reading, metres")->capture_default_str();
    heights->add_flag("--recompute-ground", h_recompute_ground, "Ignore class 2 and classify ground with SMRF");
    heights->add_flag("--no-outlier-filter", h_no_outliers, "Skip statistical outlier removal");
    heights->add_option("--sor-k", hopt.outliers.k_neighbours, "Outlier removal: neighbours")->capture_default_str();
    heights->add_option("--sor-std", hopt.outliers.std_multiplier, "Outlier removal: sigma multiplier")->capture_default_str();
    heights->add_option("--smrf-slope", hopt.ground.slope, "SMRF slope (rise/run)")->capture_default_str();
    heights->add_option("--smrf-window-m", hopt.ground.window, "SMRF largest window, metres")->capture_default_str();
    heights->add_option("--smrf-threshold-m", hopt.ground.elevation_threshold, "SMRF elevation threshold, metres")->capture_default_str();

    // cloud rasterize -------------------------------------------------------
    auto* cloud = app.add_subcommand("cloud", "Point cloud tools");
    cloud->require_subcommand(1);
    auto* rasterize = cloud->add_subcommand("rasterize", "DSM, DTM, nDSM and point density GeoTIFFs from a cloud");
    std::string r_cloud, r_out;
    cf::RasterizeOptions ropt;
    bool r_recompute_ground = false;
    rasterize->add_option("--cloud", r_cloud, "Point cloud (LAS, PLY, XYZ/CSV)")->required();
    rasterize->add_option("--out", r_out, "Output folder")->required();
    rasterize->add_option("--grid", ropt.grid_raster, "Use this raster's grid exactly (origin, size, GSD, CRS), e.g. the ortho");
    rasterize->add_option("--gsd", ropt.gsd_m, "Cell size in metres when no --grid is given")->capture_default_str();
    rasterize->add_option("--cloud-crs", ropt.cloud_crs, "CRS of the cloud, e.g. EPSG:7415");
    rasterize->add_flag("--recompute-ground", r_recompute_ground, "Ignore class 2 and classify ground with SMRF");
    rasterize->add_option("--max-points-in-memory", ropt.max_points_in_memory, "With --grid, larger clouds are read window by window")
        ->capture_default_str();
    rasterize->add_option("--tile-m", ropt.tile_m, "Tile edge of windowed reading, metres")->capture_default_str();

    // footprints ------------------------------------------------------------
    auto* footprints = app.add_subcommand("footprints", "Building footprints with rectangle fits (ortho + cloud, ortho-only or cloud-only detection)");
    std::string f_out, f_fit = "recursive", f_mode = "auto", f_reg = "lines";
    cf::FootprintsRunOptions fopt;
    footprints->add_option("--cloud", fopt.cloud, "Point cloud (LAS, PLY, XYZ/CSV)");
    footprints->add_option("--ortho", fopt.ortho, "Ortho (any GDAL raster): its grid and CRS are used");
    footprints->add_option("--ndsm", fopt.ndsm, "Heights without a cloud: nDSM raster (height above ground), aligned with the ortho's grid");
    footprints->add_option("--ndsm-band", fopt.ndsm_band, "Heights without a cloud: 1-based band of the ortho holding the nDSM");
    footprints->add_option("--cloud-cell-px", fopt.cloud_cell_factor, "Cloud rasters on cells of N x N ortho pixels (0 = from the cloud's density)")
        ->capture_default_str();
    footprints->add_option("--nir-band", fopt.nir_band, "1-based band of the ortho holding near infrared: NDVI marks vegetation");
    footprints->add_option("--mode", f_mode, "Detection: ortho_cloud (segments voted by the cloud), ortho_only, cloud_only; auto = from the inputs")
        ->check(CLI::IsMember({"auto", "ortho_cloud", "ortho_only", "cloud_only"}))
        ->capture_default_str();
    footprints->add_option("--segments", fopt.segments, "Ortho modes: labels from `cityforge segment` (GeoTIFF, or its folder: the --segment-scale level)");
    footprints->add_option("--segment-scale", fopt.segmentation.segment_scale, "Ortho modes: merging scale of the segmentation")->capture_default_str();
    footprints->add_option("--refine-passes", fopt.segmentation.refine_passes, "Ortho modes: passes moving boundary pixels to the closest-colour segment")
        ->capture_default_str();
    footprints->add_option("--ndsm-weight", fopt.segmentation.ndsm_band_weight, "ortho_cloud: weight of the nDSM band in the segmentation")->capture_default_str();
    footprints->add_option("--min-segment-building-share", fopt.segmentation.min_segment_building_share,
                           "ortho_cloud: share of a segment's pixels that must be cloud building cells")
        ->capture_default_str();
    footprints->add_option("--out", f_out, "Output .gpkg (layer buildings), .geojson, .fgb or .shp")->required();
    footprints->add_option("--cloud-crs", fopt.cloud_crs, "CRS of the cloud, e.g. EPSG:7415");
    footprints->add_option("--fit", f_fit, "Geometry written: recursive (rectangles cut/added until the area error < tolerance), regularised (edges snapped to the dominant directions), rectangle (minimum-area) or raw (simplified outline)")
        ->check(CLI::IsMember({"recursive", "regularised", "rectangle", "raw"}))
        ->capture_default_str();
    footprints->add_option("--gsd", fopt.mask.gsd_m, "Raster cell in metres when no --ortho is given")->capture_default_str();
    footprints->add_option("--min-height-m", fopt.mask.min_height_m, "nDSM threshold for buildings, metres")->capture_default_str();
    footprints->add_option("--min-area-m2", fopt.mask.min_area_m2, "Smallest building kept, square metres")->capture_default_str();
    footprints->add_option("--min-hole-m2", fopt.mask.min_hole_m2, "Smaller holes are filled, larger ones (courtyards) kept")->capture_default_str();
    footprints->add_option("--opening-px", fopt.mask.opening_radius_px, "Morphological opening radius removing slivers, pixels")->capture_default_str();
    footprints->add_option("--split-step-m", fopt.mask.split_step_m, "Split buildings along roof height steps larger than this, metres (0 = never)")
        ->capture_default_str();
    footprints->add_option("--min-split-part-m2", fopt.mask.min_split_part_m2, "Smallest part split off at a height step, square metres")
        ->capture_default_str();
    footprints->add_option("--fit-tolerance-pct", fopt.recursive.tolerance_pct, "Recursive fit: stop below this area error, percent")->capture_default_str();
    footprints->add_option("--regularize-method", f_reg, "Regularised fit: lines (edge lines snapped to the dominant directions) or cgal (CGAL Shape_regularization contours)")
        ->check(CLI::IsMember({"lines", "cgal"}))
        ->capture_default_str();
    footprints->add_option("--simplify-m", fopt.simplify_m, "Douglas-Peucker tolerance of the outline, metres")->capture_default_str();

    // export ----------------------------------------------------------------
    auto* exporter = app.add_subcommand("export", "City models: GeoJSON, GeoPackage, CityGML 2.0, CityJSON 2.0 / CityJSONSeq");
    std::string x_in, x_out, x_formats = "geojson,gpkg,citygml,cityjson,cityjsonseq", x_lods = "0,1,2";
    cf::ExportOptions xopt;
    exporter->add_option("--in", x_in, "Buildings with heights (e.g. from `cityforge heights`), any OGR polygon layer")->required();
    exporter->add_option("--out", x_out, "Output folder")->required();
    exporter->add_option("--formats", x_formats, "Comma-separated: geojson, gpkg, citygml, cityjson, cityjsonseq")->capture_default_str();
    exporter->add_option("--lod", x_lods, "Comma-separated levels of detail: 0 (footprint), 1 (block), 2 (roofs)")->capture_default_str();
    exporter->add_option("--geojson-crs", xopt.geojson_crs, "rfc7946 (WGS84 lon/lat) or native (real CRS, non-standard crs member)")
        ->check(CLI::IsMember({"rfc7946", "native"}))
        ->capture_default_str();
    exporter->add_option("--vertical-crs", xopt.vertical_crs, "Vertical CRS of the heights when the input names none, e.g. EPSG:5709");
    exporter->add_option("--layer", xopt.layer, "Input layer (default: the first)");
    exporter->add_option("--id-field", xopt.id_field, "Building id attribute (absent: the feature id)")->capture_default_str();
    exporter->add_option("--ground-field", xopt.ground_field, "Ground height attribute (vertical CRS units)")->capture_default_str();
    exporter->add_option("--height-field", xopt.height_field, "LOD1 height above ground attribute (metres)")->capture_default_str();
    exporter->add_option("--planarity-tolerance", xopt.validity.planarity_tolerance, "Validity: max vertex distance to its face plane (CRS units)")
        ->capture_default_str();

    // roofs -----------------------------------------------------------------
    auto* roofs = app.add_subcommand("roofs", "LOD2 buildings (roof planes, walls, ground) from footprints and a dense cloud, written as city models");
    std::string rf_footprints, rf_cloud, rf_out, rf_formats = "geojson,gpkg,citygml,cityjson,cityjsonseq", rf_lods = "0,1,2";
    cf::RoofsRunOptions ropts;
    bool rf_recompute_ground = false, rf_no_outliers = false;
    roofs->add_option("--footprints", rf_footprints, "Footprint polygons (any OGR layer)")->required();
    roofs->add_option("--cloud", rf_cloud, "Point cloud (LAS 1.0-1.4, PLY, XYZ/CSV)")->required();
    roofs->add_option("--out", rf_out, "Output folder (buildings.gpkg, .geojson, _lod1.gml, _lod2.gml, .city.json, .city.jsonl)")->required();
    roofs->add_option("--cloud-crs", ropts.heights.cloud_crs, "CRS of the cloud, e.g. EPSG:7415 (overrides the file's)");
    roofs->add_option("--layer", ropts.heights.footprint_layer, "Footprint layer name (default: first)");
    roofs->add_option("--formats", rf_formats, "Comma-separated: geojson, gpkg, citygml, cityjson, cityjsonseq")->capture_default_str();
    roofs->add_option("--lod", rf_lods, "Comma-separated levels of detail: 0, 1, 2")->capture_default_str();
    roofs->add_option("--id-field", ropts.model.id_field, "Building id attribute (absent: the feature id)")->capture_default_str();
    roofs->add_option("--vertical-crs", ropts.model.vertical_crs, "Vertical CRS of the heights when the cloud names none, e.g. EPSG:5709");
    roofs->add_option("--roof-percentile", ropts.heights.heights.roof_percentile, "Roof percentile of the LOD1 height and the flat fallback")
        ->capture_default_str();
    roofs->add_option("--plane-distance-m", ropts.lod2.planes.distance_tolerance_m, "Roof planes: max point-to-plane distance, metres")->capture_default_str();
    roofs->add_option("--plane-normal-deg", ropts.lod2.planes.normal_tolerance_deg, "Roof planes: max normal deviation, degrees")->capture_default_str();
    roofs->add_option("--plane-min-points", ropts.lod2.planes.min_points, "Roof planes: minimum support")->capture_default_str();
    roofs->add_option("--lod2-min-points", ropts.lod2.min_points, "Fewer roof points -> flat roof (LOD1.2)")->capture_default_str();
    roofs->add_option("--max-median-residual-m", ropts.lod2.max_median_residual_m, "A roof model missing its points by more (median) -> flat roof")
        ->capture_default_str();
    roofs->add_flag("--recompute-ground", rf_recompute_ground, "Ignore class 2 and classify ground with SMRF");
    roofs->add_flag("--no-outlier-filter", rf_no_outliers, "Skip statistical outlier removal");

    // run / plan / merge-tiles -----------------------------------------------
    struct RunCli {
        std::string ortho, cloud, cloud_crs, footprints, config, formats, lods, vertical_crs, id_field, fit;
        int tile_size = 0, threads = -1;
        double overlap_m = -1;
    };
    auto add_run_inputs = [](CLI::App* cmd, RunCli& r) {
        cmd->add_option("--ortho", r.ortho, "Ortho: the pixel grid and CRS of the run");
        cmd->add_option("--cloud", r.cloud, "Dense point cloud (LAS, PLY, XYZ)");
        cmd->add_option("--cloud-crs", r.cloud_crs, "CRS of the cloud, e.g. EPSG:7415");
        cmd->add_option("--footprints", r.footprints, "Existing footprints: skip extraction, compute heights, roofs and models");
        cmd->add_option("--config", r.config, "JSON config (schemas/run_config.schema.json); command-line options override it");
        cmd->add_option("--tile-size", r.tile_size, "Tile core edge in pixels (default 4000)");
        cmd->add_option("--overlap-m", r.overlap_m, "Context around each tile, metres (default 100)");
        cmd->add_option("--threads", r.threads, "Threads (default: all cores)");
        cmd->add_option("--formats", r.formats, "Comma-separated: geojson, gpkg, citygml, cityjson, cityjsonseq");
        cmd->add_option("--lod", r.lods, "Comma-separated levels of detail: 0, 1, 2");
        cmd->add_option("--vertical-crs", r.vertical_crs, "Vertical CRS when the cloud names none, e.g. EPSG:5709");
        cmd->add_option("--id-field", r.id_field, "Building id attribute of given footprints");
        cmd->add_option("--fit", r.fit, "Footprint geometry: recursive, regularised, rectangle or raw");
    };
    auto* run_cmd = app.add_subcommand("run", "The whole chain in tiles: cloud -> footprints -> heights -> LOD2 roofs -> city models");
    RunCli run_cli;
    std::string run_out, run_manifest;
    int run_tile_k = -1;
    bool run_mpi = false;
    add_run_inputs(run_cmd, run_cli);
    run_cmd->add_option("--out", run_out, "Output folder (buildings.*, run_report.json, tiles/)")->required();
    run_cmd->add_option("--manifest", run_manifest, "Run the tiles of a manifest from `cityforge plan`");
    run_cmd->add_option("--tile", run_tile_k, "Run only this tile of the manifest (Slurm arrays: $SLURM_ARRAY_TASK_ID); merge with merge-tiles");
    run_cmd->add_flag("--mpi", run_mpi, "Share the tiles among MPI ranks (mpirun -np N); rank 0 merges");
    auto* plan_cmd = app.add_subcommand("plan", "Write the tile manifest of a run (for --tile, --mpi or Slurm)");
    RunCli plan_cli;
    std::string plan_out;
    add_run_inputs(plan_cmd, plan_cli);
    plan_cmd->add_option("--out", plan_out, "Manifest file (.json)")->required();
    auto* merge_cmd = app.add_subcommand("merge-tiles", "Assemble the finished tiles of a run into its city models");
    std::string merge_manifest, merge_out;
    merge_cmd->add_option("--manifest", merge_manifest, "The run's manifest")->required();
    merge_cmd->add_option("--out", merge_out, "The run's output folder")->required();

    // audit -----------------------------------------------------------------
    auto* audit = app.add_subcommand("audit", "Accuracy audits");
    audit->require_subcommand(1);
    // Every audit: --out DIR and the CI gates.
    struct AuditCommon {
        std::string out, below, above;
    };
    auto add_common = [](CLI::App* cmd, AuditCommon& c) {
        cmd->add_option("--out", c.out, "Report folder (report.json, report.md, report.html)")->required();
        cmd->add_option("--fail-below", c.below, "Exit with status 4 when a measure is below its minimum, e.g. f1=0.8,iou=0.7");
        cmd->add_option("--fail-above", c.above, "Exit with status 4 when a measure is above its maximum, e.g. mae=0.5");
    };
    auto gates_of = [](const AuditCommon& c) {
        auto gates = cf::parse_gates(c.below, "--fail-below", true);
        const auto a = cf::parse_gates(c.above, "--fail-above", false);
        gates.insert(gates.end(), a.begin(), a.end());
        return gates;
    };
    auto* audit_fp = audit->add_subcommand("footprints", "Footprints against reference footprints (SpaceNet matching, PoLiS, ISPRS per-area)");
    std::string a_pred, a_ref;
    AuditCommon a_common;
    cf::FootprintAuditOptions aopt;
    audit_fp->add_option("--pred", a_pred, "Predicted footprints (any OGR polygon layer)")->required();
    audit_fp->add_option("--ref", a_ref, "Reference footprints")->required();
    audit_fp->add_option("--iou", aopt.iou_threshold, "IoU threshold of a match")->capture_default_str();
    audit_fp->add_option("--ortho", aopt.ortho_path, "Raster drawn under the map in report.html (reference CRS)");
    add_common(audit_fp, a_common);
    audit_fp->footer("Measures for gates: " + join_words(cf::footprint_audit_measures()));

    auto* audit_rect = audit->add_subcommand("rectangles", "Fitted footprints: original vs fitted area per building (the study's Table 5)");
    std::string r_in;
    AuditCommon r_common;
    cf::RectangleAuditOptions rao;
    audit_rect->add_option("--in", r_in, "Fitted footprints (e.g. from `cityforge footprints`)")->required();
    audit_rect->add_option("--original", rao.original_path, "Original polygons to compare with (matched one to one by IoU)");
    audit_rect->add_option("--original-area-field", rao.original_area_field, "Attribute with the original area in m² (without --original)")
        ->capture_default_str();
    audit_rect->add_option("--iou", rao.iou_threshold, "IoU threshold matching fitted to original polygons")->capture_default_str();
    audit_rect->add_option("--ortho", rao.ortho_path, "Raster drawn under the map in report.html (same CRS)");
    add_common(audit_rect, r_common);
    audit_rect->footer("Measures for gates: " + join_words(cf::rectangle_audit_measures()));

    auto* audit_h = audit->add_subcommand("heights", "Heights of matched footprints against reference heights (MAE, RMSE, bias, max)");
    std::string h_pred, h_ref;
    AuditCommon h_common;
    cf::HeightAuditOptions hao;
    audit_h->add_option("--pred", h_pred, "Predicted footprints with heights")->required();
    audit_h->add_option("--ref", h_ref, "Reference footprints with heights")->required();
    audit_h->add_option("--pred-field", hao.pred_field, "Predicted height attribute")->capture_default_str();
    audit_h->add_option("--ref-field", hao.ref_field, "Reference height attribute")->required();
    audit_h->add_option("--iou", hao.iou_threshold, "IoU threshold of a footprint match")->capture_default_str();
    audit_h->add_option("--ortho", hao.ortho_path, "Raster drawn under the map in report.html (reference CRS)");
    add_common(audit_h, h_common);
    audit_h->footer("Measures for gates: " + join_words(cf::height_audit_measures()) + " (metres; coverage: share of references with both heights)");

    auto* audit_cl = audit->add_subcommand("clouds", "Point cloud against a reference: precision/recall/F-score within tau, chamfer distance");
    std::string c_pred, c_ref;
    AuditCommon c_common;
    cf::CloudAuditOptions copt;
    audit_cl->add_option("--pred", c_pred, "Predicted cloud (LAS, PLY, XYZ)")->required();
    audit_cl->add_option("--ref", c_ref, "Reference cloud")->required();
    audit_cl->add_option("--tau", copt.taus_m, "Distance thresholds in metres")->delimiter(',')->capture_default_str();
    audit_cl->add_option("--pred-crs", copt.pred_crs, "CRS of the predicted cloud if it has none");
    audit_cl->add_option("--ref-crs", copt.ref_crs, "CRS of the reference cloud if it has none");
    add_common(audit_cl, c_common);
    audit_cl->footer("Measures for gates: chamfer chamfer_squared mean_pred_to_ref mean_ref_to_pred, and per tau T: precision@T recall@T f@T");

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        return app.exit(e);
    }
    cf::log::set_level(g.quiet ? cf::log::Level::quiet : g.verbose ? cf::log::Level::debug : cf::log::Level::warning);

    try {
        if (*info) {
            const cf::DatasetInfo d = cf::inspect_dataset(info_path, inspect_options);
            if (info_json) std::cout << cf::to_json(d).dump(2) << "\n";
            else std::cout << cf::to_text(d);
        } else if (*segment) {
            if (!seg_config.empty()) {
                const nlohmann::json j = read_json_file(seg_config);
                const bool allow = seg.allow_pixel_coordinates;
                seg = cf::segment_options_from_json(j, seg_config);
                seg.allow_pixel_coordinates = allow;
            }
            if (!seg_scales.empty()) seg.merging.scales = seg_scales;
            if (!seg_strategy.empty()) seg.merging.strategy = cf::queue_strategy_from_string(seg_strategy);
            if (seg_color) seg.merging.color_weight = *seg_color;
            if (seg_compact) seg.merging.compactness = *seg_compact;
            if (!seg_band_weights.empty()) seg.merging.band_weights = seg.watershed.band_weights = seg_band_weights;
            if (seg_h) seg.watershed.h_minima = *seg_h;
            if (seg_sigma) seg.watershed.smoothing_sigma_px = *seg_sigma;
            if (seg_gsd) seg.working_gsd_m = *seg_gsd;
            const cf::SegmentReport r = cf::segment_raster(seg_in, seg_out, seg, make_progress(g));
            if (!g.quiet) {
                std::fprintf(stderr, "cityforge: watershed %u regions in %.2f s (%d x %d px at %.3g m)\n",
                             r.oversegmentation_regions, r.watershed_seconds, r.working_width, r.working_height, r.working_gsd_m);
                for (const auto& l : r.levels)
                    std::fprintf(stderr, "cityforge: scale %g (%s): %u -> %u regions, queue %llu, %.3f s\n", l.scale,
                                 r.strategy.c_str(), l.regions_before, l.regions_after,
                                 static_cast<unsigned long long>(l.initial_queue_length), l.seconds);
            }
        } else if (*heights) {
            hopt.ground.trust_classification = !h_recompute_ground;
            hopt.outliers.enabled = !h_no_outliers;
            const cf::HeightsRunReport r = cf::run_heights(h_footprints, h_cloud, h_out, hopt, make_progress(g));
            if (!g.quiet) {
                std::string q;
                for (const auto& [k, v] : r.quality_counts) q += " " + k + "=" + std::to_string(v);
                std::fprintf(stderr, "cityforge: heights for %zu buildings in %.1f s, %zu cloud window(s) (%s; %llu points, %zu outliers + %zu isolated removed, %zu ground points %s%s); quality:%s\n",
                             r.buildings, r.seconds, r.tiles, r.crs.c_str(), static_cast<unsigned long long>(r.points_read),
                             r.removed_statistical, r.removed_isolated, r.ground_points,
                             r.ground_from_classification ? "from class 2" : "from SMRF", r.reprojected ? ", cloud reprojected" : "", q.c_str());
            }
        } else if (*rasterize) {
            ropt.ground.trust_classification = !r_recompute_ground;
            const cf::RasterizeReport r = cf::rasterize_run(r_cloud, r_out, ropt, make_progress(g));
            if (!g.quiet)
                std::fprintf(stderr, "cityforge: rasters %d x %d (%s) from %llu points, %zu ground (%s) in %.1f s -> %s\n", r.width,
                             r.height, r.crs.c_str(), static_cast<unsigned long long>(r.points), r.ground_points,
                             r.ground_from_classification ? "class 2" : "SMRF", r.seconds, r_out.c_str());
        } else if (*footprints) {
            fopt.fit = cf::footprint_fit_from_string(f_fit);
            fopt.mode = cf::detection_mode_from_string(f_mode);
            fopt.regularize.method = f_reg == "cgal" ? cf::RegularizeMethod::cgal_contours : cf::RegularizeMethod::lines;
            const cf::FootprintsReport r = cf::run_footprints(f_out, fopt, make_progress(g));
            if (!g.quiet)
                std::fprintf(stderr, "cityforge: %zu footprints (%s%s%s, %s, classes %s) on %d x %d cells in %.1f s; mean |fit area error| %.2f %% -> %s\n",
                             r.buildings, r.mode.c_str(), r.height_source.empty() ? "" : ", heights from ", r.height_source.c_str(), r.crs.c_str(),
                             r.used_classes ? "used" : "absent", r.width, r.height, r.seconds, r.mean_abs_fit_area_error_pct, f_out.c_str());
        } else if (*exporter) {
            xopt.formats = split_list(x_formats);
            xopt.lods = parse_lods(x_lods);
            const cf::ExportReport r = cf::run_export(x_in, x_out, xopt, make_progress(g));
            if (!g.quiet) {
                std::string files, statuses;
                for (const auto& [format, path] : r.files) files += " " + format + " (" + std::to_string(r.seconds.at(format)).substr(0, 5) + " s)";
                for (const auto& [k, v] : r.status_counts) statuses += " " + k + "=" + std::to_string(v);
                std::fprintf(stderr, "cityforge: %zu buildings (%s%s); LOD1 %zu (%zu valid), LOD2 %zu (%zu valid); status:%s; wrote%s -> %s\n",
                             r.buildings, r.crs.c_str(), r.vertical_known ? "" : ", no vertical datum", r.with_lod1, r.valid_lod1,
                             r.with_lod2, r.valid_lod2, statuses.c_str(), files.c_str(), x_out.c_str());
            }
        } else if (*roofs) {
            ropts.heights.ground.trust_classification = !rf_recompute_ground;
            ropts.heights.outliers.enabled = !rf_no_outliers;
            ropts.model.formats = split_list(rf_formats);
            ropts.model.lods = parse_lods(rf_lods);
            const cf::RoofsRunReport r = cf::run_roofs(rf_footprints, rf_cloud, rf_out, ropts, make_progress(g));
            if (!g.quiet) {
                std::string types;
                for (const auto& [k, v] : r.roof_types) types += " " + k + "=" + std::to_string(v);
                std::fprintf(stderr, "cityforge: %zu buildings (%s): LOD2 roof planes %zu, flat fallback %zu, valid LOD2 %zu of %zu; roofs:%s; mean RMSE %.3f m; roofs %.1f s, total %.1f s -> %s\n",
                             r.model.buildings, r.model.crs.c_str(), r.lod2, r.fallbacks, r.model.valid_lod2, r.model.with_lod2, types.c_str(),
                             r.mean_rmse_m, r.lod2_seconds, r.seconds, rf_out.c_str());
            }
        } else if (*run_cmd || *plan_cmd) {
            const RunCli& rc = *run_cmd ? run_cli : plan_cli;
            cf::RunManifest manifest;
            if (!run_manifest.empty() && *run_cmd) {
                manifest = cf::read_manifest(run_manifest);
            } else {
                cf::RunOptions ro;
                if (!rc.config.empty()) ro = cf::run_options_from_json(read_json_file(rc.config), rc.config);
                if (!rc.ortho.empty()) ro.ortho = rc.ortho;
                if (!rc.cloud.empty()) ro.cloud = rc.cloud;
                if (!rc.cloud_crs.empty()) ro.cloud_crs = rc.cloud_crs;
                if (!rc.footprints.empty()) ro.footprints = rc.footprints;
                if (rc.tile_size > 0) ro.tile_size_px = rc.tile_size;
                if (rc.overlap_m >= 0) ro.overlap_m = rc.overlap_m;
                if (rc.threads >= 0) ro.threads = rc.threads;
                if (!rc.formats.empty()) ro.buildings.model.formats = split_list(rc.formats);
                if (!rc.lods.empty()) ro.buildings.model.lods = parse_lods(rc.lods);
                if (!rc.vertical_crs.empty()) ro.buildings.model.vertical_crs = rc.vertical_crs;
                if (!rc.id_field.empty()) ro.buildings.model.id_field = rc.id_field;
                if (!rc.fit.empty()) ro.extraction.fit = cf::footprint_fit_from_string(rc.fit);
                manifest = cf::plan_run(ro);
            }
            if (*plan_cmd) {
                cf::write_manifest(plan_out, manifest);
                if (!g.quiet) std::fprintf(stderr, "cityforge: %zu tiles of %d px (+%d px overlap) over %d x %d px -> %s\n", manifest.tiles.size(),
                                           manifest.options.tile_size_px, manifest.overlap_px, manifest.grid.width, manifest.grid.height, plan_out.c_str());
            } else if (run_tile_k >= 0) {
                const cf::TileReport r = cf::run_tile(manifest, run_tile_k, run_out, make_progress(g));
                if (!g.quiet) std::fprintf(stderr, "cityforge: tile %d %s: %zu buildings%s%s\n", r.index, r.status.c_str(), r.buildings,
                                           r.reason.empty() ? "" : ": ", r.reason.c_str());
                if (r.status == "failed") return 1;
            } else {
                cf::RunShare share;
                if (run_mpi) share = mpi_share();
                const cf::RunReport r = cf::run_city(manifest, run_out, share, make_progress(g));
                if (!g.quiet && share.rank == 0) {
                    std::size_t failed = 0;
                    for (const auto& t : r.tiles) failed += t.status == "failed";
                    std::fprintf(stderr, "cityforge: %zu buildings from %zu tiles (%zu failed); LOD1 valid %zu, LOD2 valid %zu; %zu warnings; %.1f s, peak %.0f MB -> %s\n",
                                 r.buildings, r.tiles.size(), failed, r.valid_lod1, r.valid_lod2, r.warnings.size(), r.seconds, r.peak_memory_mb,
                                 r.report_path.c_str());
                }
            }
        } else if (*merge_cmd) {
            const cf::RunReport r = cf::merge_tiles(cf::read_manifest(merge_manifest), merge_out, make_progress(g));
            if (!g.quiet) std::fprintf(stderr, "cityforge: %zu buildings from %zu tiles -> %s\n", r.buildings, r.tiles.size(), r.report_path.c_str());
        } else if (*audit_fp) {
            aopt.gates = gates_of(a_common);
            const cf::FootprintAuditReport r = cf::audit_footprints(a_pred, a_ref, a_common.out, aopt);
            const auto& s = r.scores;
            std::printf("precision %.4f recall %.4f F1 %.4f mean IoU %.4f mean |area error| %.2f %% mean PoLiS %.3f (TP %zu of %zu predicted, %zu reference)%s\n",
                        s.precision, s.recall, s.f1, s.mean_iou, s.mean_abs_area_error_pct, s.mean_polis, s.true_positives, s.predicted,
                        s.reference, r.reprojected ? "; prediction reprojected" : "");
            return gate_exit(r.output);
        } else if (*audit_rect) {
            rao.gates = gates_of(r_common);
            const cf::RectangleAuditReport r = cf::audit_rectangles(r_in, r_common.out, rao);
            std::printf("mean |area error| %.3f %% max %.3f %% mean signed %+.3f %% over %zu of %zu footprints\n", r.mean_abs_error_pct,
                        r.max_abs_error_pct, r.mean_error_pct, r.rows.size(), r.fitted);
            return gate_exit(r.output);
        } else if (*audit_h) {
            hao.gates = gates_of(h_common);
            const cf::HeightAuditReport r = cf::audit_heights(h_pred, h_ref, h_common.out, hao);
            std::printf("MAE %.3f m RMSE %.3f m bias %+.3f m max %.3f m over %zu buildings (%zu matched of %zu reference)\n", r.mae, r.rmse,
                        r.bias, r.max_abs, r.with_values, r.matched, r.reference);
            return gate_exit(r.output);
        } else if (*audit_cl) {
            copt.gates = gates_of(c_common);
            const cf::CloudAuditReport r = cf::audit_clouds(c_pred, c_ref, c_common.out, copt);
            const auto& c = r.comparison;
            std::printf("chamfer %.4f m (pred->ref %.4f, ref->pred %.4f)", c.chamfer, c.mean_pred_to_ref, c.mean_ref_to_pred);
            for (const auto& s : c.scores) std::printf("; tau %.2f m: P %.4f R %.4f F %.4f", s.tau, s.precision, s.recall, s.f_score);
            std::printf("\n");
            return gate_exit(r.output);
        } else if (*synth) {
            if (origin.size() == 2) synth_options.origin_x = origin[0], synth_options.origin_y = origin[1];
            synth_options.cloud_mode = cf::cloud_mode_from_string(cloud_mode);
            const cf::SynthResult r = cf::write_synthetic_town(synth_out, synth_options, make_progress(g));
            if (!g.quiet)
                std::fprintf(stderr, "cityforge: synth wrote %s (%d x %d px, %d buildings, %d trees, %llu points) in %.1f s\n",
                             synth_out.c_str(), r.width, r.height, r.buildings, r.trees,
                             static_cast<unsigned long long>(r.points), r.seconds);
        }
    } catch (const cf::Error& e) {
        std::fprintf(stderr, "cityforge: error: %s\n", e.what());
        return 1;
    } catch (const std::bad_alloc&) {
        std::fprintf(stderr, "cityforge: error: out of memory\n");
        return 3;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "cityforge: internal error: %s\n", e.what());
        return 2;
    }
    return 0;
}
