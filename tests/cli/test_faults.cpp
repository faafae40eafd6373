// Faults through the built CLI: a full disk (a file-size limit) and a run
// whose every tile fails. A failed write exits 1, names the file and leaves
// neither the final file nor a temporary.
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>

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
                                            "buildings.part-" + dead_pid + ".geojson"};
    for (const std::string& f : stale) std::ofstream(dir / ("run/" + f)) << "half-written";
    std::ofstream(dir / ("run/tiles/tile_00002.part-" + live_pid + ".jsonl")) << "being written";
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
    CHECK(test::slurp(dir / "run/buildings.geojson") == first);
}
