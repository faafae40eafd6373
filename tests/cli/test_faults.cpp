// Faults through the built CLI: a full disk (a file-size limit), a run whose
// every tile fails, interrupted commands and footprints that cannot be moved
// to lon/lat. A failed write exits 1, names the file and leaves neither the
// final file nor a temporary.
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;

namespace {
// Runs the CLI with files limited to `kb` KiB: writes past it fail with EFBIG
// (SIGXFSZ ignored), as on a full disk.
test::CommandResult run_cli_limited(int kb, const std::string& args) {
    return test::run_command("bash -c \"trap '' XFSZ; ulimit -f " + std::to_string(kb) + "; " + test::cli() + " " + args + "\"");
}
std::size_t files_in(const std::filesystem::path& dir) {
    std::size_t n = 0;
    if (std::filesystem::exists(dir))
        for ([[maybe_unused]] const auto& e : std::filesystem::recursive_directory_iterator(dir)) n += e.is_regular_file();
    return n;
}
// Files and folders under `dir` whose names hold ".part-" (temporaries).
std::vector<std::string> temporaries_in(const std::filesystem::path& dir) {
    std::vector<std::string> found;
    if (std::filesystem::exists(dir))
        for (const auto& e : std::filesystem::recursive_directory_iterator(dir))
            if (e.path().filename().string().find(".part-") != std::string::npos) found.push_back(e.path().string());
    return found;
}
}  // namespace

TEST_CASE("a full disk: heights, roofs and run exit 1 naming the file and leave no final or temporary file", "[faults][cli]") {
    ScratchDir dir("faults_disk");
    const SynthResult s = test::make_town(dir, 120, 3, 4.0);
    for (const char* ext : {"geojson", "shp", "gpkg", "fgb"}) {
        const std::string out_dir = dir / (std::string("h_") + ext);
        std::filesystem::create_directories(out_dir);
        const std::string out = out_dir + "/h." + ext;
        const auto r = run_cli_limited(1, "heights --quiet --footprints " + s.truth_path + " --cloud " + s.cloud_path + " --out " + out);
        INFO(ext << ": " << r.err);
        CHECK(r.exit_code == 1);
        CHECK(r.err.find(out) != std::string::npos);
        CHECK(files_in(out_dir) == 0);  // no h.geojson, no h.part-PID.shx
        // Without the limit the same command writes the file.
        CHECK(test::run_cli("heights --quiet --footprints " + s.truth_path + " --cloud " + s.cloud_path + " --out " + out).exit_code == 0);
        CHECK(std::filesystem::exists(out));
    }
    // Shapefile sidecars move with the .shp.
    CHECK(std::filesystem::exists(dir / "h_shp/h.dbf"));
    CHECK(std::filesystem::exists(dir / "h_shp/h.shx"));
    CHECK(files_in(dir / "h_shp") == 4);  // .shp .shx .dbf .prj
    // City models: the failing file is not left, whatever was finished before it is complete.
    const auto roofs = run_cli_limited(40, "roofs --quiet --footprints " + s.truth_path + " --cloud " + s.cloud_path + " --out " + (dir / "roofs"));
    INFO(roofs.err);
    CHECK(roofs.exit_code == 1);
    CHECK(roofs.err.find(dir / "roofs/buildings.") != std::string::npos);
    for (const auto& e : std::filesystem::directory_iterator(dir / "roofs")) {
        INFO(e.path());
        CHECK(e.path().string().find(".part-") == std::string::npos);
    }
    // glTF and 3D Tiles: the error names the file asked for (never x.part-PID.glb or
    // 3dtiles.part-PID/...), in the other writers' words, and nothing is left.
    for (const std::string format : {"gltf", "3dtiles"}) {
        const std::string out_dir = dir / ("x_" + format);
        std::filesystem::create_directories(out_dir);
        const auto r = run_cli_limited(8, "export --quiet --formats " + format + " --in " + (dir / "h_gpkg/h.gpkg") + " --out " + out_dir);
        INFO(format << ": " << r.err);
        CHECK(r.exit_code == 1);
        CHECK(r.err.find(out_dir + (format == "gltf" ? "/buildings.glb: " : "/3dtiles/")) != std::string::npos);
        CHECK(r.err.find("write failed (disk full?)") != std::string::npos);
        CHECK(r.err.find(".part-") == std::string::npos);
        CHECK(std::filesystem::is_empty(out_dir));  // no file, no 3dtiles.part-PID/ folder
        // Without the limit the same command writes it.
        const auto ok = test::run_cli("export --quiet --formats " + format + " --in " + (dir / "h_gpkg/h.gpkg") + " --out " + out_dir);
        INFO(ok.err);
        CHECK(ok.exit_code == 0);
        CHECK(std::filesystem::exists(out_dir + (format == "gltf" ? "/buildings.glb" : "/3dtiles/tileset.json")));
        CHECK(temporaries_in(out_dir).empty());
    }
    // A run whose cloud split cannot be written.
    const auto run = run_cli_limited(200, "run --quiet --ortho " + s.ortho_path + " --cloud " + s.cloud_path + " --tile-size 120 --out " + (dir / "run"));
    CHECK(run.exit_code == 1);
    CHECK(run.err.find("write failed") != std::string::npos);
    for (const auto& e : std::filesystem::recursive_directory_iterator(dir / "run")) {
        INFO(e.path());
        CHECK(e.path().string().find(".part-") == std::string::npos);
    }
}

TEST_CASE("run: every tile failed is an error, not empty city models", "[faults][run][cli]") {
    ScratchDir dir("faults_all_failed");
    const SynthResult s = test::make_town(dir, 120, 3, 4.0);
    // An ortho whose header reads but whose pixels do not: truncated after its first bytes.
    std::filesystem::copy_file(s.ortho_path, dir / "broken.tif");
    std::filesystem::resize_file(dir / "broken.tif", 8000);
    const auto r = test::run_cli("run --quiet --ortho " + (dir / "broken.tif") + " --cloud " + s.cloud_path + " --tile-size 120 --out " + (dir / "run"));
    INFO(r.err);
    CHECK(r.exit_code == 1);
    CHECK(r.err.find("every tile failed") != std::string::npos);
    CHECK(r.err.find("broken.tif") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "run/buildings.geojson"));
    CHECK_FALSE(std::filesystem::exists(dir / "run/buildings.city.json"));
    // One tile of a manifest (Slurm arrays): the failure is an error line even with --quiet.
    REQUIRE(test::run_cli("plan --quiet --ortho " + (dir / "broken.tif") + " --cloud " + s.cloud_path + " --tile-size 120 --out " +
                          (dir / "m.json")).exit_code == 0);
    const auto one = test::run_cli("run --quiet --manifest " + (dir / "m.json") + " --tile 0 --out " + (dir / "one"));
    INFO(one.err);
    CHECK(one.exit_code == 1);
    CHECK(one.err.find("cityforge: error: tile 0 failed: ") != std::string::npos);
    CHECK(one.err.find("broken.tif") != std::string::npos);
}

TEST_CASE("results printed to a full stdout are a failed write", "[faults][cli]") {
    ScratchDir dir("faults_stdout");
    const SynthResult s = test::make_town(dir, 60, 3, 0.0);
    const auto full = test::run_command("bash -c '" + test::cli() + " info --json " + s.ortho_path + " >/dev/full'");
    INFO(full.err);
    CHECK(full.exit_code == 1);
    CHECK(full.err.find("stdout: write failed") != std::string::npos);
    CHECK(test::run_command(test::cli() + " info --json " + s.ortho_path + " >/dev/null").exit_code == 0);
}

TEST_CASE("run: temporaries of a killed run are removed on the next start, a live process's are kept, the resume is identical", "[faults][run][cli]") {
    ScratchDir dir("faults_stale");
    const SynthResult s = test::make_town(dir, 120, 3, 4.0);
    const std::string cmd = "run --quiet --ortho " + s.ortho_path + " --cloud " + s.cloud_path + " --tile-size 120 --formats geojson --out " + (dir / "run");
    REQUIRE(test::run_cli(cmd).exit_code == 0);
    const std::string first = test::slurp(dir / "run/buildings.geojson");
    // A process that has exited: its PID names no running process.
    const std::string dead = test::run_command("sh -c 'echo $$'").out;
    const std::string dead_pid = dead.substr(0, dead.find('\n'));
    const std::string live_pid = std::to_string(::getpid());
    const std::vector<std::string> stale = {"cloud_tiles/tile_00000.part-" + dead_pid + ".las", "tiles/tile_00001.part-" + dead_pid + ".jsonl",
                                            "buildings.part-" + dead_pid + ".geojson", "3dtiles.part-" + dead_pid + "/content/0_0_0.glb",
                                            "3dtiles.part-" + dead_pid};
    std::filesystem::create_directories(dir / ("run/3dtiles.part-" + dead_pid + "/content"));  // the 3D Tiles writer's folder
    for (const std::string& f : stale)
        if (!std::filesystem::is_directory(dir / ("run/" + f))) std::ofstream(dir / ("run/" + f)) << "half-written";
    std::ofstream(dir / ("run/tiles/tile_00002.part-" + live_pid + ".jsonl")) << "being written";
    std::filesystem::create_directories(dir / ("run/3dtiles.part-" + live_pid + "/content"));
    std::ofstream(dir / ("run/3dtiles.part-" + live_pid + "/content/0_0_0.glb")) << "being written";
    // The last tile lost: the rerun redoes it and gives the same bytes.
    std::filesystem::remove(dir / "run/tiles/tile_00003.json");
    std::filesystem::remove(dir / "run/buildings.geojson");
    const auto again = test::run_cli(cmd);
    INFO(again.err);
    REQUIRE(again.exit_code == 0);
    for (const std::string& f : stale) {
        INFO(f);
        CHECK_FALSE(std::filesystem::exists(dir / ("run/" + f)));
    }
    CHECK(std::filesystem::exists(dir / ("run/tiles/tile_00002.part-" + live_pid + ".jsonl")));
    CHECK(std::filesystem::exists(dir / ("run/3dtiles.part-" + live_pid + "/content/0_0_0.glb")));
    CHECK(test::slurp(dir / "run/buildings.geojson") == first);
    // Other writing commands clean their output's folder too: a dead process's leftovers beside `heights --out`.
    std::filesystem::create_directories(dir / ("h/3dtiles.part-" + dead_pid + "/content"));
    std::ofstream(dir / ("h/3dtiles.part-" + dead_pid + "/content/0_0_0.glb")) << "half-written";
    std::ofstream(dir / ("h/h.part-" + dead_pid + ".gpkg")) << "half-written";
    const auto h = test::run_cli("heights --quiet --footprints " + s.truth_path + " --cloud " + s.cloud_path + " --out " + (dir / "h/h.gpkg"));
    INFO(h.err);
    CHECK(h.exit_code == 0);
    CHECK(temporaries_in(dir / "h").empty());
    CHECK(std::filesystem::exists(dir / "h/h.gpkg"));
}

TEST_CASE("Ctrl-C and kill: an interrupted command leaves no temporary", "[faults][cli]") {
    ScratchDir dir("faults_sigint");
    // 2 million XYZ points: `cloud translate` takes about a second, most of it writing out.part-PID.las.
    {
        std::ofstream xyz(dir / "big.xyz");
        char line[96];
        for (int i = 0; i < 2000000; ++i) {
            std::snprintf(line, sizeof line, "%.2f %.2f %.2f\n", 500000 + (i % 1400) * 0.5, 4400000 + (i / 1400) * 0.5, 50 + (i % 7) * 0.1);
            xyz << line;
        }
    }
    // Job control on (set -m): a background job of a script would otherwise ignore SIGINT.
    for (const char* sig : {"INT", "TERM", "HUP"})
        for (const char* delay : {"0.2", "0.5", "0.8"}) {
            const std::string out = dir / (std::string("o_") + sig + "_" + delay);
            std::filesystem::create_directories(out);
            const auto r = test::run_command("bash -c 'set -m; " + test::cli() + " cloud translate --quiet " + (dir / "big.xyz") + " " + out +
                                             "/o.las --crs EPSG:32650 & p=$!; sleep " + delay + "; kill -" + sig + " $p; wait $p; echo $?'");
            const int rc = std::atoi(r.out.c_str());
            INFO(sig << " after " << delay << " s: exit " << rc << ", " << r.err);
            CHECK((rc == 0 || rc == 128 + (sig[0] == 'I' ? 2 : sig[0] == 'T' ? 15 : 1)));  // finished, or ended by the signal
            CHECK(temporaries_in(out).empty());
            if (rc != 0) CHECK((std::filesystem::is_empty(out) || std::filesystem::exists(out + "/o.las")));  // o.las only when complete
        }
    // The next command in the same folder works (and removes what a kill -9 would have left).
    const std::string out = dir / "o_INT_0.5";
    std::ofstream(out + "/o.part-999999999.las") << "left by a kill -9";
    CHECK(test::run_cli("cloud translate --quiet --overwrite " + (dir / "big.xyz") + " " + out + "/o.las --crs EPSG:32650").exit_code == 0);
    CHECK(temporaries_in(out).empty());
}

TEST_CASE("footprints that cannot be moved to lon/lat: roofs and export keep every row, warn naming input and feature", "[faults][cli]") {
    ScratchDir dir("faults_lonlat");
    const SynthResult s = test::make_town(dir, 60, 3, 2.0);
    // Feature 1 becomes a square 9e8 m wide (inside the +-1e9 sanity bound, far outside UTM's area).
    nlohmann::json g = nlohmann::json::parse(test::slurp(s.truth_path));
    REQUIRE(g["features"].size() >= 2);
    auto& ft = g["features"][0];
    const std::string id = std::to_string(ft["properties"]["id"].get<int64_t>());
    const double x = ft["geometry"]["coordinates"][0][0][0], y = ft["geometry"]["coordinates"][0][0][1], side = 9e8;
    ft["geometry"] = {{"type", "Polygon"}, {"coordinates", {{{x, y}, {x + side, y}, {x + side, y + side}, {x, y + side}, {x, y}}}}};
    const std::string huge = dir / "huge.geojson";
    std::ofstream(huge) << g.dump();
    const std::size_t n = g["features"].size();
    auto check_rows = [&](const std::string& path) {
        const nlohmann::json out = nlohmann::json::parse(test::slurp(path));
        REQUIRE(out["features"].size() == n);  // every building has its row
        std::size_t without = 0;
        for (const auto& f : out["features"]) {
            CHECK(f["properties"].contains("status"));
            if (f["geometry"].is_null()) {
                ++without;
                CHECK(f["properties"]["cityforge_id"] == id);
            }
        }
        CHECK(without == 1);
    };
    const auto roofs = test::run_cli("roofs --footprints " + huge + " --cloud " + s.cloud_path + " --formats geojson,gpkg --out " + (dir / "roofs"));
    INFO(roofs.err);
    REQUIRE(roofs.exit_code == 0);
    CHECK(roofs.err.find(huge + ": feature '" + id + "': cannot be moved from EPSG:32650 to WGS 84") != std::string::npos);
    check_rows(dir / "roofs/buildings.geojson");
    const auto heights = test::run_cli("heights --quiet --footprints " + huge + " --cloud " + s.cloud_path + " --out " + (dir / "h.gpkg"));
    REQUIRE(heights.exit_code == 0);
    const auto exported = test::run_cli("export --formats geojson,gpkg --in " + (dir / "h.gpkg") + " --out " + (dir / "export"));
    INFO(exported.err);
    REQUIRE(exported.exit_code == 0);
    CHECK(exported.err.find(dir / "h.gpkg" + ": feature '" + id + "'") != std::string::npos);
    check_rows(dir / "export/buildings.geojson");
}
