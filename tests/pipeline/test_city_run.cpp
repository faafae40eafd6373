#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "cloud/las.hpp"
#include "pipeline/city_run.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;

namespace {
const char* kOutputs[] = {"buildings.geojson", "buildings.gpkg", "buildings_lod1.gml", "buildings_lod2.gml", "buildings.city.json",
                          "buildings.city.jsonl", "buildings.glb", "3dtiles/tileset.json"};
bool same_bytes(const std::string& a, const std::string& b) { return test::slurp(a) == test::slurp(b) && !test::slurp(a).empty(); }
}  // namespace

TEST_CASE("run is tile-invariant and thread-invariant - byte-identical outputs - resumes finished tiles", "[run]") {
    ScratchDir dir("run_tiles");
    const SynthResult s = test::make_town(dir, 500, 4, 8.0);
    const std::string common = "--ortho " + s.ortho_path + " --cloud " + s.cloud_path + " --vertical-crs EPSG:5773 --overlap-m 60 --quiet";
    const std::string env = "SOURCE_DATE_EPOCH=1700000000 ";
    // One tile on two threads; 9 tiles of 350 px on one thread; 9 tiles,
    // three at once on two threads: the same bytes.
    REQUIRE(test::run_command(env + test::cli() + " run " + common + " --tile-size 4000 --threads 2 --out " + (dir / "one")).exit_code == 0);
    for (const auto& [name, options] : {std::pair<std::string, std::string>{"many", " --tile-size 350 --threads 1"},
                                        {"at_once", " --tile-size 350 --threads 2 --concurrent-tiles 3"}}) {
        const auto tiled = test::run_command(env + test::cli() + " run " + common + options + " --out " + (dir / name));
        INFO(name << ": " << tiled.err);
        REQUIRE(tiled.exit_code == 0);
        for (const char* f : kOutputs) {
            INFO(f);
            CHECK(same_bytes(dir / (std::string("one/") + f), dir / (name + "/" + f)));
        }
    }
    CHECK(nlohmann::json::parse(test::slurp(dir / "at_once/run_report.json"))["options"]["concurrent_tiles"] == 3);
    // Resumed with another count of tiles at once and of threads (e.g. after
    // running out of memory): the same plan, so its finished tiles are kept.
    std::filesystem::remove(dir / "at_once/tiles/tile_00004.json");
    std::filesystem::remove(dir / "at_once/buildings.city.json");
    const auto resumed_at_once =
        test::run_command(env + test::cli() + " run " + common + " --tile-size 350 --threads 1 --concurrent-tiles 1 --out " + (dir / "at_once"));
    INFO(resumed_at_once.err);
    REQUIRE(resumed_at_once.exit_code == 0);
    CHECK(same_bytes(dir / "one/buildings.city.json", dir / "at_once/buildings.city.json"));
    const auto report = nlohmann::json::parse(test::slurp(dir / "many/run_report.json"));
    CHECK(report["tiles"].size() == 9);
    CHECK(report["counts"]["buildings"] == s.buildings);
    CHECK(report["counts"]["valid_lod2"] == s.buildings);
    CHECK(report["stage_seconds"].contains("roofs"));
    // The run's wall-clock phases add up to its total.
    const auto& wall = report["wall_seconds"];
    double phases = 0;
    for (const char* p : {"split", "tiles", "merge", "export", "view"}) {
        INFO(p);
        REQUIRE(wall.contains(p));
        CHECK(wall[p].get<double>() >= 0);
        phases += wall[p].get<double>();
    }
    CHECK(wall["total"].get<double>() >= phases - 1e-6);
    CHECK(wall["total"].get<double>() <= phases + 5.0);  // only the writing of the report itself is left out
    CHECK(wall["tiles"].get<double>() > 0);
    CHECK(report["peak_memory_mb"].get<double>() > 0);
    CHECK(report["inputs"]["ortho"]["crs"] == "EPSG:32650");
    CHECK(report["options"]["extraction"]["mode"] == "auto");
    // With an ortho and a cloud, buildings are redrawn along the ortho.
    CHECK(test::slurp(dir / "many/buildings.geojson").find("\"mode\": \"ortho_cloud\"") != std::string::npos);
    // Footprints match the truth one to one.
    const auto audit = test::run_cli("audit footprints --pred " + (dir / "many/buildings.gpkg") + " --ref " + s.truth_path + " --out " +
                                     (dir / "audit") + " --fail-below f1=0.95,iou=0.85");
    CHECK(audit.exit_code == 0);
    // Resume: a lost tile is redone, the others are skipped, the result is the same.
    std::filesystem::remove(dir / "many/tiles/tile_00004.json");
    std::filesystem::remove(dir / "many/tiles/tile_00004.jsonl");
    std::filesystem::remove(dir / "many/buildings.city.json");
    REQUIRE(test::run_command(env + test::cli() + " run " + common + " --tile-size 350 --threads 1 --out " + (dir / "many")).exit_code == 0);
    CHECK(same_bytes(dir / "one/buildings.city.json", dir / "many/buildings.city.json"));
    const auto resumed = nlohmann::json::parse(test::slurp(dir / "many/run_report.json"));
    CHECK(resumed["tiles"].size() == 9);
    // Other options in the same folder are refused rather than mixed.
    const auto mixed = test::run_cli("run " + common + " --tile-size 300 --out " + (dir / "many"));
    CHECK(mixed.exit_code == 1);
    CHECK(mixed.err.find("holds a run with other options") != std::string::npos);
    // Intermediate rasters when asked: tile cores mosaic back onto the ortho's grid.
    {
        std::ofstream cfg(dir / "rasters.json");
        cfg << R"({"keep_rasters": true, "export": {"formats": ["geojson"]}})";
    }
    REQUIRE(test::run_cli("run " + common + " --tile-size 350 --config " + (dir / "rasters.json") + " --out " + (dir / "rasters")).exit_code == 0);
    const auto vrt = test::run_command("gdalinfo " + (dir / "rasters/ndsm.vrt"));
    CHECK(vrt.out.find("Size is 1000, 1000") != std::string::npos);
    CHECK(std::filesystem::exists(dir / "rasters/dtm.vrt"));
    CHECK(same_bytes(dir / "one/buildings.geojson", dir / "rasters/buildings.geojson"));
}

TEST_CASE("plan - run one tile - merge-tiles - MPI ranks - a failed tile is reported", "[run][mpi]") {
    ScratchDir dir("run_plan");
    const SynthResult s = test::make_town(dir, 400, 6, 8.0);
    const std::string env = "SOURCE_DATE_EPOCH=1700000000 ";
    REQUIRE(test::run_cli("plan --ortho " + s.ortho_path + " --cloud " + s.cloud_path + " --config " + test::source_dir() +
                          "/samples/run.json --tile-size 300 --out " + (dir / "m.json") + " --quiet").exit_code == 0);
    const RunManifest m = read_manifest(dir / "m.json");
    CHECK(m.tiles.size() == 9);
    CHECK(m.options.buildings.heights.outliers.max_mean_distance > 0);  // fixed once for every tile
    for (std::size_t k = 0; k < m.tiles.size(); ++k)
        REQUIRE(test::run_command(env + test::cli() + " run --manifest " + (dir / "m.json") + " --tile " + std::to_string(k) + " --out " +
                                  (dir / "slurm") + " --quiet").exit_code == 0);
    REQUIRE(test::run_command(env + test::cli() + " merge-tiles --manifest " + (dir / "m.json") + " --out " + (dir / "slurm") + " --quiet").exit_code == 0);
    if (test::run_command("command -v mpirun").exit_code == 0) {
        const auto mpi = test::run_command(env + "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 mpirun --oversubscribe -np 2 " +
                                           test::cli() + " run --manifest " + (dir / "m.json") + " --mpi --out " + (dir / "mpi") + " --quiet");
        INFO(mpi.out + mpi.err);
        REQUIRE(mpi.exit_code == 0);
        for (const char* f : kOutputs) {
            INFO(f);
            CHECK(same_bytes(dir / (std::string("slurm/") + f), dir / (std::string("mpi/") + f)));
        }
        // Resumed with a tile that failed before (rank 1's tile 5): rank 0
        // merges only once this job's report of it is there (before, the old
        // "failed" report let it merge without the tile and exit 0).
        {
            auto r5 = nlohmann::json::parse(test::slurp(dir / "mpi/tiles/tile_00005.json"));
            r5["status"] = "failed", r5["reason"] = "an earlier fault";
            std::ofstream(dir / "mpi/tiles/tile_00005.json") << r5.dump(2);
            std::filesystem::remove(dir / "mpi/tiles/tile_00005.jsonl");
            std::filesystem::remove(dir / "mpi/buildings.city.json");
        }
        const auto resumed = test::run_command(env + "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 mpirun --oversubscribe -np 2 " +
                                               test::cli() + " run --manifest " + (dir / "m.json") + " --mpi --out " + (dir / "mpi") + " --quiet");
        INFO(resumed.out + resumed.err);
        REQUIRE(resumed.exit_code == 0);
        CHECK(nlohmann::json::parse(test::slurp(dir / "mpi/tiles/tile_00005.json"))["status"] == "done");
        for (const char* f : kOutputs) {
            INFO(f);
            CHECK(same_bytes(dir / (std::string("slurm/") + f), dir / (std::string("mpi/") + f)));
        }
    } else {
        WARN("mpirun not installed: the MPI path was not exercised");
    }
    // The config schema accepts the sample and refuses unknown keys (so does the parser).
    CHECK(test::validate_json(test::source_dir() + "/schemas/run_config.schema.json", test::source_dir() + "/samples/run.json").exit_code == 0);
    {
        std::ofstream bad(dir / "bad.json");
        bad << R"({"tile_size_px": 500, "extraction": {"fitt": "raw"}})";
    }
    CHECK(test::validate_json(test::source_dir() + "/schemas/run_config.schema.json", dir / "bad.json").exit_code == 1);
    const auto refused = test::run_cli("plan --ortho " + s.ortho_path + " --cloud " + s.cloud_path + " --config " + (dir / "bad.json") + " --out " + (dir / "x.json"));
    CHECK(refused.exit_code == 1);
    CHECK(refused.err.find("bad.json: extraction: unknown key 'fitt'") != std::string::npos);
    // A tile whose data cannot be read fails alone, with its reason in the report.
    RunManifest broken = m;
    broken.options.cloud = dir / "missing.las";
    write_manifest(dir / "broken.json", broken);
    const auto failed = test::run_cli("run --manifest " + (dir / "broken.json") + " --tile 0 --out " + (dir / "broken"));
    CHECK(failed.exit_code == 1);
    CHECK(failed.err.find("missing.las: file not found") != std::string::npos);
    CHECK(std::filesystem::exists(dir / "broken/tiles/tile_00000.json"));
}

TEST_CASE("run: a tile that fails while another runs is reported and the others finish whole - a rerun after mending redoes it, same bytes", "[run]") {
    namespace fs = std::filesystem;
    ScratchDir dir("run_tile_fault");
    const SynthResult s = test::make_town(dir, 400, 12, 8.0);
    const std::string env = "SOURCE_DATE_EPOCH=1700000000 ";
    const std::string cmd = env + test::cli() + " run --ortho " + s.ortho_path + " --cloud " + s.cloud_path +
                            " --vertical-crs EPSG:5773 --overlap-m 60 --tile-size 270 --threads 2 --quiet --out ";
    const auto clean = test::run_command(cmd + (dir / "clean") + " --concurrent-tiles 2");
    INFO(clean.err);
    REQUIRE(clean.exit_code == 0);
    REQUIRE(nlohmann::json::parse(test::slurp(dir / "clean/run_report.json"))["tiles"].size() == 9);
    // The same run folder with its tiles lost and the last tile's cloud
    // truncated (a disk fault): the nine tiles run again (the automatic
    // count of tiles at once reads the split files' headers: a damaged one
    // must not stop the run before its tiles). The
    // tiles whose windows (grown around a building, too) read that file fail
    // with it; the others do not.
    fs::copy(dir / "clean", dir / "faulty", fs::copy_options::recursive);
    fs::remove_all(dir / "faulty/tiles");
    const fs::path broken = dir / "faulty/cloud_tiles/tile_00008.las";
    fs::resize_file(broken, 300);
    const auto faulty = test::run_command(cmd + (dir / "faulty"));
    INFO(faulty.err);
    // Some tiles: a result with the failures said, and exit 5 (a partial
    // result: scripts and schedulers must see that tiles are missing).
    REQUIRE(faulty.exit_code == 5);
    CHECK(faulty.err.find("partial result") != std::string::npos);
    CHECK(faulty.err.find("tile_00008.las: corrupt LAS header") != std::string::npos);  // the first failed tile's reason
    const auto report = nlohmann::json::parse(test::slurp(dir / "faulty/run_report.json"));
    REQUIRE(report["tiles"].size() == 9);
    CHECK(report["tiles"][8]["status"] == "failed");
    CHECK(report["tiles"][8]["reason"].get<std::string>().find("tile_00008.las: corrupt LAS header") != std::string::npos);
    bool said = false;
    for (const auto& w : report["warnings"]) said = said || w.get<std::string>().find("tile 8 failed") != std::string::npos;
    CHECK(said);
    // merge-tiles of the same folder says the same (exit 5) and how to run the failed tile.
    const auto merged = test::run_command(env + test::cli() + " merge-tiles --quiet --manifest " + (dir / "faulty/manifest.json") + " --out " +
                                          (dir / "faulty"));
    INFO(merged.err);
    CHECK(merged.exit_code == 5);
    CHECK(merged.err.find("partial result") != std::string::npos);
    CHECK(merged.err.find("tile_00008.las: corrupt LAS header") != std::string::npos);
    CHECK(merged.err.find("--tile K") != std::string::npos);
    // Rank 0 of two MPI ranks without a job id in the environment (an MPI
    // that names none): it cannot tell this failure from an old one, so the
    // failed tile is kept, the run merges the others (rank 1's tiles are all
    // reported already) and says how to run the failed tile: exit 5.
    const auto rank0 = test::run_command(env + "env -u PMIX_NAMESPACE -u OMPI_MCA_ess_base_jobid -u PMI_JOBID -u SLURM_JOB_ID "
                                               "OMPI_COMM_WORLD_RANK=0 OMPI_COMM_WORLD_SIZE=2 " +
                                         test::cli() + " run --manifest " + (dir / "faulty/manifest.json") + " --mpi --out " + (dir / "faulty"));
    INFO(rank0.err);
    CHECK(rank0.exit_code == 5);
    CHECK(rank0.err.find("no MPI job id in the environment") != std::string::npos);
    CHECK(rank0.err.find("--tile K") != std::string::npos);
    CHECK(nlohmann::json::parse(test::slurp(dir / "faulty/run_report.json"))["tiles"][8]["status"] == "failed");
    int done = 0;
    for (int k = 0; k < 9; ++k) {  // the tiles that finished are whole: the clean run's bytes
        INFO("tile " << k);
        if (report["tiles"][k]["status"] != "done") continue;
        ++done;
        const std::string name = "tiles/tile_0000" + std::to_string(k) + ".jsonl";
        CHECK(same_bytes(dir / ("clean/" + name), dir / ("faulty/" + name)));
    }
    CHECK(done >= 4);  // tile 0's corner, at least, is far from tile 8's file
    CHECK(report["tiles"][0]["status"] == "done");
    for (const auto& e : fs::directory_iterator(dir / "faulty/tiles")) {  // no temporary left behind
        INFO(e.path());
        CHECK(e.path().filename().string().find(".part-") == std::string::npos);
    }
    // Mended (the file restored), the same command runs the failed tiles again
    // and keeps the others (their reports, which hold seconds, untouched): the clean run's bytes.
    const std::string tile0_report = test::slurp(dir / "faulty/tiles/tile_00000.json");
    // And a finished tile whose report was damaged runs again too (its
    // report unreadable; the merge would refuse it).
    int damaged = -1;
    for (int k = 1; k < 9 && damaged < 0; ++k)
        if (report["tiles"][k]["status"] == "done") damaged = k;
    REQUIRE(damaged > 0);
    const fs::path damaged_report = dir / ("faulty/tiles/tile_0000" + std::to_string(damaged) + ".json");
    fs::resize_file(damaged_report, 40);
    fs::copy_file(dir / "clean/cloud_tiles/tile_00008.las", broken, fs::copy_options::overwrite_existing);
    const auto mended = test::run_command(cmd + (dir / "faulty"));
    INFO(mended.err);
    REQUIRE(mended.exit_code == 0);
    const auto mended_report = nlohmann::json::parse(test::slurp(dir / "faulty/run_report.json"));
    for (int k = 0; k < 9; ++k) CHECK(mended_report["tiles"][k]["status"] == "done");
    CHECK(test::slurp(dir / "faulty/tiles/tile_00000.json") == tile0_report);
    CHECK(nlohmann::json::parse(test::slurp(damaged_report))["status"] == "done");
    for (const char* f : kOutputs) {
        INFO(f);
        CHECK(same_bytes(dir / (std::string("clean/") + f), dir / (std::string("faulty/") + f)));
    }
}

TEST_CASE("run: tiles at once - the automatic choice by memory and threads", "[run]") {
    // Asked for: taken, never more than the threads.
    CHECK(choose_concurrent_tiles(3, 2, 9, 1e12, 1e9) == 2);
    CHECK(choose_concurrent_tiles(1, 2, 9, 0.0, 24e9) == 1);
    CHECK(choose_concurrent_tiles(2, 0, 9, 0.0, 24e9) == 1);
    // Automatic: one thread or one tile -> 1.
    CHECK(choose_concurrent_tiles(0, 1, 9, 1e6, 24e9) == 1);
    CHECK(choose_concurrent_tiles(0, 2, 1, 1e6, 24e9) == 1);
    // Two tiles must fit in half the usable memory.
    const double tile = estimated_tile_bytes(11.5e6 * 2, 2400.0 * 2400.0);  // a 2400 px window at twice 8 points/m²
    CHECK(tile == Approx(100.0 * 23e6 + 50.0 * 5.76e6));
    CHECK(choose_concurrent_tiles(0, 2, 16, tile, 24e9) == 2);
    CHECK(choose_concurrent_tiles(0, 2, 16, tile, 4.0 * tile) == 2);
    CHECK(choose_concurrent_tiles(0, 2, 16, tile, 4.0 * tile - 1.0) == 1);
    CHECK(choose_concurrent_tiles(0, 8, 16, tile, 2e9) == 1);
    // Memory unknown: taken to fit.
    CHECK(choose_concurrent_tiles(0, 2, 16, tile, 0.0) == 2);
}

TEST_CASE("run without a cloud - ortho-only footprints as one tile - no heights said in every row", "[run]") {
    ScratchDir dir("run_ortho");
    const SynthResult s = test::make_town(dir, 300, 8, 0.0);
    const auto cli = test::run_cli("run --ortho " + s.ortho_path + " --out " + (dir / "out") + " --formats geojson,citygml --quiet");
    INFO(cli.err);
    REQUIRE(cli.exit_code == 0);
    const auto report = nlohmann::json::parse(test::slurp(dir / "out/run_report.json"));
    CHECK(report["tiles"].size() == 1);
    CHECK(report["counts"]["buildings"].get<int>() > 0);
    CHECK(report["counts"]["status"].contains("no_height"));
    CHECK(test::run_command("xmllint --noout --nonet --schema " + test::shared_data("citygml2_schemas/CityGML.xsd") + " " + (dir / "out/buildings_lod1.gml")).exit_code == 0);
    const auto audit = test::run_cli("audit footprints --pred " + (dir / "out/buildings.geojson") + " --ref " + s.truth_path + " --out " + (dir / "a"));
    CHECK(audit.exit_code == 0);
}

TEST_CASE("run with a cloud alone - a grid over its points, tiles without points left out - tile-invariant - matches the truth", "[run]") {
    ScratchDir dir("run_cloud_only");
    const SynthResult s = test::make_town(dir, 400, 6, 8.0);
    const std::string env = "SOURCE_DATE_EPOCH=1700000000 ";
    const std::string common = " run --cloud " + s.cloud_path + " --vertical-crs EPSG:5773 --formats geojson,gpkg,cityjson --quiet";
    REQUIRE(test::run_command(env + test::cli() + common + " --tile-size 4000 --threads 2 --out " + (dir / "one")).exit_code == 0);
    const auto many = test::run_command(env + test::cli() + common + " --tile-size 350 --threads 1 --out " + (dir / "many"));
    INFO(many.err);
    REQUIRE(many.exit_code == 0);
    for (const char* f : {"buildings.geojson", "buildings.gpkg", "buildings.city.json"}) {
        INFO(f);
        CHECK(same_bytes(dir / (std::string("one/") + f), dir / (std::string("many/") + f)));
    }
    const auto report = nlohmann::json::parse(test::slurp(dir / "many/run_report.json"));
    CHECK(report["tiles"].size() == 9);  // 801 x 801 cells of 0.5 m
    CHECK_FALSE(report["inputs"].contains("ortho"));
    CHECK(report["working_crs"] == "EPSG:32650");
    CHECK(report["counts"]["valid_lod2"] == report["counts"]["buildings"]);
    CHECK(test::slurp(dir / "many/buildings.geojson").find("\"mode\": \"cloud_only\"") != std::string::npos);
    const auto audit = test::run_cli("audit footprints --pred " + (dir / "many/buildings.gpkg") + " --ref " + s.truth_path + " --out " +
                                     (dir / "audit") + " --fail-below f1=0.95,iou=0.85");
    CHECK(audit.exit_code == 0);
    // An L-shaped survey: the north-east corner has no point, so the tile
    // whose window (core + overlap) lies there is not planned (it would only
    // fail for want of points).
    LasHeader h;
    const PointCloud all = read_las(s.cloud_path, &h);
    PointCloud kept;
    double minx = all.x[0], maxy = all.y[0];
    for (std::size_t i = 0; i < all.size(); ++i) minx = std::min(minx, all.x[i]), maxy = std::max(maxy, all.y[i]);
    for (std::size_t i = 0; i < all.size(); ++i)
        if (!(all.x[i] > minx + 150.0 && all.y[i] > maxy - 300.0)) kept.append(all, i);
    {
        LasWriter w(dir / "l_shape.las", h.scale, h.offset, h.crs.wkt);
        w.write(kept);
        w.close();
    }
    const auto l = test::run_command(env + test::cli() + " run --cloud " + (dir / "l_shape.las") +
                                     " --vertical-crs EPSG:5773 --formats geojson --quiet --tile-size 350 --out " + (dir / "l"));
    INFO(l.err);
    REQUIRE(l.exit_code == 0);
    const auto lr = nlohmann::json::parse(test::slurp(dir / "l/run_report.json"));
    CHECK(lr["tiles"].size() == 8);
    for (const auto& t : lr["tiles"]) CHECK(t["status"] == "done");
    CHECK(lr["counts"]["buildings"].get<int>() > 0);
    CHECK(lr["counts"]["buildings"].get<int>() < report["counts"]["buildings"].get<int>());
    // With the ortho, the same tile is left out and said in a warning (before, it failed for want of points).
    const auto lo = test::run_cli("run --ortho " + s.ortho_path + " --cloud " + (dir / "l_shape.las") +
                                  " --vertical-crs EPSG:5773 --formats geojson --tile-size 350 --out " + (dir / "lo"));
    INFO(lo.err);
    REQUIRE(lo.exit_code == 0);
    CHECK(lo.err.find("1 of 9 tiles have no point of " + (dir / "l_shape.las") + " in their window and are not planned (no building is detected there") !=
          std::string::npos);
    const auto lor = nlohmann::json::parse(test::slurp(dir / "lo/run_report.json"));
    CHECK(lor["tiles"].size() == 8);
    for (const auto& t : lor["tiles"]) CHECK(t["status"] == "done");
    bool said = false;  // also in the report, for merge-tiles on another host
    for (const auto& w : lor["warnings"]) said = said || w.get<std::string>().find("1 of 9 tiles have no point of") != std::string::npos;
    CHECK(said);
    {
        std::ofstream cfg(dir / "no_outliers.json");
        cfg << R"({"cleaning": {"outlier_filter": false}, "export": {"formats": ["geojson"]}})";
    }
    // A cloud whose box covers the ortho but none of whose points lie on it
    // (two patches beyond opposite corners): refused at plan time, naming both.
    {
        PointCloud far;
        for (std::size_t i = 0; i < all.size() && far.size() < 400; ++i) {
            far.append(all, i);
            far.x.back() += far.size() % 2 ? -600.0 : 600.0;
            far.y.back() += far.size() % 2 ? -600.0 : 600.0;
        }
        LasWriter w(dir / "far.las", h.scale, h.offset, h.crs.wkt);
        w.write(far);
        w.close();
    }
    const auto off = test::run_cli("run --ortho " + s.ortho_path + " --cloud " + (dir / "far.las") + " --config " + (dir / "no_outliers.json") +
                                   " --tile-size 350 --out " + (dir / "off"));
    CHECK(off.exit_code == 1);
    CHECK(off.err.find("far.las: no point of the cloud lies on the grid of " + s.ortho_path) != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "off/buildings.geojson"));
    // One point on a whole multiple of the cell: the grid's top edge lies
    // above it, so the tile holds it (before: "no points in tile 0").
    {
        PointCloud one;
        one.append(all, 0);
        one.x.back() = 500100.0, one.y.back() = 4400100.0;
        LasWriter w(dir / "one.las", {0.01, 0.01, 0.01}, {500000.0, 4400000.0, 0.0}, h.crs.wkt);
        w.write(one);
        w.close();
    }
    const auto single = test::run_cli("run --cloud " + (dir / "one.las") + " --config " + (dir / "no_outliers.json") + " --out " + (dir / "single"));
    CHECK(single.exit_code == 1);
    CHECK(single.err.find("one.las: no building found in 1 tile(s)") != std::string::npos);
    // Only the ground's points: the tiles run, find nothing, and the run says so (exit 1, no city model).
    {
        PointCloud ground;
        for (std::size_t i = 0; i < all.size(); ++i)
            if (all.classification[i] == 2) ground.append(all, i);
        LasWriter w(dir / "ground.las", h.scale, h.offset, h.crs.wkt);
        w.write(ground);
        w.close();
    }
    const auto none = test::run_cli("run --cloud " + (dir / "ground.las") + " --vertical-crs EPSG:5773 --formats geojson --quiet --out " + (dir / "none"));
    CHECK(none.exit_code == 1);
    CHECK(none.err.find("ground.las: no building found in 1 tile(s) (cloud only") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "none/buildings.geojson"));
    // The grid's cell from the config (extraction.cloud_grid_m): 401 x 401 cells of 1 m.
    {
        std::ofstream cfg(dir / "coarse.json");
        cfg << R"({"extraction": {"cloud_grid_m": 1.0}, "export": {"formats": ["geojson"]}})";
    }
    REQUIRE(test::run_cli("plan --cloud " + s.cloud_path + " --config " + (dir / "coarse.json") + " --tile-size 350 --out " + (dir / "coarse_manifest.json") +
                          " --quiet").exit_code == 0);
    const RunManifest coarse = read_manifest(dir / "coarse_manifest.json");
    CHECK(coarse.tiles.size() == 4);
    CHECK(coarse.grid.transform.pixel_width == 1.0);
    // The plan's passes over the cloud say how far they are (a large cloud
    // takes them tens of seconds): its box, then the points per tile, each
    // up to every point the header announces, the overall share never falling.
    {
        RunOptions po;
        po.cloud = s.cloud_path;
        std::vector<std::pair<double, std::string>> said_progress;
        const RunManifest pm = plan_run(po, Progress([&](double f, std::string_view msg) {
            said_progress.emplace_back(f, std::string(msg));
            return true;
        }));
        CHECK(pm.tiles.size() == 1);
        const std::string all_points = " of " + std::to_string(all.size()) + " points";
        bool bounds_done = false, tiles_done = false, rising = true;
        for (std::size_t k = 0; k < said_progress.size(); ++k) {
            bounds_done = bounds_done || said_progress[k].second == "cloud bounds: " + std::to_string(all.size()) + all_points;
            tiles_done = tiles_done || said_progress[k].second == "points per tile: " + std::to_string(all.size()) + all_points;
            rising = rising && (k == 0 || said_progress[k].first >= said_progress[k - 1].first) && said_progress[k].first <= 1.0;
        }
        CHECK(bounds_done);
        CHECK(tiles_done);
        CHECK(rising);
        CHECK(said_progress.back().first == Approx(1.0));
        // --quiet: nothing on stderr.
        const auto quiet = test::run_cli("plan --cloud " + s.cloud_path + " --progress --quiet --out " + (dir / "quiet_manifest.json"));
        CHECK(quiet.exit_code == 0);
        CHECK(quiet.err.empty());
    }
    // Footprints given with the ortho are read at plan time: a missing file is
    // refused there, with no manifest written (before: plan exited 0, every tile failed).
    const auto missing = test::run_cli("plan --ortho " + s.ortho_path + " --cloud " + s.cloud_path + " --footprints " + (dir / "missing.gpkg") +
                                       " --out " + (dir / "missing_manifest.json"));
    CHECK(missing.exit_code == 1);
    CHECK(missing.err.find((dir / "missing.gpkg") + ": file not found") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "missing_manifest.json"));
    // Without an ortho, ortho_cloud detection cannot be asked for.
    RunOptions o;
    o.cloud = s.cloud_path;
    o.extraction.mode = DetectionMode::ortho_cloud;
    CHECK_THROWS_WITH(o.validate(), Catch::StartsWith("extraction.mode") && Catch::Contains("needs an ortho"));
}

TEST_CASE("run refuses detection modes its inputs cannot serve", "[run][errors]") {
    RunOptions o;
    o.ortho = "ortho.tif";
    o.cloud = "cloud.las";
    o.extraction.mode = DetectionMode::ortho_only;
    CHECK_THROWS_WITH(o.validate(), Catch::StartsWith("extraction.mode") && Catch::Contains("would ignore the cloud"));
    o.cloud.clear();
    o.extraction.mode = DetectionMode::ortho_cloud;
    CHECK_THROWS_WITH(o.validate(), Catch::StartsWith("extraction.mode") && Catch::Contains("needs a cloud"));
}

TEST_CASE("run config: roof_seams and crown_plane_sigma_m are read, schema-valid and recorded - a negative sigma is refused", "[run][config]") {
    ScratchDir dir("run_config_crowns");
    const nlohmann::json j = nlohmann::json::parse(R"({"extraction": {"roof_seams": false, "crown_plane_sigma_m": 0.45}})");
    {
        std::ofstream f(dir / "c.json");
        f << j.dump();
    }
    CHECK(test::validate_json(test::source_dir() + "/schemas/run_config.schema.json", dir / "c.json").exit_code == 0);
    RunOptions base;
    base.ortho = "o.tif", base.cloud = "c.las";
    const RunOptions o = run_options_from_json(j, "c.json", base);
    CHECK_FALSE(o.extraction.seams.enabled);
    CHECK(o.extraction.segmentation.max_crown_plane_sigma_m == 0.45);
    const nlohmann::json back = to_json(o);
    CHECK(back["extraction"]["crown_plane_sigma_m"] == 0.45);
    CHECK(back["extraction"]["roof_seams"] == false);
    RunOptions bad = run_options_from_json(nlohmann::json::parse(R"({"extraction": {"crown_plane_sigma_m": -1}})"), "b.json", base);
    CHECK_THROWS_WITH(bad.validate(), Catch::StartsWith("crown_plane_sigma_m"));
}
