#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "test_support.hpp"

using cityforge::test::count_lines;
using cityforge::test::run_cli;
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
