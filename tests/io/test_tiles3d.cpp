// 3D Tiles 1.1 and glTF 2.0 export: validated by the Khronos glTF validator
// and the tileset checks of tools/validators/validate_3dtiles.mjs, placed in
// ECEF as PROJ's cs2cs places them, deterministic, refused without solids.
#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "core/error.hpp"
#include "crs/crs.hpp"
#include "io/tiles3d_writer.hpp"
#include "io/vector.hpp"
#include "pipeline/export_run.hpp"
#include "pipeline/roofs_run.hpp"
#include "raster/raster.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;
using test::shared_data;
namespace fs = std::filesystem;

namespace {

const std::string kDelftFootprints = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
const std::string kDelftCloud = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");

test::CommandResult validate(const std::string& mode, const std::string& file, int expect_buildings) {
    return test::run_command("node " + test::source_dir() + "/tools/validators/validate_3dtiles.mjs " + mode + " " + file +
                             " --expect-buildings " + std::to_string(expect_buildings));
}

// The Delft BGT footprints (written by GDAL from 3dfier's data) with their reference heights, in RD New + NAP.
CityModel delft_model(CrsInfo& crs) {
    const PolygonLayer layer = read_polygon_layer(kDelftFootprints);
    crs = combine_with_vertical(layer.crs, crs_from_user_input("EPSG:5709", "test"));
    ExportOptions o;
    o.id_field = "gml_id", o.ground_field = "ref_ground_nap_m", o.height_field = "ref_height_m";
    return build_city_model(layer, crs, o, kDelftFootprints);
}

struct Glb {
    nlohmann::json json;
    std::string bin;
};
Glb read_glb(const std::string& path) {
    const std::string b = test::slurp(path);
    uint32_t jlen = 0, blen = 0;
    std::memcpy(&jlen, b.data() + 12, 4);
    std::memcpy(&blen, b.data() + 20 + jlen, 4);
    return {nlohmann::json::parse(b.substr(20, jlen)), b.substr(28 + jlen, blen)};
}

// First vertex of the first primitive, in ECEF (node translation added, y-up turned to z-up).
std::array<double, 3> first_vertex_ecef(const Glb& g) {
    const auto& acc = g.json["accessors"][g.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"].get<int>()];
    const auto& view = g.json["bufferViews"][acc["bufferView"].get<int>()];
    float p[3];
    std::memcpy(p, g.bin.data() + view["byteOffset"].get<std::size_t>(), 12);
    const auto t = g.json["nodes"][0]["translation"];
    const double x = p[0] + t[0].get<double>(), y = p[1] + t[1].get<double>(), z = p[2] + t[2].get<double>();
    return {x, -z, y};
}

// Accessor `index` of a glb as floats (FLOAT) or as indices (UNSIGNED_INT), tightly packed.
std::vector<float> accessor_floats(const Glb& g, int index) {
    const auto& a = g.json["accessors"][index];
    REQUIRE(a["componentType"] == 5126);
    const std::size_t comps = a["type"] == "VEC3" ? 3 : a["type"] == "VEC2" ? 2 : 1;
    const auto& v = g.json["bufferViews"][a["bufferView"].get<int>()];
    std::vector<float> out(a["count"].get<std::size_t>() * comps);
    std::memcpy(out.data(), g.bin.data() + v["byteOffset"].get<std::size_t>(), out.size() * 4);
    return out;
}
std::vector<uint32_t> accessor_indices(const Glb& g, int index) {
    const auto& a = g.json["accessors"][index];
    REQUIRE(a["componentType"] == 5125);
    const auto& v = g.json["bufferViews"][a["bufferView"].get<int>()];
    std::vector<uint32_t> out(a["count"].get<std::size_t>());
    std::memcpy(out.data(), g.bin.data() + v["byteOffset"].get<std::size_t>(), out.size() * 4);
    return out;
}

}  // namespace

TEST_CASE("3D Tiles and glTF of real LOD2 roofs pass the validators with zero errors", "[3dtiles][gltf][real]") {
    ScratchDir dir("tiles3d_delft");
    const auto r = test::run_cli("roofs --quiet --footprints " + kDelftFootprints + " --cloud " + kDelftCloud +
                                 " --cloud-crs EPSG:7415 --id-field gml_id --formats gpkg,3dtiles,gltf --out " + dir / "out");
    REQUIRE(r.exit_code == 0);
    const auto ts = validate("tileset", dir / "out/3dtiles/tileset.json", 135);
    INFO(ts.out << ts.err);
    CHECK(ts.exit_code == 0);
    const auto summary = nlohmann::json::parse(ts.out);
    CHECK(summary["errors"].empty());
    CHECK(summary["buildings"] == 135);
    const auto glb = validate("glb", dir / "out/buildings.glb", 135);
    INFO(glb.out << glb.err);
    CHECK(glb.exit_code == 0);
    CHECK(nlohmann::json::parse(glb.out)["gltf_errors"] == 0);
    // LOD2: the glb has roof, wall and ground primitives and says which LOD each building shows.
    const Glb g = read_glb(dir / "out/buildings.glb");
    CHECK(g.json["meshes"][0]["primitives"].size() == 3);
    CHECK(g.json["asset"]["extras"]["crs"] == "EPSG:28992+5709");
    CHECK(g.json["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["count"] == 135);
    // The LOD named as CityJSON and 3DBAG name it: the first building shows its roof planes, "2.2".
    const auto& lod_view = g.json["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["properties"]["lod"];
    const auto& lod_values = g.json["bufferViews"][lod_view["values"].get<int>()];
    const auto& lod_offsets = g.json["bufferViews"][lod_view["stringOffsets"].get<int>()];
    uint32_t lod_end0 = 0;
    std::memcpy(&lod_end0, g.bin.data() + lod_offsets["byteOffset"].get<std::size_t>() + 4, 4);
    CHECK(g.bin.substr(lod_values["byteOffset"].get<std::size_t>(), lod_end0) == "2.2");
}

TEST_CASE("3D Tiles quadtree: deeper tiles, falling errors, ECEF as cs2cs, same bytes twice", "[3dtiles]") {
    CrsInfo crs;
    const CityModel model = delft_model(crs);
    REQUIRE(model.buildings.size() == 135);
    ScratchDir dir("tiles3d_tree");
    Tiles3dWriteOptions o;
    o.max_buildings_per_tile = 10;
    const Tiles3dWriteReport rep = write_3dtiles(dir / "a", model, crs, o);
    CHECK(rep.buildings == 135);
    CHECK(rep.depth >= 2);
    CHECK(rep.content_tiles >= 14);
    const auto ts = validate("tileset", dir / "a/tileset.json", 135);
    INFO(ts.out << ts.err);
    CHECK(ts.exit_code == 0);
    CHECK(nlohmann::json::parse(ts.out)["depth"] == rep.depth);

    // Geometric errors fall with depth; leaves (with content) are exact.
    const auto tileset = nlohmann::json::parse(test::slurp(dir / "a/tileset.json"));
    CHECK(tileset["asset"]["version"] == "1.1");
    std::function<void(const nlohmann::json&, double)> walk = [&](const nlohmann::json& t, double parent) {
        CHECK(t["geometricError"].get<double>() < parent);
        if (t.contains("content")) CHECK(t["geometricError"].get<double>() == 0.0);
        if (t.contains("children"))
            for (const auto& c : t["children"]) walk(c, t["geometricError"].get<double>() + (t["geometricError"] == 0 ? 1e-9 : 0));
    };
    walk(tileset["root"], tileset["geometricError"].get<double>() + 1e-9);

    // A vertex lands where PROJ's cs2cs (an independent program) puts the model point. PROJ here has no NAP
    // geoid grid: the tiles take NAP heights as ellipsoidal heights on the proper horizontal datum shift
    // (Amersfoort to WGS 84, 1 m), as cs2cs does from EPSG:28992. From EPSG:7415 cs2cs would fall back to
    // PROJ's "ballpark geographic offset" (no datum shift at all): about 100 m off.
    // In each tile, the first vertex against cs2cs of the same model point.
    bool compared = false;
    for (const auto& e : fs::directory_iterator(fs::path(dir.path) / "a" / "content")) {
        const Glb g = read_glb(e.path().string());
        // Feature 0 of the first primitive is the tile's first building; its first vertex is its first ground/wall vertex.
        const auto v = first_vertex_ecef(g);
        CHECK(std::hypot(v[0], v[1], v[2]) > 6.36e6);
        if (compared) continue;
        // The first primitive is the ground (every LOD1 prism has one): its first vertex is the first outer
        // footprint vertex of the tile's first building at ground_z.
        const auto& ids_view = g.json["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["properties"]["id"];
        const auto& bv_values = g.json["bufferViews"][ids_view["values"].get<int>()];
        const auto& bv_offsets = g.json["bufferViews"][ids_view["stringOffsets"].get<int>()];
        uint32_t end0 = 0;
        std::memcpy(&end0, g.bin.data() + bv_offsets["byteOffset"].get<std::size_t>() + 4, 4);
        const std::string id0 = g.bin.substr(bv_values["byteOffset"].get<std::size_t>(), end0);
        const Building* tb = nullptr;
        for (const Building& c : model.buildings)
            if (c.id == id0) tb = &c;
        REQUIRE(tb);
        const Face& ground = tb->lod1.front().faces.front();
        REQUIRE(ground.type == SurfaceType::ground);
        const Point3 p = ground.outer.front();
        char line[128];
        std::snprintf(line, sizeof line, "%.4f %.4f %.4f\n", p.x, p.y, p.z);
        std::ofstream(dir / "point.txt") << line;
        const auto cs = test::run_command("cs2cs -f %.4f EPSG:28992 EPSG:4978 " + dir / "point.txt");
        REQUIRE(cs.exit_code == 0);
        double X = 0, Y = 0, Z = 0;
        REQUIRE(std::sscanf(cs.out.c_str(), "%lf %lf %lf", &X, &Y, &Z) == 3);
        CHECK(std::hypot(v[0] - X, v[1] - Y, v[2] - Z) < 0.02);
        compared = true;
    }
    CHECK(compared);

    // Same model, same options: same bytes.
    write_3dtiles(dir / "b", model, crs, o);
    CHECK(test::slurp(dir / "a/tileset.json") == test::slurp(dir / "b/tileset.json"));
    for (const auto& e : fs::directory_iterator(fs::path(dir.path) / "a" / "content"))
        CHECK(test::slurp(e.path().string()) == test::slurp((fs::path(dir.path) / "b" / "content" / e.path().filename()).string()));
}

TEST_CASE("3D Tiles refuse a model without solids and leave nothing behind", "[3dtiles]") {
    CrsInfo crs;
    CityModel model = delft_model(crs);
    for (Building& b : model.buildings) b.lod1.clear(), b.lod2.clear();
    ScratchDir dir("tiles3d_empty");
    CHECK_THROWS_WITH(write_3dtiles(dir / "t", model, crs), Catch::Contains("no building has a LOD1 or LOD2 solid"));
    CHECK_THROWS_AS(write_glb(dir / "b.glb", model), Error);
    CHECK(dir.file_count() == 0);
    const auto r = test::run_cli("export --quiet --in " + kDelftFootprints + " --formats 3dtiles --out " + dir / "x");
    CHECK(r.exit_code == 1);
    CHECK(r.err.find(kDelftFootprints + ": no building has a height") != std::string::npos);  // the input, refused before writing
    CHECK(dir.file_count() == 0);
}

TEST_CASE("3D Tiles with roof textures: each tile's atlas holds the ortho's pixels under its roofs, zero validator errors", "[3dtiles][gltf][texture]") {
    ScratchDir dir("tiles3d_textured");
    const SynthResult town = test::make_town(dir, 220, 11, 8);
    RoofsRunOptions o;
    o.model.formats = {"3dtiles", "cityjson"};
    o.model.texture_ortho = town.ortho_path;
    o.model.tiles.max_buildings_per_tile = 6;  // several tiles, each with its own atlas
    const RoofsRunReport rep = run_roofs(town.truth_path, town.cloud_path, dir / "out", o);
    REQUIRE(rep.model.files.count("textures"));
    const auto ts = validate("tileset", dir / "out/3dtiles/tileset.json", int(rep.model.buildings));
    INFO(ts.out << ts.err);
    CHECK(ts.exit_code == 0);  // the Khronos glTF validator on every tile (textures included) and the tileset checks
    CHECK(nlohmann::json::parse(ts.out)["errors"].empty());

    // Every sample point inside a textured roof triangle: its ECEF position (node translation, y-up -> z-up)
    // back to the model CRS through PROJ, then the ortho pixel there (GDAL) against the tile atlas pixel at
    // its interpolated (u, v) (glTF: v down from the top). Both 8-bit RGB.
    const RasterReader ortho(town.ortho_path);
    const GeoTransform& gt = ortho.info().transform;
    const CrsInfo ecef = crs_from_user_input("EPSG:4978", "test");
    RasterOpenOptions plain;
    plain.allow_pixel_coordinates = true;
    int tiles = 0, textured_tiles = 0;
    std::size_t samples = 0, same = 0, atlas_px = 0;
    for (const auto& e : fs::directory_iterator(fs::path(dir.path) / "out/3dtiles/content")) {
        ++tiles;
        const Glb g = read_glb(e.path().string());
        if (!g.json.contains("images")) continue;
        ++textured_tiles;
        REQUIRE(g.json["images"].size() == 1);
        const auto& iv = g.json["bufferViews"][g.json["images"][0]["bufferView"].get<int>()];
        const fs::path png = fs::path(dir.path) / (e.path().stem().string() + ".png");
        std::ofstream(png, std::ios::binary) << g.bin.substr(iv["byteOffset"].get<std::size_t>(), iv["byteLength"].get<std::size_t>());
        const auto atlas = RasterReader(png.string(), plain).read_all<uint8_t>();
        atlas_px += std::size_t(atlas.width) * atlas.height;
        const auto& t = g.json["nodes"][0]["translation"];
        for (const auto& prim : g.json["meshes"][0]["primitives"]) {
            const auto& mat = g.json["materials"][prim["material"].get<int>()];
            if (!mat["pbrMetallicRoughness"].contains("baseColorTexture")) continue;
            const auto pos = accessor_floats(g, prim["attributes"]["POSITION"].get<int>());
            const auto uv = accessor_floats(g, prim["attributes"]["TEXCOORD_0"].get<int>());
            const auto idx = accessor_indices(g, prim["indices"].get<int>());
            std::vector<double> X, Y, Z, U, V;
            for (std::size_t k = 0; k + 2 < idx.size(); k += 3)
                for (const auto& w : std::vector<std::array<double, 3>>{{0.6, 0.2, 0.2}, {0.2, 0.6, 0.2}, {0.2, 0.2, 0.6}, {0.34, 0.33, 0.33}}) {
                    double p[3] = {0, 0, 0}, q[2] = {0, 0};
                    for (int c = 0; c < 3; ++c) {
                        const uint32_t i = idx[k + std::size_t(c)];
                        for (int d = 0; d < 3; ++d) p[d] += w[c] * pos[3 * i + std::size_t(d)];
                        for (int d = 0; d < 2; ++d) q[d] += w[c] * uv[2 * i + std::size_t(d)];
                    }
                    const double x = p[0] + t[0].get<double>(), y = p[1] + t[1].get<double>(), z = p[2] + t[2].get<double>();
                    X.push_back(x), Y.push_back(-z), Z.push_back(y), U.push_back(q[0]), V.push_back(q[1]);
                }
            transform_points(ecef, ortho.info().crs, X, Y, Z, "test");
            for (std::size_t k = 0; k < X.size(); ++k) {
                const PixelPoint op = gt.map_to_pixel({X[k], Y[k]});
                const double ac = U[k] * atlas.width, ar = V[k] * atlas.height;
                // Points on a pixel boundary (either image) are skipped: which pixel they are in is a matter of rounding.
                auto near_edge = [](double v) { return std::abs(v - std::round(v)) < 0.02; };
                if (near_edge(op.col) || near_edge(op.row) || near_edge(ac) || near_edge(ar)) continue;
                const auto o_px = ortho.read<uint8_t>({int(std::floor(op.col)), int(std::floor(op.row)), 1, 1}, {1, 2, 3});
                bool equal = true;
                for (int b = 0; b < 3; ++b) equal = equal && atlas.at(b, int(std::floor(ac)), int(std::floor(ar))) == o_px.at(b, 0, 0);
                ++samples, same += equal;
            }
        }
    }
    INFO(tiles << " tiles, " << textured_tiles << " textured, " << samples << " samples");
    CHECK(tiles >= 4);
    CHECK(textured_tiles == tiles);
    CHECK(samples >= 200);
    CHECK(same == samples);
    // Each tile carries only its own buildings' roofs: together about the model's atlas, not a copy per tile.
    const auto full = RasterReader(rep.model.files.at("textures"), plain).info();
    CHECK(atlas_px < std::size_t(2 * full.width * full.height));

    // Same input, same tiles (atlases included).
    o.model.formats = {"3dtiles"};
    run_roofs(town.truth_path, town.cloud_path, dir / "again", o);
    for (const auto& e : fs::directory_iterator(fs::path(dir.path) / "out/3dtiles/content"))
        CHECK(test::slurp(e.path().string()) == test::slurp((fs::path(dir.path) / "again/3dtiles/content" / e.path().filename()).string()));
}
