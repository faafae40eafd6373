// cityforge run / plan / merge-tiles: the whole chain in tiles.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>

#include "commands/commands.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "pipeline/city_run.hpp"

namespace cityforge::cli {

namespace {

// The rank and size of this process under mpirun (Open MPI, MPICH/PMI, PMIx).
RunShare mpi_share() {
    auto env = [](const char* a, const char* b, const char* c) -> const char* {
        for (const char* k : {a, b, c})
            if (const char* v = std::getenv(k)) return v;
        return nullptr;
    };
    const char* rank = env("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK");
    const char* size = env("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "MPI_LOCALNRANKS");
    if (!rank || !size) throw Error("--mpi", "no MPI rank in the environment; start with mpirun -np N");
    RunShare s;
    s.rank = std::atoi(rank), s.size = std::atoi(size);
    // The job's id, the same on every rank: failed tiles of an earlier run are then run again.
    if (const char* ns = env("PMIX_NAMESPACE", "OMPI_MCA_ess_base_jobid", "PMI_JOBID")) s.job = ns;
    else if (const char* slurm = std::getenv("SLURM_JOB_ID"))
        s.job = std::string(slurm) + "." + (std::getenv("SLURM_STEP_ID") ? std::getenv("SLURM_STEP_ID") : "0");
    return s;
}

// The inputs `run` and `plan` share; given options override the config file.
struct RunInputs {
    std::string ortho, cloud, cloud_crs, footprints, config, formats, lods, vertical_crs, id_field, fit, db, working_crs, out_crs, texture_ortho;
    int tile_size = 0, threads = -1, concurrent_tiles = -1;
    double overlap_m = -1;
};

void add_run_inputs(CLI::App* cmd, RunInputs& r) {
    cmd->add_option("--ortho", r.ortho, "Ortho: the pixel grid and CRS of the run (without it: a grid over the footprints, or over the cloud alone)");
    cmd->add_option("--cloud", r.cloud, "Dense point cloud (LAS, LAZ, COPC, PLY, XYZ)");
    cmd->add_option("--cloud-crs", r.cloud_crs, "CRS of the cloud, e.g. EPSG:7415");
    cmd->add_option("--footprints", r.footprints, "Existing footprints: skip extraction, compute heights, roofs and models");
    cmd->add_option("--working-crs", r.working_crs, "Projected CRS to work in (default: the ortho's, else the footprints' or the cloud's; a lon/lat ortho: the UTM zone of its centre)");
    cmd->add_option("--out-crs", r.out_crs, "Projected CRS of the city models (default: the input's; the working CRS for a lon/lat input)");
    cmd->add_option("--config", r.config, "JSON config (schemas/run_config.schema.json); command-line options override it");
    cmd->add_option("--tile-size", r.tile_size, "Tile core edge in pixels (default 4000)");
    cmd->add_option("--overlap-m", r.overlap_m, "Context around each tile, metres (default 100)");
    cmd->add_option("--threads", r.threads, "Threads (default: all cores)");
    cmd->add_option("--concurrent-tiles", r.concurrent_tiles, "Tiles processed at once (default 0: 2 with 2 or more threads, else 1; each holds its window's cloud)");
    cmd->add_option("--formats", r.formats, "Comma-separated: geojson, gpkg, citygml, cityjson, cityjsonseq, 3dtiles, gltf");
    cmd->add_option("--lod", r.lods, "Comma-separated levels of detail: 0, 1, 2");
    cmd->add_option("--db", r.db, "Also write the building table to PostGIS: \"PG:dbname=... [tables=NAME]\" (table replaced)");
    cmd->add_option("--vertical-crs", r.vertical_crs, "Vertical CRS when the cloud names none, e.g. EPSG:5709");
    cmd->add_option("--id-field", r.id_field, "Building id attribute of given footprints");
    cmd->add_option("--texture-ortho", r.texture_ortho, "Texture the LOD2 roofs with this ortho's pixels (CityJSON, buildings.glb, 3D Tiles), e.g. the --ortho");
    cmd->add_option("--fit", r.fit, "Footprint geometry: recursive, regularised, rectangle or raw");
}

// The run's plan from the config file and the options given.
RunManifest plan_from(const RunInputs& rc, const Progress& progress) {
    RunOptions ro;
    if (!rc.config.empty()) ro = run_options_from_json(read_json_file(rc.config), rc.config);
    if (!rc.ortho.empty()) ro.ortho = rc.ortho;
    if (!rc.cloud.empty()) ro.cloud = rc.cloud;
    if (!rc.cloud_crs.empty()) ro.cloud_crs = rc.cloud_crs;
    if (!rc.footprints.empty()) ro.footprints = rc.footprints;
    if (!rc.working_crs.empty()) ro.working_crs = rc.working_crs;
    if (!rc.out_crs.empty()) ro.out_crs = rc.out_crs;
    if (rc.tile_size > 0) ro.tile_size_px = rc.tile_size;
    if (rc.overlap_m >= 0) ro.overlap_m = rc.overlap_m;
    if (rc.threads >= 0) ro.threads = rc.threads;
    if (rc.concurrent_tiles >= 0) ro.concurrent_tiles = rc.concurrent_tiles;
    if (!rc.formats.empty()) ro.buildings.model.formats = split_list(rc.formats);
    if (!rc.lods.empty()) ro.buildings.model.lods = parse_lods(rc.lods);
    if (!rc.vertical_crs.empty()) ro.buildings.model.vertical_crs = rc.vertical_crs;
    if (!rc.id_field.empty()) ro.buildings.model.id_field = rc.id_field;
    if (!rc.db.empty()) ro.buildings.model.database = rc.db;
    if (!rc.texture_ortho.empty()) ro.buildings.model.texture_ortho = rc.texture_ortho;
    if (!rc.fit.empty()) ro.extraction.fit = footprint_fit_from_string(rc.fit);
    return plan_run(ro, progress);
}

// What --out may hold before a run: nothing, or an earlier run of the same
// plan (resumed: its finished tiles are kept). An earlier run with other
// options, or other files, are refused unless --overwrite: then the earlier
// run's state (manifest, tiles, cloud tiles, report) is removed and the run
// starts afresh, its outputs replacing the folder's.
void prepare_run_folder(const GlobalFlags& g, const std::string& out, const RunManifest& m) {
    namespace fs = std::filesystem;
    std::error_code ec;
    if (!fs::exists(out, ec)) return;
    if (!fs::is_directory(out, ec)) throw Error(out, "exists and is not a folder; --out names the run's output folder");
    if (fs::is_empty(out, ec)) return;
    const fs::path stored = fs::path(out) / "manifest.json";
    if (fs::exists(stored, ec)) {
        bool same = false;
        try {
            const RunManifest before = read_manifest(stored.string());
            same = same_plan(before, m);
        } catch (const Error&) {
            if (!g.overwrite) throw;
        }
        if (same) return;  // resume
        if (!g.overwrite)
            throw Error(out, "holds a run with other options or tiles; resume with the same options, use a new folder, or give --overwrite to replace it");
    } else if (!g.overwrite) {
        throw Error(out, "output folder exists and is not empty (no earlier run to resume in it); give --overwrite to replace its outputs");
    }
    for (const char* name : {"manifest.json", "run_report.json", "tiles", "cloud_tiles"}) fs::remove_all(fs::path(out) / name, ec);
    log::info(out + ": earlier run state removed (--overwrite); the run starts afresh");
}

// Exit status of a run or merge whose result leaves tiles out: 5 (a partial
// result) with one error line naming the count, the first failure and how to
// complete the result (`retry`), printed whatever --quiet says, so scripts
// and schedulers see that the outputs miss tiles; 0 when every tile is in.
int partial_result_exit(const RunReport& r, const std::string& retry) {
    std::size_t failed = 0;
    const TileReport* first = nullptr;
    for (const auto& t : r.tiles)
        if (t.status == "failed") {
            ++failed;
            if (!first) first = &t;
        }
    if (failed == 0) return 0;
    std::fprintf(stderr, "cityforge: error: %s: partial result: %zu of %zu tiles failed (first: tile %d: %s); the outputs hold the other tiles; %s\n",
                 r.report_path.c_str(), failed, r.tiles.size(), first->index, first->reason.empty() ? "no reason recorded" : first->reason.c_str(),
                 retry.c_str());
    return 5;
}

}  // namespace

void add_run_commands(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct RunState {
        RunInputs inputs;
        std::string out, manifest;
        int tile = -1;
        bool mpi = false;
    };
    auto rs = std::make_shared<RunState>();
    auto* run_cmd = parent.add_subcommand("run", "The whole chain in tiles: cloud -> footprints -> heights -> LOD2 roofs -> city models");
    add_run_inputs(run_cmd, rs->inputs);
    run_cmd->add_option("--out", rs->out, "Output folder (buildings.*, run_report.json, tiles/)")->required();
    run_cmd->add_option("--manifest", rs->manifest, "Run the tiles of a manifest from `cityforge plan`");
    run_cmd->add_option("--tile", rs->tile, "Run only this tile of the manifest (Slurm arrays: $SLURM_ARRAY_TASK_ID); merge with merge-tiles");
    run_cmd->add_flag("--mpi", rs->mpi, "Share the tiles among MPI ranks (mpirun -np N); rank 0 merges");
    // What only the config holds: every key with its default (schema and example named).
    run_cmd->footer("Config file (--config): JSON, schema schemas/run_config.schema.json, example samples/run.json; unknown keys are "
                    "refused, command-line options override it. Keys and defaults:\n" + to_json(RunOptions{}).dump(2) +
                    "\nDIR may hold an earlier run of the same command: its finished tiles are kept and skipped, tiles that "
                    "failed run again (a folder made with other options is refused).");
    out.push_back({run_cmd, [rs, &g]() {
                       const RunManifest manifest = rs->manifest.empty() ? plan_from(rs->inputs, make_progress(g)) : read_manifest(rs->manifest);
                       if (rs->tile >= 0) {
                           const TileReport r = run_tile(manifest, rs->tile, rs->out, make_progress(g));
                           if (r.status == "failed") {  // an error: printed whatever --quiet says
                               std::fprintf(stderr, "cityforge: error: tile %d failed: %s\n", r.index,
                                            r.reason.empty() ? "no reason recorded (see the tile's report in --out/tiles)" : r.reason.c_str());
                               return 1;
                           }
                           if (!g.quiet)
                               std::fprintf(stderr, "cityforge: tile %d %s: %zu buildings%s%s\n", r.index, r.status.c_str(), r.buildings,
                                            r.reason.empty() ? "" : ": ", r.reason.c_str());
                           return 0;
                       }
                       RunShare share;
                       if (rs->mpi) share = mpi_share();
                       if (!manifest.options.buildings.model.vertical_crs.empty()) vertical_crs_option(manifest.options.buildings.model.vertical_crs);
                       require_readable_raster(manifest.options.buildings.model.texture_ortho);
                       if (share.rank == 0) prepare_run_folder(g, rs->out, manifest);
                       const RunReport r = run_city(manifest, rs->out, share, make_progress(g));
                       if (!g.quiet && share.rank == 0) {
                           std::size_t failed = 0;
                           for (const auto& t : r.tiles) failed += t.status == "failed";
                           std::fprintf(stderr,
                                        "cityforge: %zu buildings from %zu tiles (%zu failed); LOD1 valid %zu, LOD2 valid %zu; %zu warnings; %.1f s, peak %.0f MB -> %s\n",
                                        r.buildings, r.tiles.size(), failed, r.valid_lod1, r.valid_lod2, r.warnings.size(), r.seconds,
                                        r.peak_memory_mb, r.report_path.c_str());
                           auto wall = [&r](const char* phase) {
                               const auto it = r.wall_seconds.find(phase);
                               return it == r.wall_seconds.end() ? 0.0 : it->second;
                           };
                           std::fprintf(stderr, "cityforge: wall seconds: split %.1f, tiles %.1f, merge %.1f, export %.1f, view %.1f\n", wall("split"),
                                        wall("tiles"), wall("merge"), wall("export"), wall("view"));
                       }
                       if (share.rank != 0) return 0;
                       // Several ranks without a job id keep failed tiles (they cannot tell an old failure from a new one).
                       return partial_result_exit(r, share.size > 1 && share.job.empty()
                                                         ? "run the failed tiles again with `cityforge run --manifest " + rs->out + "/manifest.json --tile K --out " + rs->out +
                                                               "`, then merge-tiles"
                                                         : "run the same command again to retry the failed ones");
                   }});

    struct PlanState {
        RunInputs inputs;
        std::string out;
    };
    auto ps = std::make_shared<PlanState>();
    auto* plan_cmd = parent.add_subcommand("plan", "Write the tile manifest of a run (for --tile, --mpi or Slurm)");
    add_run_inputs(plan_cmd, ps->inputs);
    plan_cmd->add_option("--out", ps->out, "Manifest file (.json)")->required();
    out.push_back({plan_cmd, [ps, &g]() {
                       const RunManifest manifest = plan_from(ps->inputs, make_progress(g));
                       refuse_existing_output(g, ps->out);
                       write_manifest(ps->out, manifest);
                       if (!g.quiet)
                           std::fprintf(stderr, "cityforge: %zu tiles of %d px (+%d px overlap) over %d x %d px -> %s\n", manifest.tiles.size(),
                                        manifest.options.tile_size_px, manifest.overlap_px, manifest.grid.width, manifest.grid.height,
                                        ps->out.c_str());
                       return 0;
                   }});

    struct MergeState {
        std::string manifest, out;
    };
    auto ms = std::make_shared<MergeState>();
    auto* merge_cmd = parent.add_subcommand("merge-tiles", "Assemble the finished tiles of a run into its city models");
    merge_cmd->add_option("--manifest", ms->manifest, "The run's manifest")->required();
    merge_cmd->add_option("--out", ms->out, "The run's output folder")->required();
    out.push_back({merge_cmd, [ms, &g]() {
                       const RunReport r = merge_tiles(read_manifest(ms->manifest), ms->out, make_progress(g));
                       if (!g.quiet)
                           std::fprintf(stderr, "cityforge: %zu buildings from %zu tiles -> %s\n", r.buildings, r.tiles.size(),
                                        r.report_path.c_str());
                       return partial_result_exit(r, "run the failed tiles again with `cityforge run --manifest " + ms->manifest + " --tile K --out " + ms->out +
                                                             "`, then merge-tiles again");
                   }});
}

}  // namespace cityforge::cli
