#include <catch2/catch.hpp>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "test_support.hpp"

using cityforge::test::count_lines;
using cityforge::test::run_cli;
using cityforge::test::run_command;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

TEST_CASE("cityforge --version and --help on every subcommand", "[cli]") {
    const auto v = run_cli("--version");
    CHECK(v.exit_code == 0);
    CHECK(v.out.find("cityforge ") == 0);
    for (const char* sub : {"info", "synth", "segment", "heights", "footprints", "cloud rasterize", "audit footprints", "audit heights", "audit clouds"}) {
        const auto h = run_cli(std::string(sub) + " --help");
        INFO(sub);
        CHECK(h.exit_code == 0);
        CHECK(h.out.find("Usage") != std::string::npos);
    }
    CHECK(run_cli("").exit_code != 0);
    CHECK(run_cli("no-such-subcommand").exit_code != 0);
}

TEST_CASE("cityforge info prints text and JSON for a real raster", "[cli]") {
    const std::string tif = shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif");
    const auto t = run_cli("info " + tif);
    CHECK(t.exit_code == 0);
    CHECK(t.out.find("EPSG:32616") != std::string::npos);
    CHECK(t.out.find("UInt16") != std::string::npos);
    const auto j = run_cli("info --json " + tif);
    REQUIRE(j.exit_code == 0);
    const auto doc = nlohmann::json::parse(j.out);
    CHECK(doc["kind"] == "raster");
    CHECK(doc["width"] == 450);
    CHECK(doc["crs"]["epsg"] == 32616);
    CHECK(doc["gsd_m"]["x"].get<double>() == Approx(0.5));
    const auto cloud = run_cli("info --json --crs EPSG:7415 " + shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"));
    REQUIRE(cloud.exit_code == 0);
    CHECK(nlohmann::json::parse(cloud.out)["crs"]["vertical_epsg"] == 5709);
}

TEST_CASE("cityforge errors are one line on stderr naming the file - with a non-zero exit", "[cli][errors]") {
    ScratchDir dir("cli_err");
    const auto missing = run_cli("info " + (dir / "nothere.tif"));
    CHECK(missing.exit_code != 0);
    CHECK(count_lines(missing.err) == 1);
    CHECK(missing.err.find("nothere.tif: file not found") != std::string::npos);
    CHECK(missing.out.empty());

    const auto bad = run_cli("synth --quiet --out " + (dir / "town") + " --size-m 1");
    CHECK(bad.exit_code != 0);
    CHECK(count_lines(bad.err) == 1);
    CHECK(bad.err.find("--size-m") != std::string::npos);
    CHECK(dir.file_count() == 0);
}

TEST_CASE("cityforge synth writes the town - --quiet keeps stderr empty", "[cli]") {
    ScratchDir dir("cli_synth");
    const auto r = run_cli("synth --quiet --out " + (dir / "town") + " --size-m 60 --cloud-density 1 --seed 5 --epsg 32631 --origin 300000 5000000");
    REQUIRE(r.exit_code == 0);
    CHECK(r.err.empty());
    const auto info = run_cli("info --json " + (dir / "town/ortho.tif"));
    const auto doc = nlohmann::json::parse(info.out);
    CHECK(doc["crs"]["epsg"] == 32631);
    CHECK(doc["extent"]["min_x"].get<double>() == Approx(300000.0));
    CHECK(doc["bands"].size() == 3);
}

TEST_CASE("cityforge footprints refuses a misaligned nDSM - segments on another grid - a missing segments level in one line", "[cli][errors]") {
    ScratchDir dir("cli_fp_err");
    const std::string pan = shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif");
    // The panchromatic tile as its own "nDSM" over Delft's cloud CRS would be
    // mismatched; over itself shifted by a fraction of a pixel it is misaligned.
    const auto shifted = run_command("gdal_translate -q -a_ullr 733601.2 3725139 733826.2 3724689 " + pan + " " + (dir / "shifted.tif"));
    REQUIRE(shifted.exit_code == 0);
    const auto bad = run_cli("footprints --quiet --ortho " + pan + " --ndsm " + (dir / "shifted.tif") + " --out " + (dir / "fp.gpkg"));
    CHECK(bad.exit_code == 1);
    CHECK(count_lines(bad.err) == 1);
    CHECK(bad.err.find("shifted.tif: the nDSM's pixels are not aligned with the ortho's") != std::string::npos);
    const auto mode = run_cli("footprints --quiet --ortho " + pan + " --mode cloud_only --out " + (dir / "fp.gpkg"));
    CHECK(mode.exit_code == 1);
    CHECK(mode.err.find("--mode: cloud_only needs a point cloud") != std::string::npos);
    const auto segs = run_cli("footprints --quiet --ortho " + pan + " --segments " + dir.path.string() + " --out " + (dir / "fp.gpkg"));
    CHECK(segs.exit_code == 1);
    CHECK(segs.err.find("no segments_scale_30.tif for --segment-scale; levels here: none") != std::string::npos);
    REQUIRE(run_command("gdal_translate -q -srcwin 0 0 100 100 " + pan + " " + (dir / "small.tif")).exit_code == 0);
    const auto grid = run_cli("footprints --quiet --ortho " + pan + " --segments " + (dir / "small.tif") + " --out " + (dir / "fp.gpkg"));
    CHECK(grid.exit_code == 1);
    CHECK(grid.err.find("small.tif: segments are not on the ortho's grid (100 x 100 vs 450 x 900)") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "fp.gpkg"));
}
