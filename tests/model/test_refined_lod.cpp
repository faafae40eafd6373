// Refined LODs (LOD1.2, LOD1.3, LOD2.2 BuildingParts) on a hand-made stepped
// building with exact truth; every solid checked by validate_solid and,
// independently, by CGAL's closed-mesh predicates, in memory and as written.
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "io/citygml_writer.hpp"
#include "io/cityjson_writer.hpp"
#include "model/building_model.hpp"
#include "model/cgal_solid_check.hpp"
#include "model/refined_lod.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;

namespace {

Face face(std::initializer_list<Point3> ring, SurfaceType t) { return Face{Ring3(ring), {}, t}; }

// 20 m x 10 m on the ground (z 0): the west half a flat roof at 6 m, the east
// half a gable (eaves 9 m, ridge 11 m along y = 5), a step wall at x = 10.
Solid stepped_solid() {
    const auto R = SurfaceType::roof, W = SurfaceType::wall, G = SurfaceType::ground;
    Solid s;
    s.faces = {
        face({{0, 0, 6}, {10, 0, 6}, {10, 10, 6}, {0, 10, 6}}, R),
        face({{10, 0, 9}, {20, 0, 9}, {20, 5, 11}, {10, 5, 11}}, R),
        face({{10, 5, 11}, {20, 5, 11}, {20, 10, 9}, {10, 10, 9}}, R),
        face({{10, 10, 6}, {10, 0, 6}, {10, 0, 9}, {10, 5, 11}, {10, 10, 9}}, W),  // step
        face({{0, 10, 0}, {0, 0, 0}, {0, 0, 6}, {0, 10, 6}}, W),
        face({{0, 0, 0}, {10, 0, 0}, {10, 0, 6}, {0, 0, 6}}, W),
        face({{10, 0, 0}, {20, 0, 0}, {20, 0, 9}, {10, 0, 9}, {10, 0, 6}}, W),
        face({{20, 0, 0}, {20, 10, 0}, {20, 10, 9}, {20, 5, 11}, {20, 0, 9}}, W),
        face({{20, 10, 0}, {10, 10, 0}, {10, 10, 6}, {10, 10, 9}, {20, 10, 9}}, W),
        face({{10, 10, 0}, {0, 10, 0}, {0, 10, 6}, {10, 10, 6}}, W),
        face({{0, 0, 0}, {0, 10, 0}, {10, 10, 0}, {20, 10, 0}, {20, 0, 0}, {10, 0, 0}}, G),
    };
    return s;
}

// 20 m x 10 m: the west half a flat roof at 3 m; the east half three faces
// that join without a step except along y = 5 between x = 15 and 20, where
// the south-east face falls below the flat north face: a step that fades out
// at (15, 5) inside the part and is 1 m high at (20, 5) on its outline.
Solid fading_step_solid() {
    const auto R = SurfaceType::roof, W = SurfaceType::wall, G = SurfaceType::ground;
    Solid s;
    s.faces = {
        face({{0, 0, 3}, {10, 0, 3}, {10, 10, 3}, {0, 10, 3}}, R),
        face({{10, 0, 7}, {15, 0, 7}, {15, 5, 8}, {10, 5, 8}}, R),
        face({{15, 0, 7}, {20, 0, 6}, {20, 5, 7}, {15, 5, 8}}, R),
        face({{10, 5, 8}, {15, 5, 8}, {20, 5, 8}, {20, 10, 8}, {10, 10, 8}}, R),
        face({{10, 10, 3}, {10, 0, 3}, {10, 0, 7}, {10, 5, 8}, {10, 10, 8}}, W),  // step to the west part
        face({{15, 5, 8}, {20, 5, 7}, {20, 5, 8}}, W),                            // the fading step
        face({{0, 0, 0}, {10, 0, 0}, {10, 0, 3}, {0, 0, 3}}, W),
        face({{10, 0, 0}, {15, 0, 0}, {15, 0, 7}, {10, 0, 7}, {10, 0, 3}}, W),
        face({{15, 0, 0}, {20, 0, 0}, {20, 0, 6}, {15, 0, 7}}, W),
        face({{20, 0, 0}, {20, 5, 0}, {20, 5, 7}, {20, 0, 6}}, W),
        face({{20, 5, 0}, {20, 10, 0}, {20, 10, 8}, {20, 5, 8}, {20, 5, 7}}, W),
        face({{20, 10, 0}, {10, 10, 0}, {10, 10, 3}, {10, 10, 8}, {20, 10, 8}}, W),
        face({{10, 10, 0}, {0, 10, 0}, {0, 10, 3}, {10, 10, 3}}, W),
        face({{0, 10, 0}, {0, 0, 0}, {0, 0, 3}, {0, 10, 3}}, W),
        face({{0, 0, 0}, {0, 10, 0}, {10, 10, 0}, {20, 10, 0}, {20, 5, 0}, {20, 0, 0}, {15, 0, 0}, {10, 0, 0}}, G),
    };
    return s;
}

CityModel stepped_model() {
    CityModel m;
    m.crs.label = "EPSG:28992+5709", m.crs.horizontal_epsg = 28992, m.crs.vertical_epsg = 5709, m.crs.compound_epsg = 7415;
    Building b;
    b.id = "step";
    Polygon fp;
    for (const auto& [x, y] : std::vector<std::pair<double, double>>{{0, 0}, {20, 0}, {20, 10}, {0, 10}}) fp.outer.push_back({85000 + x, 447500 + y});
    b.footprint = {fp};
    b.ground_z = 0, b.height_m = 9;
    Solid s = stepped_solid();
    for (Face& f : s.faces) {
        for (Point3& p : f.outer) p.x += 85000, p.y += 447500;
    }
    b.lod2 = {s};
    b.roof_type = "complex";
    m.buildings.push_back(b);
    for (Building& x : m.buildings) complete_building(x, m.crs);
    return m;
}

}  // namespace

TEST_CASE("refined LODs: a stepped roof gives two roof parts, LOD1.3 blocks at their heights, LOD2.2 parts that add up", "[model][lod]") {
    const Solid s = stepped_solid();
    REQUIRE(validate_solid(s).empty());
    double v = 0;
    REQUIRE(test::cgal_check_solid(s, &v) == "");
    CHECK(v == Approx(1600.0));
    const RoofPartsResult r = roof_parts({s});
    CHECK(r.unsplit.empty());
    REQUIRE(r.parts.size() == 2);
    const RoofPart& flat = r.parts[0];
    const RoofPart& gable = r.parts[1];
    CHECK(flat.lod13_roof_z == Approx(6.0));
    // z is uniform on [9, 11] over the gable's plan: its 70th percentile is 10.4.
    CHECK(gable.lod13_roof_z == Approx(10.4).margin(0.1));
    for (const RoofPart& p : r.parts) {
        CHECK(p.ground_z == 0.0);
        CHECK(p.lod13_errors.empty());
        CHECK(p.lod22_errors.empty());
        double v13 = 0, v22 = 0;
        CHECK(test::cgal_check_solid(p.lod13, &v13) == "");
        CHECK(test::cgal_check_solid(p.lod22, &v22) == "");
        CHECK(v13 == Approx(p.lod13_volume));
        CHECK(v22 == Approx(p.lod22_volume));
        CHECK(v13 == Approx(100.0 * p.lod13_roof_z));  // 10 m x 10 m blocks
    }
    // The parts tile the solid: no overlap, nothing lost.
    CHECK(flat.lod22_volume == Approx(600.0));
    CHECK(gable.lod22_volume == Approx(1000.0));
    // A solid without a step stays one part: its LOD2.2 is the solid itself.
    Solid box = extrude_prism(Polygon{{{0, 0}, {4, 0}, {4, 3}, {0, 3}}, {}}, 1.0, 5.0);
    const RoofPartsResult one = roof_parts({box});
    REQUIRE(one.parts.size() == 1);
    CHECK(one.parts[0].lod13_roof_z == Approx(5.0));
    CHECK(one.parts[0].lod22.faces.size() == box.faces.size());
    CHECK(roof_parts({}).parts.empty());
}

TEST_CASE("refined LODs in CityJSON (BuildingParts, 1.2 / 1.3 / 2.2, schema-valid, CGAL-closed) and CityGML 2.0 (attribute, xmllint)", "[model][lod][cityjson]") {
    ScratchDir dir("refined_lod");
    const CityModel m = stepped_model();
    const Building& b = m.buildings[0];
    CHECK(b.status == "ok");
    REQUIRE(b.roof_parts.size() == 2);
    write_cityjson(dir / "m.city.json", m);
    std::vector<std::string> parts;
    for (const char* n : {"cityobjects.schema.json", "geomprimitives.schema.json", "appearance.schema.json", "geomtemplates.schema.json", "metadata.schema.json"})
        parts.push_back(test::shared_data(std::string("cityjson/schemas-2.0.2/") + n));
    const auto v = test::validate_json(test::shared_data("cityjson/schemas-2.0.2/cityjson.schema.json"), dir / "m.city.json", parts);
    INFO(v.out);
    CHECK(v.exit_code == 0);
    const auto j = nlohmann::json::parse(test::slurp(dir / "m.city.json"));
    const auto& objs = j["CityObjects"];
    REQUIRE(objs.size() == 3);
    const auto& bo = objs["step"];
    CHECK(bo["children"] == nlohmann::json::array({"step-0", "step-1"}));
    CHECK(bo["attributes"]["lods"] == nlohmann::json::array({"0", "1.2", "1.3", "2.2"}));
    CHECK(bo["attributes"]["lod22_parts"] == 2);
    CHECK(bo["attributes"]["lod22_valid"] == true);
    CHECK(bo["attributes"]["lod13_valid"] == true);
    CHECK(bo["attributes"]["lod22_volume_m3"].get<double>() == Approx(1600.0));
    std::map<std::string, int> solids_by_lod;
    for (const auto& [id, o] : objs.items()) {
        if (o["type"] == "BuildingPart") CHECK(o["parents"] == nlohmann::json::array({"step"}));
        for (const auto& g : o["geometry"]) {
            for (const Solid& s : test::solids_from_cityjson(g, j["vertices"], j["transform"])) {
                ++solids_by_lod[g["lod"].get<std::string>()];
                INFO(id << " lod " << g["lod"]);
                CHECK(test::cgal_check_solid(s) == "");
                CHECK(validate_solid(s).empty());
            }
        }
    }
    CHECK(solids_by_lod["1.2"] == 1);
    CHECK(solids_by_lod["1.3"] == 2);
    CHECK(solids_by_lod["2.2"] == 2);
    CHECK(objs["step-1"]["attributes"]["lod13_height_m"].get<double>() == Approx(10.4).margin(0.1));

    write_citygml(dir / "lod2.gml", m, {2, 3});
    write_citygml(dir / "lod1.gml", m, {1, 3});
    for (const char* f : {"lod1.gml", "lod2.gml"}) {
        const auto x = test::run_command("xmllint --noout --nonet --schema " + test::shared_data("citygml2_schemas/CityGML.xsd") + " " + (dir / f));
        INFO(x.err);
        CHECK(x.exit_code == 0);
    }
    const std::string gml2 = test::slurp(dir / "lod2.gml"), gml1 = test::slurp(dir / "lod1.gml");
    CHECK(gml2.find("<bldg:BuildingPart gml:id=\"bldg_step-1\">") != std::string::npos);
    CHECK(gml2.find("name=\"refined_lod\"><gen:value>2.2<") != std::string::npos);
    CHECK(gml1.find("name=\"refined_lod\"><gen:value>1.2<") != std::string::npos);
}

TEST_CASE("refined LODs: a step that fades out at the part's outline (Delft's unclosed parts) gives closed parts that add up", "[model][lod]") {
    // The walls under the outline edges meeting at (20, 5) end at different heights there (7 m and 8 m);
    // before, both took the next edge's start height and left the part's shell open (302 SHELL_NOT_CLOSED).
    const Solid s = fading_step_solid();
    REQUIRE(validate_solid(s).empty());
    double v = 0;
    REQUIRE(test::cgal_check_solid(s, &v) == "");
    CHECK(v == Approx(1062.5));
    const RoofPartsResult r = roof_parts({s});
    INFO((r.unsplit.empty() ? std::string() : r.unsplit.front()));
    CHECK(r.unsplit.empty());
    REQUIRE(r.parts.size() == 2);
    double sum = 0;
    for (const RoofPart& p : r.parts) {
        CHECK(p.lod22_errors.empty());
        CHECK(p.lod13_errors.empty());
        double v22 = 0;
        CHECK(test::cgal_check_solid(p.lod22, &v22) == "");
        CHECK(v22 == Approx(p.lod22_volume));
        sum += p.lod22_volume;
    }
    CHECK(r.parts[0].lod22_volume == Approx(300.0));
    CHECK(r.parts[1].lod22_volume == Approx(762.5));
    CHECK(sum == Approx(v));
}
