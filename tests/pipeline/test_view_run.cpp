// The viewer page of a run, opened from disk in Debian's headless Chromium
// (tools/validators/view_check.mjs): no console error, every building drawn on
// the map and in 3D, a clicked building shows its id and height, a screenshot
// under the test's output folder (build/test_output/viewer/).
#include <catch2/catch.hpp>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "core/error.hpp"
#include "io/vector.hpp"
#include "pipeline/view_run.hpp"
#include "synth_fixture.hpp"

using namespace cityforge;
using test::ScratchDir;
namespace fs = std::filesystem;

namespace {

std::string output_folder(const std::string& name) {
    const fs::path p = fs::current_path() / "test_output" / name;
    fs::create_directories(p);
    return p.string();
}

}  // namespace

TEST_CASE("The run's viewer page works in headless Chromium from disk", "[view][browser]") {
    ScratchDir dir("view_run");
    const SynthResult town = test::make_town(dir, 220, 11, 8);
    const auto run = test::run_cli("run --quiet --ortho " + town.ortho_path + " --cloud " + town.cloud_path + " --tile-size 300 --out " +
                                   (dir / "run") + " --formats gpkg,gltf,3dtiles");
    INFO(run.err);
    REQUIRE(run.exit_code == 0);
    REQUIRE(test::run_cli("audit footprints --quiet --pred " + (dir / "run/buildings.gpkg") + " --ref " + town.truth_path + " --out " +
                          (dir / "run/audit_footprints"))
                .exit_code == 0);
    // `run` wrote the page; `view` refuses to replace it without --overwrite, then writes it with the audit.
    REQUIRE(fs::exists(dir / "run/view/index.html"));
    const auto again = test::run_cli("view " + (dir / "run"));
    CHECK(again.exit_code == 1);
    CHECK(again.err.find("exists (use --overwrite") != std::string::npos);
    const auto view = test::run_cli("view --quiet --overwrite " + (dir / "run"));
    CHECK(view.exit_code == 0);
    ViewOptions vo;
    vo.overwrite = true;
    const ViewReport rep = write_view(dir / "run", vo);
    CHECK(rep.ortho);
    CHECK(rep.audits == 1);
    const PolygonLayer model = read_polygon_layer(dir / "run/buildings.gpkg");
    REQUIRE(rep.buildings == model.features.size());
    REQUIRE(rep.buildings > 10);

    // A known building: the tallest (for the 3D click: nothing stands in front of its roof), and a middle one for the map.
    int id_f = -1, h_f = -1;
    for (std::size_t k = 0; k < model.field_names.size(); ++k) {
        if (model.field_names[k] == "cityforge_id") id_f = int(k);
        if (model.field_names[k] == "height_m") h_f = int(k);
    }
    REQUIRE(id_f >= 0);
    REQUIRE(h_f >= 0);
    std::size_t tallest = 0;
    for (std::size_t i = 0; i < model.features.size(); ++i)
        if (std::get<double>(model.features[i].values[h_f]) > std::get<double>(model.features[tallest].values[h_f])) tallest = i;
    const std::size_t known = model.features.size() / 2;
    const std::string known_id = std::get<std::string>(model.features[known].values[id_f]);
    const double known_height = std::get<double>(model.features[known].values[h_f]);
    const std::string tall_id = std::get<std::string>(model.features[tallest].values[id_f]);

    const std::string out = output_folder("viewer");
    char height[32];
    std::snprintf(height, sizeof height, "%.3f", known_height);
    const auto check = test::run_command("node " + test::source_dir() + "/tools/validators/view_check.mjs " + rep.path + " " + out +
                                         " --expect-buildings " + std::to_string(rep.buildings) + " --expect-meshed " +
                                         std::to_string(rep.meshed) + " --click-id " + known_id + " --expect-height " + height +
                                         " --click3d-id " + tall_id);
    INFO(check.out << check.err);
    CHECK(check.exit_code == 0);
    const auto summary = nlohmann::json::parse(check.out);
    CHECK(summary["failures"].empty());
    CHECK(summary["drawn_map"] == rep.buildings);
    CHECK(summary["drawn_3d"] == rep.meshed);
    CHECK(rep.meshed == rep.buildings);
    CHECK(fs::file_size(fs::path(out) / "viewer.png") > 10000);

    // The page is self-contained: no link off the disk.
    const std::string page = test::slurp(rep.path);
    CHECK(page.find("src=\"http") == std::string::npos);
    CHECK(page.find("href=\"http") == std::string::npos);
    CHECK(page.find("cityforge-glb") != std::string::npos);
}

TEST_CASE("view refuses folders without buildings and existing pages", "[view]") {
    ScratchDir dir("view_errors");
    CHECK_THROWS_WITH(write_view(dir / "missing"), Catch::Contains("not a folder"));
    fs::create_directories(dir / "empty");
    CHECK_THROWS_WITH(write_view(dir / "empty"), Catch::Contains("no buildings.gpkg"));
}
