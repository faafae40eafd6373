#include <catch2/catch.hpp>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "core/error.hpp"
#include "io/cityjson_writer.hpp"
#include "io/citygml_writer.hpp"
#include "io/vector.hpp"
#include "pipeline/export_run.hpp"
#include "pipeline/heights_run.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;
using test::shared_data;

namespace {

std::string cityjson_schema(const std::string& name) { return shared_data("cityjson/schemas-2.0.2/" + name); }
std::vector<std::string> cityjson_parts() {
    std::vector<std::string> v;
    for (const char* n : {"cityobjects.schema.json", "geomprimitives.schema.json", "appearance.schema.json", "geomtemplates.schema.json",
                          "metadata.schema.json"})
        v.push_back(cityjson_schema(n));
    return v;
}
test::CommandResult xmllint(const std::string& gml) {
    return test::run_command("xmllint --noout --nonet --schema " + shared_data("citygml2_schemas/CityGML.xsd") + " " + gml);
}
// Splits a CityJSONSeq file into its header (CityJSON) and its features (JSON Lines).
void split_seq(const std::string& path, const std::string& header, const std::string& features) {
    std::ifstream in(path);
    std::string line;
    std::getline(in, line);
    std::ofstream(header) << line;
    std::ofstream out(features);
    while (std::getline(in, line)) out << line << "\n";
}

Polygon rect(double x0, double y0, double x1, double y1) { return Polygon{{{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}}, {}}; }

// Three buildings in RD New + NAP: a box, a courtyard block, one without height.
CityModel small_model() {
    CityModel m;
    m.crs.label = "EPSG:28992+5709", m.crs.horizontal_epsg = 28992, m.crs.vertical_epsg = 5709, m.crs.compound_epsg = 7415;
    Building a;
    a.id = "box";
    a.footprint = {rect(85000, 447500, 85010, 447520)};
    a.ground_z = 0.5, a.height_m = 6.0;
    a.attributes = {{"name", std::string("a <box> & co")}, {"floors", int64_t(2)}, {"score", 0.25}, {"empty", AttributeValue()}};
    Building c;
    c.id = "court yard/1";  // characters a gml:id cannot hold
    Polygon p = rect(85020, 447500, 85050, 447530);
    p.holes.push_back({{85030, 447510}, {85030, 447520}, {85040, 447520}, {85040, 447510}});
    c.footprint = {p};
    c.ground_z = 0.2, c.height_m = 9.0;
    c.attributes = {{"name", std::string("court")}, {"floors", int64_t(3)}, {"score", 0.5}, {"empty", AttributeValue()}};
    // LOD2 for the box: a gable roof made by hand (ridge along y at x = 85005, eaves 6 m, ridge 9 m).
    {
        const double x0 = 85000, x1 = 85010, xm = 85005, y0 = 447500, y1 = 447520, g = 0.5, e = 6.5, r = 9.5;
        Solid s;
        s.faces.push_back({{{x0, y0, g}, {x0, y1, g}, {x1, y1, g}, {x1, y0, g}}, {}, SurfaceType::ground});
        s.faces.push_back({{{x0, y0, g}, {x1, y0, g}, {x1, y0, e}, {xm, y0, r}, {x0, y0, e}}, {}, SurfaceType::wall});
        s.faces.push_back({{{x1, y1, g}, {x0, y1, g}, {x0, y1, e}, {xm, y1, r}, {x1, y1, e}}, {}, SurfaceType::wall});
        s.faces.push_back({{{x1, y0, g}, {x1, y1, g}, {x1, y1, e}, {x1, y0, e}}, {}, SurfaceType::wall});
        s.faces.push_back({{{x0, y1, g}, {x0, y0, g}, {x0, y0, e}, {x0, y1, e}}, {}, SurfaceType::wall});
        s.faces.push_back({{{x1, y0, e}, {x1, y1, e}, {xm, y1, r}, {xm, y0, r}}, {}, SurfaceType::roof});
        s.faces.push_back({{{x0, y1, e}, {x0, y0, e}, {xm, y0, r}, {xm, y1, r}}, {}, SurfaceType::roof});
        a.lod2.push_back(s);
        a.roof_type = "gable";
    }
    Building n;
    n.id = "nothing";
    n.footprint = {rect(85060, 447500, 85070, 447510)};
    n.attributes = {{"name", std::string("n")}, {"floors", AttributeValue()}, {"score", AttributeValue()}, {"empty", AttributeValue()}};
    m.buildings = {a, c, n};
    for (Building& b : m.buildings) complete_building(b, m.crs);
    return m;
}

}  // namespace

TEST_CASE("Hand-made model - gable LOD2 is valid - CityGML LOD1 and LOD2 validate against the XSD", "[export][citygml]") {
    ScratchDir dir("export_gml");
    const CityModel m = small_model();
    CHECK(m.buildings[0].lod2_errors.empty());
    // Gable volume: box 10 x 20 x 6 plus the prism of the gable, 10 x 3 / 2 x 20.
    CHECK(m.buildings[0].lod2_volume == Approx(10.0 * 20.0 * 6.0 + 10.0 * 3.0 / 2.0 * 20.0));
    CHECK(m.buildings[1].lod1_volume == Approx((900.0 - 100.0) * 9.0));
    CHECK(m.buildings[2].status == "no_height");
    const CityGmlWriteReport r1 = write_citygml(dir / "lod1.gml", m, {1, 3});
    CHECK(r1.buildings == 3);
    CHECK(r1.with_geometry == 2);
    const auto v1 = xmllint(dir / "lod1.gml");
    INFO(v1.err);
    CHECK(v1.exit_code == 0);
    const auto r2 = write_citygml(dir / "lod2.gml", m, {2, 3});
    CHECK(r2.with_geometry == 1);
    const auto v2 = xmllint(dir / "lod2.gml");
    INFO(v2.err);
    CHECK(v2.exit_code == 0);
    const std::string gml = test::slurp(dir / "lod1.gml");
    CHECK(gml.find("srsName=\"urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709\" srsDimension=\"3\"") != std::string::npos);
    CHECK(gml.find("gml:id=\"bldg_court_yard_1\"") != std::string::npos);
    CHECK(gml.find("<bldg:measuredHeight uom=\"m\">9.000</bldg:measuredHeight>") != std::string::npos);
    CHECK(gml.find("a &lt;box&gt; &amp; co") != std::string::npos);
    CHECK(gml.find("<gml:interior>") != std::string::npos);  // the courtyard ring
    CHECK(test::slurp(dir / "lod2.gml").find("<bldg:RoofSurface") != std::string::npos);
    // Every gml:id is unique.
    std::set<std::string> ids;
    for (std::size_t p = gml.find("gml:id=\""); p != std::string::npos; p = gml.find("gml:id=\"", p + 1)) {
        const std::size_t q = gml.find('"', p + 8);
        CHECK(ids.insert(gml.substr(p + 8, q - p - 8)).second);
    }
}

TEST_CASE("Hand-made model - CityJSON and CityJSONSeq validate against the CityJSON 2.0.2 schemas", "[export][cityjson]") {
    ScratchDir dir("export_cj");
    const CityModel m = small_model();
    const CityJsonWriteReport r = write_cityjson(dir / "m.city.json", m);
    CHECK(r.buildings == 3);
    const auto v = test::validate_json(cityjson_schema("cityjson.schema.json"), dir / "m.city.json", cityjson_parts());
    INFO(v.out);
    CHECK(v.exit_code == 0);
    const auto j = nlohmann::json::parse(test::slurp(dir / "m.city.json"));
    CHECK(j["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/7415");
    CHECK(j["CityObjects"]["box"]["geometry"].size() == 2);  // LOD0, LOD1.2; its one roof part holds LOD1.3 and LOD2.2
    CHECK(j["CityObjects"]["box"]["children"] == nlohmann::json::array({"box-0"}));
    CHECK(j["CityObjects"]["box-0"]["type"] == "BuildingPart");
    CHECK(j["CityObjects"]["box-0"]["geometry"].size() == 2);
    CHECK(j["CityObjects"]["box-0"]["geometry"][1]["lod"] == "2.2");
    CHECK(j["CityObjects"].size() == 4);
    CHECK(j["CityObjects"]["box"]["attributes"]["roofType"] == "gable");
    CHECK(j["CityObjects"]["nothing"]["attributes"]["status"] == "no_height");
    // Vertices are integers after `transform`: the box's first corner comes back to the millimetre.
    const auto& t = j["transform"];
    bool found = false;
    for (const auto& vx : j["vertices"])
        if (std::abs(vx[0].get<double>() * t["scale"][0].get<double>() + t["translate"][0].get<double>() - 85000.0) < 1e-9 &&
            std::abs(vx[1].get<double>() * t["scale"][1].get<double>() + t["translate"][1].get<double>() - 447500.0) < 1e-9)
            found = true;
    CHECK(found);
    CityJsonWriteOptions seq;
    seq.sequence = true;
    write_cityjson(dir / "m.city.jsonl", m, seq);
    split_seq(dir / "m.city.jsonl", dir / "header.json", dir / "features.jsonl");
    CHECK(test::validate_json(cityjson_schema("cityjson.schema.json"), dir / "header.json", cityjson_parts()).exit_code == 0);
    const auto fv = test::validate_json(cityjson_schema("cityjsonfeature.schema.json"), dir / "features.jsonl", cityjson_parts());
    INFO(fv.out);
    CHECK(fv.exit_code == 0);
    CHECK(test::count_lines(test::slurp(dir / "m.city.jsonl")) == 4);
}

TEST_CASE("export on Delft heights - every format - CRS and vertical datum - GDAL round trip - LOD1 volumes", "[export][real]") {
    ScratchDir dir("export_delft");
    HeightsRunOptions ho;
    ho.cloud_crs = "EPSG:7415";
    run_heights(shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson"), shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"),
                dir / "h.gpkg", ho);
    const auto cli = test::run_cli("export --in " + (dir / "h.gpkg") + " --out " + (dir / "out") + " --id-field gml_id");
    INFO(cli.err);
    REQUIRE(cli.exit_code == 0);
    CHECK(cli.err.find("135 buildings (EPSG:28992+5709); LOD1 135 (135 valid)") != std::string::npos);
    // GeoJSON is RFC 7946 (WGS84, no crs member); the GeoPackage keeps RD New + NAP.
    const auto gj = nlohmann::json::parse(test::slurp(dir / "out/buildings.geojson"));
    CHECK_FALSE(gj.contains("crs"));
    CHECK(gj["features"].size() == 135);
    const double lon = gj["features"][0]["geometry"]["coordinates"][0][0][0].get<double>();
    CHECK(lon > 4.3);
    CHECK(lon < 4.4);
    const auto info = test::run_command("ogrinfo -ro -so " + (dir / "out/buildings.gpkg") + " buildings");
    CHECK(info.out.find("Feature Count: 135") != std::string::npos);
    CHECK(info.out.find("NAP height") != std::string::npos);
    CHECK(info.out.find("Amersfoort / RD New") != std::string::npos);
    const auto gj_info = test::run_command("ogrinfo -ro -so " + (dir / "out/buildings.geojson") + " buildings");
    CHECK(gj_info.out.find("Feature Count: 135") != std::string::npos);
    CHECK(gj_info.out.find("WGS 84") != std::string::npos);
    // LOD1 volume = footprint area x height, building by building.
    const PolygonLayer out = read_polygon_layer(dir / "out/buildings.gpkg");
    int vol = -1, h = -1, status = -1;
    for (std::size_t i = 0; i < out.field_names.size(); ++i) {
        if (out.field_names[i] == "lod1_volume_m3") vol = static_cast<int>(i);
        if (out.field_names[i] == "height_m") h = static_cast<int>(i);
        if (out.field_names[i] == "status") status = static_cast<int>(i);
    }
    REQUIRE(vol >= 0);
    REQUIRE(h >= 0);
    for (const Feature& f : out.features) {
        const double area = parts_area(f.geometry);
        CHECK(std::get<double>(f.values[vol]) == Approx(area * std::get<double>(f.values[h])).epsilon(1e-9));
        CHECK(std::get<std::string>(f.values[status]) == "ok");
    }
    CHECK(xmllint(dir / "out/buildings_lod1.gml").exit_code == 0);
    CHECK(xmllint(dir / "out/buildings_lod2.gml").exit_code == 0);
    CHECK(test::validate_json(cityjson_schema("cityjson.schema.json"), dir / "out/buildings.city.json", cityjson_parts()).exit_code == 0);
    const auto cj = nlohmann::json::parse(test::slurp(dir / "out/buildings.city.json"));
    CHECK(cj["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/7415");
    CHECK(cj["CityObjects"].size() == 135);
    // Native GeoJSON keeps RD New with a crs member.
    REQUIRE(test::run_cli("export --in " + (dir / "h.gpkg") + " --out " + (dir / "native") + " --formats geojson --geojson-crs native").exit_code == 0);
    const auto native = nlohmann::json::parse(test::slurp(dir / "native/buildings.geojson"));
    CHECK(native.contains("crs"));
    CHECK(native["features"][0]["geometry"]["coordinates"][0][0][0].get<double>() > 84000);
    CHECK_FALSE(std::filesystem::exists(dir / "native/buildings.gpkg"));
}

TEST_CASE("export refuses bad inputs with the file named and writes nothing", "[export][errors]") {
    ScratchDir dir("export_bad");
    const auto missing = test::run_cli("export --in " + (dir / "none.gpkg") + " --out " + (dir / "o1"));
    CHECK(missing.exit_code == 1);
    CHECK(missing.err.find("none.gpkg: file not found") != std::string::npos);
    {
        std::ofstream f(dir / "geo.geojson");
        f << R"({"type":"FeatureCollection","features":[{"type":"Feature","properties":{"height_m":"tall","ground_z":1},"geometry":{"type":"Polygon","coordinates":[[[4.3,52.0],[4.3001,52.0],[4.3001,52.0001],[4.3,52.0]]]}}]})";
    }
    const auto geo = test::run_cli("export --in " + (dir / "geo.geojson") + " --out " + (dir / "o2"));
    // Lon/lat buildings are worked on their UTM zone (export of a run's buildings.geojson): the text height still stops it.
    CHECK(geo.exit_code == 1);
    CHECK(geo.err.find("geo.geojson: field 'height_m' is text") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "o2/buildings.geojson"));
    REQUIRE(std::system(("ogr2ogr -q -t_srs EPSG:28992 " + (dir / "rd.geojson") + " " + (dir / "geo.geojson")).c_str()) == 0);
    const auto text = test::run_cli("export --in " + (dir / "rd.geojson") + " --out " + (dir / "o3"));
    CHECK(text.exit_code == 1);
    CHECK(text.err.find("rd.geojson: field 'height_m' is text") != std::string::npos);
    const auto fmt = test::run_cli("export --in " + (dir / "rd.geojson") + " --out " + (dir / "o4") + " --formats kml");
    CHECK(fmt.exit_code == 1);
    CHECK(fmt.err.find("unknown format 'kml'") != std::string::npos);
}
