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
#include "raster/raster.hpp"
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
                                   (dir / "run") + " --formats gpkg,gltf,3dtiles,cityjson --texture-ortho " + town.ortho_path);
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
                                         " --click3d-id " + tall_id + " --expect-textured");
    INFO(check.out << check.err);
    CHECK(check.exit_code == 0);
    const auto summary = nlohmann::json::parse(check.out);
    CHECK(summary["failures"].empty());
    CHECK(summary["drawn_map"] == rep.buildings);
    CHECK(summary["drawn_3d"] == rep.meshed);
    CHECK(rep.meshed == rep.buildings);
    CHECK(fs::file_size(fs::path(out) / "viewer.png") > 10000);
    CHECK(summary["textured_meshes"].get<int>() >= 1);
    // The textured glb (roofs: baseColorTexture from the atlas) has zero errors by the Khronos glTF validator.
    const auto gv = test::run_command("node " + test::source_dir() + "/tools/validators/validate_3dtiles.mjs glb " + (dir / "run/buildings.glb") +
                                      " --expect-buildings " + std::to_string(rep.meshed));
    INFO(gv.out << gv.err);
    CHECK(gv.exit_code == 0);
    CHECK(gv.out.find("\"errors\": []") != std::string::npos);

    // The run's 3D Tiles carry the same roof textures (an atlas per tile): zero errors by the glTF validator on
    // every tile and by the tileset checks, and the page shows them textured from the tileset as well.
    const auto tv = test::run_command("node " + test::source_dir() + "/tools/validators/validate_3dtiles.mjs tileset " +
                                      (dir / "run/3dtiles/tileset.json") + " --expect-buildings " + std::to_string(rep.meshed));
    INFO(tv.out << tv.err);
    CHECK(tv.exit_code == 0);
    CHECK(tv.out.find("\"errors\": []") != std::string::npos);
    const auto textured_tiles = test::run_command("node " + test::source_dir() + "/tools/validators/view_check.mjs " + rep.path + " " +
                                                  output_folder("viewer_textured_tiles") + " --source tiles --expect-meshed " +
                                                  std::to_string(rep.meshed) + " --expect-textured");
    INFO(textured_tiles.out << textured_tiles.err);
    CHECK(textured_tiles.exit_code == 0);
    const auto tts = nlohmann::json::parse(textured_tiles.out);
    CHECK(tts["source"] == "tiles");
    CHECK(tts["textured_meshes"].get<int>() >= 1);
    CHECK(tts["drawn_3d"] == rep.meshed);

    // The page shows the 3D Tiles tileset too (tiles.js beside it): here one written with small leaves, so that
    // several tiles stream in; every tile loaded, every building drawn where the glb draws it, and clickable.
    CHECK(rep.tiles >= 1);
    CHECK(fs::exists(fs::path(rep.path).parent_path() / "tiles.js"));
    REQUIRE(test::run_cli("export --quiet --in " + (dir / "run/buildings.gpkg") + " --id-field cityforge_id --formats 3dtiles --tile-buildings 4 --out " +
                          (dir / "small_tiles"))
                .exit_code == 0);
    ViewOptions vt;
    vt.overwrite = true, vt.tileset = dir / "small_tiles/3dtiles/tileset.json", vt.out = dir / "run/view_tiles/index.html";
    const ViewReport trep = write_view(dir / "run", vt);
    REQUIRE(trep.tiles >= 4);
    const std::string out_tiles = output_folder("viewer_tiles");
    const auto tiles = test::run_command("node " + test::source_dir() + "/tools/validators/view_check.mjs " + trep.path + " " + out_tiles +
                                         " --source tiles --expect-buildings " + std::to_string(rep.buildings) + " --expect-meshed " +
                                         std::to_string(rep.meshed) + " --click3d-id " + tall_id);
    INFO(tiles.out << tiles.err);
    CHECK(tiles.exit_code == 0);
    const auto ts = nlohmann::json::parse(tiles.out);
    CHECK(ts["source"] == "tiles");
    CHECK(ts["tiles"]["loaded"] == trep.tiles);
    CHECK(ts["drawn_3d"] == rep.meshed);
    CHECK(ts["scene_click"]["id"] == tall_id);
    // Tiles (ECEF, LOD1 from the table) and glb (model CRS, LOD2) land in the same place: same plan extent to 5 cm.
    for (int k : {0, 2, 3, 5}) CHECK(ts["box"][k].get<double>() == Approx(summary["box"][k].get<double>()).margin(0.05));

    // Roof textures: a roof's texture pixels are the ortho's pixels under it. Points inside roof triangles of
    // the LOD2.2 parts, their (u, v) interpolated from the CityJSON vertices-texture, read in the atlas; the
    // ortho read through GDAL at their map x, y. Both images hold 8-bit RGB.
    {
        const auto cj = nlohmann::json::parse(test::slurp(dir / "run/buildings.city.json"));
        REQUIRE(cj.contains("appearance"));
        const auto& app = cj["appearance"];
        REQUIRE(app["textures"].size() == 1);
        CHECK(app["textures"][0]["image"] == "textures/roofs.png");
        RasterOpenOptions plain;
        plain.allow_pixel_coordinates = true;
        const RasterReader atlas((dir / "run/textures/roofs.png"), plain);
        const RasterReader ortho(town.ortho_path);
        const auto a_img = atlas.read_all<uint8_t>();
        const GeoTransform& gt = ortho.info().transform;
        const auto& t = cj["transform"];
        auto vertex = [&](std::size_t i) {
            const auto& v = cj["vertices"][i];
            return std::array<double, 2>{v[0].get<double>() * t["scale"][0].get<double>() + t["translate"][0].get<double>(),
                                         v[1].get<double>() * t["scale"][1].get<double>() + t["translate"][1].get<double>()};
        };
        std::size_t textured = 0, samples = 0, same = 0;
        for (const auto& [id, o] : cj["CityObjects"].items()) {
            if (o["type"] != "BuildingPart") continue;
            for (const auto& g : o["geometry"]) {
                if (g["lod"] != "2.2" || !g.contains("texture")) continue;
                ++textured;
                const auto& shell = g["boundaries"][0];
                const auto& tex = g["texture"]["ortho"]["values"][0];
                for (std::size_t f = 0; f < shell.size(); ++f) {
                    if (tex[f][0][0].is_null()) continue;
                    const auto& ring = shell[f][0];
                    const auto& uvi = tex[f][0];
                    REQUIRE(uvi.size() == ring.size() + 1);
                    // Points of a fan from the first vertex (inside the face's convex hull, so under its window).
                    for (std::size_t k = 1; k + 1 < ring.size(); ++k)
                        for (const auto& w : std::vector<std::array<double, 3>>{{0.6, 0.2, 0.2}, {0.2, 0.6, 0.2}, {0.2, 0.2, 0.6}, {0.34, 0.33, 0.33}}) {
                            const std::size_t vi[3] = {ring[0].get<std::size_t>(), ring[k].get<std::size_t>(), ring[k + 1].get<std::size_t>()};
                            const std::size_t ti[3] = {uvi[1].get<std::size_t>(), uvi[k + 1].get<std::size_t>(), uvi[k + 2].get<std::size_t>()};
                            double x = 0, y = 0, u = 0, v = 0;
                            for (int c = 0; c < 3; ++c) {
                                const auto p = vertex(vi[c]);
                                x += w[c] * p[0], y += w[c] * p[1];
                                u += w[c] * app["vertices-texture"][ti[c]][0].get<double>(), v += w[c] * app["vertices-texture"][ti[c]][1].get<double>();
                            }
                            const PixelPoint op = gt.map_to_pixel({x, y});
                            const double ac = u * a_img.width, ar = (1.0 - v) * a_img.height;  // CityJSON: v up from the bottom
                            // Skip points on a pixel boundary (either image): which pixel they are in is a matter of rounding.
                            auto near_edge = [](double q) { return std::abs(q - std::round(q)) < 0.02; };
                            if (near_edge(op.col) || near_edge(op.row) || near_edge(ac) || near_edge(ar)) continue;
                            const auto o_px = ortho.read<uint8_t>({int(std::floor(op.col)), int(std::floor(op.row)), 1, 1}, {1, 2, 3});
                            bool equal = true;
                            for (int b = 0; b < 3; ++b) equal = equal && a_img.at(b, int(std::floor(ac)), int(std::floor(ar))) == o_px.at(b, 0, 0);
                            ++samples, same += equal;
                        }
                }
            }
        }
        INFO(textured << " textured roof parts, " << samples << " samples");
        CHECK(textured >= 5);
        CHECK(samples >= 100);
        CHECK(same == samples);
    }

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
