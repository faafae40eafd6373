// Property: `cityforge run` gives the same bytes for any tile size, overlap
// and thread count, also for buildings larger than a tile and than the
// overlap (they are done again on a window grown around them).
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "synth/synth.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;

namespace {

struct Tiling {
    int tile_px;
    double overlap_m;
    int threads;
};

// The largest building edge of the truth, metres.
double largest_building_m(const std::string& truth_path) {
    const auto truth = nlohmann::json::parse(test::slurp(truth_path));
    double largest = 0;
    for (const auto& f : truth["features"]) {
        double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
        for (const auto& ring : f["geometry"]["coordinates"])
            for (const auto& p : ring) {
                x0 = std::min(x0, p[0].get<double>()), x1 = std::max(x1, p[0].get<double>());
                y0 = std::min(y0, p[1].get<double>()), y1 = std::max(y1, p[1].get<double>());
            }
        largest = std::max({largest, x1 - x0, y1 - y0});
    }
    return largest;
}

void check_tilings(const ScratchDir& dir, const std::string& name, const SynthOptions& so, const std::string& extra,
                   const std::vector<Tiling>& tilings) {
    const SynthResult s = write_synthetic_town(dir / name, so);
    const std::string common = "--ortho " + s.ortho_path + " --cloud " + s.cloud_path + " --formats geojson,cityjson --quiet " + extra;
    const std::string ref = dir / (name + "_ref");
    const auto one = test::run_cli("run " + common + " --tile-size 4000 --threads 2 --out " + ref);
    INFO(one.err);
    REQUIRE(one.exit_code == 0);
    const std::string ref_geojson = test::slurp(ref + "/buildings.geojson"), ref_city = test::slurp(ref + "/buildings.city.json");
    REQUIRE(ref_geojson.size() > 1000);
    // The property is only worth checking where buildings are larger than the tiles.
    const double gsd = so.gsd_m;
    bool smaller_than_building = false;
    std::size_t grown = 0;
    for (const Tiling& t : tilings) {
        smaller_than_building = smaller_than_building || t.tile_px * gsd < largest_building_m(s.truth_path);
        const std::string out = dir / (name + "_" + std::to_string(t.tile_px) + "_" + std::to_string(t.threads));
        const auto r = test::run_cli("run " + common + " --tile-size " + std::to_string(t.tile_px) + " --overlap-m " +
                                     std::to_string(t.overlap_m) + " --threads " + std::to_string(t.threads) + " --out " + out);
        INFO(name << ": tile " << t.tile_px << " px, overlap " << t.overlap_m << " m, " << t.threads << " threads\n" << r.err);
        REQUIRE(r.exit_code == 0);
        CHECK(test::slurp(out + "/buildings.geojson") == ref_geojson);
        CHECK(test::slurp(out + "/buildings.city.json") == ref_city);
        const auto report = nlohmann::json::parse(test::slurp(out + "/run_report.json"));
        for (const auto& tile : report["tiles"]) grown += tile["grown"].get<std::size_t>();
    }
    CHECK(smaller_than_building);
    CHECK(grown > 0);  // some buildings left their tile's window and were done on a grown one
}

}  // namespace

TEST_CASE("run: the same bytes for any tiling, buildings larger than a tile and the overlap included", "[run][tiles]") {
    ScratchDir dir("tile_invariance");
    SECTION("lidar town, ortho + cloud, classified cloud") {
        SynthOptions so;
        so.size_m = 200, so.seed = 7, so.cloud_density_m2 = 4;
        // Prime tile sizes (33.5 and 50.5 m; its largest building is 73 m long), overlaps below the context.
        check_tilings(dir, "lidar", so, "", {{67, 0.0, 1}, {101, 12.0, 2}});
    }
    SECTION("terraced town: rows of touching houses cut at their roof seams across tiles") {
        SynthOptions so;
        so.size_m = 200, so.seed = 7, so.cloud_density_m2 = 8;
        so.variation.terraced_block_share = 0.6;
        // Tiles of 33.5 and 50.5 m; terrace rows run up to 70 m, one building is 73 m long.
        check_tilings(dir, "terraces", so, "", {{67, 0.0, 1}, {101, 12.0, 2}});
        // The seams did cut: more buildings than with them off (26 against 14 on the truth's 32).
        {
            std::ofstream cfg(dir / "no_seams.json");
            cfg << R"({"extraction": {"roof_seams": false}})";
        }
        const std::string common = "--ortho " + (dir / "terraces/ortho.tif") + " --cloud " + (dir / "terraces/cloud.las") + " --formats geojson --quiet";
        const auto off = test::run_cli("run " + common + " --tile-size 4000 --config " + (dir / "no_seams.json") + " --out " + (dir / "terraces_off"));
        REQUIRE(off.exit_code == 0);
        auto count = [](const std::string& path) { return nlohmann::json::parse(test::slurp(path))["features"].size(); };
        CHECK(count(dir / "terraces_ref/buildings.geojson") > count(dir / "terraces_off/buildings.geojson"));
    }
    SECTION("photogrammetric town, cloud only, ground recomputed (SMRF)") {
        SynthOptions so;
        so.size_m = 160, so.seed = 7, so.cloud_density_m2 = 4, so.cloud_mode = CloudMode::photo;
        {
            std::ofstream cfg(dir / "cloud_only.json");
            cfg << R"({"extraction": {"mode": "cloud_only"}, "cleaning": {"recompute_ground": true}})";
        }
        check_tilings(dir, "photo", so, "--config " + (dir / "cloud_only.json"), {{71, 0.0, 2}, {97, 5.0, 1}});
    }
}
