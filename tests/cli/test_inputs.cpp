// Data we did not make (issue #14): inputs written by other software, re-runs
// on our own output, inputs that cannot work. Everything through the built CLI.
#include <catch2/catch.hpp>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include "test_support.hpp"

using cityforge::test::count_lines;
using cityforge::test::run_cli;
using cityforge::test::run_command;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;
using cityforge::test::slurp;
using nlohmann::json;

namespace {

json info_json(const std::string& path, const std::string& extra = "") {
    const auto r = run_cli("info --json " + extra + " " + path);
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    return json::parse(r.out);
}

// A copy of the (CRS-less) AHN3 Delft LAS 1.2 file with the CRS as GeoTIFF
// keys only, the way LAS 1.0-1.3 archives store it: ProjectedCSTypeGeoKey
// 28992 (RD New) and VerticalCSTypeGeoKey 5709 (NAP height).
void write_geokeys_only_copy(const std::string& src, const std::string& dst) {
    std::string las = slurp(src);
    REQUIRE(las.size() > 227);
    uint16_t header_size;
    uint32_t offset, n_vlr;
    std::memcpy(&header_size, las.data() + 94, 2);
    std::memcpy(&offset, las.data() + 96, 4);
    std::memcpy(&n_vlr, las.data() + 100, 4);
    const std::vector<uint16_t> keys = {1, 1, 0, 3, 1024, 0, 1, 1, 3072, 0, 1, 28992, 4096, 0, 1, 5709};
    std::string vlr(54, '\0');
    std::memcpy(vlr.data() + 2, "LASF_Projection", 15);
    const uint16_t id = 34735, len = static_cast<uint16_t>(keys.size() * 2);
    std::memcpy(vlr.data() + 18, &id, 2);
    std::memcpy(vlr.data() + 20, &len, 2);
    vlr.append(reinterpret_cast<const char*>(keys.data()), len);
    const uint32_t new_offset = offset + static_cast<uint32_t>(vlr.size()), new_n = n_vlr + 1;
    std::memcpy(las.data() + 96, &new_offset, 4);
    std::memcpy(las.data() + 100, &new_n, 4);
    std::size_t at = header_size;  // after the existing VLRs
    for (uint32_t i = 0; i < n_vlr; ++i) {
        uint16_t l;
        std::memcpy(&l, las.data() + at + 20, 2);
        at += 54 + l;
    }
    las.insert(at, vlr);
    std::ofstream(dst, std::ios::binary) << las;
}

// A GeoJSON of square footprints (RD New) centred on the given points.
void write_squares(const std::string& path, const std::vector<std::pair<double, double>>& centres, double half = 4.0,
                   const std::string& extra_properties = "") {
    json fc{{"type", "FeatureCollection"}, {"crs", {{"type", "name"}, {"properties", {{"name", "urn:ogc:def:crs:EPSG::28992"}}}}}};
    fc["features"] = json::array();
    int id = 1;
    for (auto [x, y] : centres) {
        json props = extra_properties.empty() ? json::object() : json::parse(extra_properties);
        props["name"] = "b" + std::to_string(id++);
        json ring = json::array();
        for (auto [dx, dy] : {std::pair{-1, -1}, {1, -1}, {1, 1}, {-1, 1}, {-1, -1}}) ring.push_back(json::array({x + dx * half, y + dy * half}));
        json geometry{{"type", "Polygon"}, {"coordinates", json::array({ring})}};
        fc["features"].push_back(json{{"type", "Feature"}, {"properties", props}, {"geometry", geometry}});
    }
    std::ofstream(path) << fc.dump();
}

std::vector<std::string> layer_fields(const std::string& path) {
    const json j = info_json(path);
    return j["layers"][0]["fields"].get<std::vector<std::string>>();
}

}  // namespace

// ---------------------------------------------------------------- 1. CRS

TEST_CASE("One CRS resolution for clouds: WKT, libLAS WKT, GeoTIFF keys (projected, vertical, user-defined), none", "[inputs][crs]") {
    // GeoTIFF keys only, with a vertical key (laz-perf's 1815.las): NAD83(2011) + NAVD88 height.
    const json k = info_json(shared_data("laz_corpus/reference_las/1815.las"));
    CHECK(k["crs"]["horizontal_epsg"] == 6580);
    CHECK(k["crs"]["vertical_epsg"] == 5703);
    CHECK(k["crs_source"] == "GeoTIFF keys");
    // GeoTIFF keys (26910) and libLAS's WKT record, which agree: no warning.
    const json p = info_json(shared_data("laz_corpus/reference_las/point-color.las"));
    CHECK(p["crs"]["epsg"] == 26910);
    CHECK(p["crs_warnings"].empty());
    // LAS 1.4, WKT bit set, LASF_Projection WKT (IGN Lidar HD).
    const json l = info_json(shared_data("ign_lidarhd_bdtopo_west/lidarhd_870200_6617083_west.las"));
    CHECK(l["crs"]["epsg"] == 2154);
    CHECK(l["crs_source"] == "WKT VLR");
    // autzen_thin_srs: user-defined keys whose false easting (400000 under a
    // foot unit) disagrees with the libLAS WKT: the WKT wins, a warning names both.
    const auto thin = run_cli("info --json " + shared_data("autzen_oregon/autzen_thin_srs.las"));
    REQUIRE(thin.exit_code == 0);
    const json t = json::parse(thin.out);
    CHECK(t["crs_source"] == "libLAS WKT VLR");
    CHECK(t["crs"]["linear_unit"] == "foot");
    REQUIRE(t["crs_warnings"].size() == 1);
    const std::string w = t["crs_warnings"][0];
    CHECK(w.find("GeoTIFF keys") != std::string::npos);
    CHECK(w.find("x_0=400000") != std::string::npos);
    CHECK(w.find("x_0=121920") != std::string::npos);
    CHECK(thin.err.find("warning") != std::string::npos);
    // No CRS at all (AHN3 Delft): null; the user's CRS is taken.
    CHECK(info_json(shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"))["crs"].is_null());
    CHECK(info_json(shared_data("laz_corpus/reference_las/1.2-with-color.las"))["crs"].is_null());
    // A user CRS that contradicts the file's is used, with a warning.
    const auto over = run_cli("info --json --crs EPSG:32610 " + shared_data("laz_corpus/reference_las/point-color.las"));
    REQUIRE(over.exit_code == 0);
    CHECK(json::parse(over.out)["crs"]["epsg"] == 32610);
    CHECK(over.err.find("overrides the file's CRS EPSG:26910") != std::string::npos);
}

TEST_CASE("heights takes a LAS 1.2 cloud whose CRS is GeoTIFF keys only - and needs --cloud-crs without any", "[inputs][crs]") {
    ScratchDir dir("inputs_geokeys");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    const std::string fp = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    write_geokeys_only_copy(delft, dir / "geokeys.las");
    const json i = info_json(dir / "geokeys.las");
    CHECK(i["crs"]["horizontal_epsg"] == 28992);
    CHECK(i["crs"]["vertical_epsg"] == 5709);

    const auto none = run_cli("heights --quiet --footprints " + fp + " --cloud " + delft + " --out " + (dir / "none.gpkg"));
    CHECK(none.exit_code == 1);
    CHECK(count_lines(none.err) == 1);
    CHECK(none.err.find("no CRS") != std::string::npos);
    CHECK(none.err.find("--cloud-crs") != std::string::npos);

    const auto r = run_cli("heights --quiet --footprints " + fp + " --cloud " + (dir / "geokeys.las") + " --out " + (dir / "h.gpkg"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    // The compound CRS is written under its registered code (EPSG:7415), z_crs names NAP.
    const auto srs = run_command("ogrinfo -q -ro " + (dir / "h.gpkg") + " -sql \"SELECT srs_id FROM gpkg_contents\"");
    CHECK(srs.out.find("srs_id (Integer64) = 7415") != std::string::npos);
    const auto z = run_command("ogrinfo -q -ro " + (dir / "h.gpkg") + " -sql \"SELECT DISTINCT z_crs FROM buildings\"");
    CHECK(z.out.find("z_crs (String) = EPSG:5709") != std::string::npos);
}

// ---------------------------------------------------------------- 2. rasters in any CRS

namespace {
// Sum of area_m2 and geodesic_area_m2 over a footprint file (ogrinfo SQL).
std::pair<double, double> area_sums(const std::string& path) {
    const auto r = run_command("ogrinfo -q -ro " + path + " -sql \"SELECT SUM(area_m2) AS a, SUM(geodesic_area_m2) AS g FROM buildings\"");
    auto value = [&](const std::string& key) {
        const std::size_t at = r.out.find(key + " (Real) = ");
        REQUIRE(at != std::string::npos);
        return std::stod(r.out.substr(at + key.size() + 10));
    };
    return {value("a"), value("g")};
}
}  // namespace

TEST_CASE("footprints on a lon/lat raster (SpaceNet Rio, EPSG:4326) work in metres and write lon/lat", "[inputs][geographic]") {
    ScratchDir dir("inputs_rio");
    const std::string rio = shared_data("spacenet1_rio_rgb/3band_013022223130_Public_img50_rgb.tif");
    const auto r = run_cli("footprints --quiet --ortho " + rio + " --out " + (dir / "rio.gpkg"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(info_json(dir / "rio.gpkg")["layers"][0]["crs"]["epsg"] == 4326);
    const auto [area, geodesic] = area_sums(dir / "rio.gpkg");
    CHECK(area > 100.0);
    CHECK(area == Approx(geodesic).epsilon(0.01));  // ground m², not square degrees
    const auto utm = run_cli("footprints --quiet --ortho " + rio + " --out-crs EPSG:32723 --out " + (dir / "rio_utm.gpkg"));
    REQUIRE(utm.exit_code == 0);
    CHECK(info_json(dir / "rio_utm.gpkg")["layers"][0]["crs"]["epsg"] == 32723);
}

TEST_CASE("Web Mercator orthos (OpenAerialMap Banepa, 27.6 N) give true ground GSD and areas", "[inputs][geographic]") {
    ScratchDir dir("inputs_banepa");
    const std::string banepa = shared_data("oam_catanduanes_banepa/banepa_z19_a_rgba.tif");
    const json i = info_json(banepa);
    CHECK(i["gsd_m"]["x"].get<double>() == Approx(0.2640).margin(0.002));  // nominal 0.2986 "metres" of EPSG:3857
    const auto r = run_cli("footprints --quiet --ortho " + banepa + " --out " + (dir / "b.gpkg"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(info_json(dir / "b.gpkg")["layers"][0]["crs"]["epsg"] == 3857);
    const auto [area, geodesic] = area_sums(dir / "b.gpkg");
    CHECK(area == Approx(geodesic).epsilon(0.01));  // not x1.27
}

// ---------------------------------------------------------------- 3, 4, 5, 6. re-runs, overlap, outputs

TEST_CASE("heights and export run on their own output: colliding fields replaced with a warning, same fields", "[inputs][rerun]") {
    ScratchDir dir("inputs_rerun");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    const std::string fp = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    REQUIRE(run_cli("heights --quiet --footprints " + fp + " --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "h1.gpkg")).exit_code == 0);
    const auto again = run_cli("heights --footprints " + (dir / "h1.gpkg") + " --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "h2.gpkg"));
    INFO(again.err);
    REQUIRE(again.exit_code == 0);
    CHECK(again.err.find("ground_z") != std::string::npos);
    CHECK(again.err.find("replaced") != std::string::npos);
    CHECK(layer_fields(dir / "h2.gpkg") == layer_fields(dir / "h1.gpkg"));
    CHECK(info_json(dir / "h2.gpkg")["layers"][0]["feature_count"] == 135);

    REQUIRE(run_cli("export --quiet --in " + (dir / "h1.gpkg") + " --out " + (dir / "e1")).exit_code == 0);
    const auto e2 = run_cli("export --in " + (dir / "e1/buildings.gpkg") + " --out " + (dir / "e2"));
    INFO(e2.err);
    REQUIRE(e2.exit_code == 0);
    CHECK(e2.err.find("lod1_valid") != std::string::npos);
    CHECK(layer_fields(dir / "e2/buildings.gpkg") == layer_fields(dir / "e1/buildings.gpkg"));
    // The compound CRS read back from our GeoPackage keeps its vertical datum.
    CHECK(e2.err.find("no vertical CRS") == std::string::npos);
}

TEST_CASE("Inputs that cannot work are errors - partial overlap warns - buildings without heights keep their footprint", "[inputs][overlap]") {
    ScratchDir dir("inputs_overlap");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    const std::string fp = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    // Delft footprints, Autzen cloud: no overlap at all.
    const auto none = run_cli("heights --quiet --footprints " + fp + " --cloud " + shared_data("autzen_oregon/autzen_trim.las") + " --out " +
                              (dir / "x.gpkg"));
    CHECK(none.exit_code == 1);
    CHECK(count_lines(none.err) == 1);
    CHECK(none.err.find("bgt_pand_west_with_ref_heights.geojson") != std::string::npos);
    CHECK(none.err.find("autzen_trim.las") != std::string::npos);
    CHECK(none.err.find("EPSG:28992") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "x.gpkg"));
    // An ortho in Atlanta, a cloud in Delft.
    const auto far = run_cli("footprints --quiet --ortho " + shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif") + " --cloud " + delft +
                             " --cloud-crs EPSG:7415 --out " + (dir / "y.gpkg"));
    CHECK(far.exit_code == 1);
    CHECK(count_lines(far.err) == 1);
    CHECK(far.err.find("does not overlap") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "y.gpkg"));

    // One footprint on a Delft roof, one 5 km away: a warning with the count.
    write_squares(dir / "two.geojson", {{84905.0, 447560.0}, {90000.0, 447560.0}});
    const auto part = run_cli("heights --footprints " + (dir / "two.geojson") + " --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "two.gpkg"));
    INFO(part.err);
    REQUIRE(part.exit_code == 0);
    CHECK(part.err.find("1 of 2 footprints lie outside") != std::string::npos);
    // The far one has no height: no solid, but its footprint in CityJSON and CityGML.
    REQUIRE(run_cli("export --quiet --in " + (dir / "two.gpkg") + " --out " + (dir / "model")).exit_code == 0);
    const json cj = json::parse(slurp(dir / "model/buildings.city.json"));
    REQUIRE(cj["CityObjects"].size() == 2);
    int with_lod0 = 0, estimated = 0;
    for (const auto& [id, o] : cj["CityObjects"].items()) {
        bool lod0 = false;
        for (const auto& g : o["geometry"]) lod0 = lod0 || g["lod"] == "0";
        with_lod0 += lod0;
        if (o["attributes"].value("status", "") == "no_height") {
            estimated += o["attributes"].value("footprint_z_estimated", false);
            for (const auto& g : o["geometry"]) CHECK(g["lod"] == "0");
        }
    }
    CHECK(with_lod0 == 2);
    CHECK(estimated == 1);
    const std::string gml = slurp(dir / "model/buildings_lod1.gml");
    std::size_t footprints = 0;
    for (std::size_t at = gml.find("<bldg:lod0FootPrint>"); at != std::string::npos; at = gml.find("<bldg:lod0FootPrint>", at + 1)) ++footprints;
    CHECK(footprints == 2);

    // roofs: no LOD2 solid is invented for the building without points.
    const auto roofs = run_cli("roofs --quiet --footprints " + (dir / "two.geojson") + " --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "roofs"));
    INFO(roofs.err);
    REQUIRE(roofs.exit_code == 0);
    const json rj = json::parse(slurp(dir / "roofs/buildings.city.json"));
    for (const auto& [id, o] : rj["CityObjects"].items())
        if (o["attributes"].value("status", "") == "no_height")
            for (const auto& g : o["geometry"]) CHECK(g["lod"] == "0");
}

// ---------------------------------------------------------------- 7. OGR dataset names

TEST_CASE("Vector inputs may be any GDAL dataset name (/vsigzip/, PG:) - not stat()ed as files", "[inputs][ogr]") {
    ScratchDir dir("inputs_ogr");
    REQUIRE(run_command("cp " + shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson") + " " + (dir / "fp.geojson") +
                        " && gzip " + (dir / "fp.geojson")).exit_code == 0);
    const auto r = run_cli("heights --quiet --footprints /vsigzip/" + (dir / "fp.geojson.gz") + " --cloud " +
                           shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las") + " --cloud-crs EPSG:7415 --out " + (dir / "h.gpkg"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(info_json(dir / "h.gpkg")["layers"][0]["feature_count"] == 135);
    const auto pg = run_cli("info \"PG:dbname=cityforge_no_such_database host=/nonexistent\"");
    CHECK(pg.exit_code == 1);
    CHECK(pg.err.find("file not found") == std::string::npos);
}

// ---------------------------------------------------------------- 8. CLI habits

TEST_CASE("CLI habits: usage errors exit 2 with a suggestion, existing outputs refused without --overwrite, run --help names the config", "[inputs][cli]") {
    ScratchDir dir("inputs_cli");
    const auto typo = run_cli("segmnt");
    CHECK(typo.exit_code == 2);
    CHECK(typo.err.find("did you mean 'segment'") != std::string::npos);
    CHECK(run_cli("audit footprnts").err.find("did you mean 'audit footprints'") != std::string::npos);
    CHECK(run_cli("heights --cloud x.las").exit_code == 2);   // a required option missing
    CHECK(run_cli("footprints --fit bogus --out a.gpkg").exit_code == 2);  // a value outside the choices
    CHECK(run_cli("info " + (dir / "missing.tif")).exit_code == 1);      // a data error

    const std::string rio = shared_data("spacenet1_rio_rgb/3band_013022223130_Public_img51_rgb.tif");
    std::ofstream(dir / "fp.gpkg") << "not ours";
    const auto refused = run_cli("footprints --quiet --ortho " + rio + " --out " + (dir / "fp.gpkg"));
    CHECK(refused.exit_code == 1);
    CHECK(refused.err.find("--overwrite") != std::string::npos);
    CHECK(slurp(dir / "fp.gpkg") == "not ours");
    const auto replaced = run_cli("footprints --ortho " + rio + " --overwrite --progress --out " + (dir / "fp.gpkg"));
    INFO(replaced.err);
    CHECK(replaced.exit_code == 0);
    CHECK(slurp(dir / "fp.gpkg") != "not ours");
    // The progress line: percent and elapsed time, not GDAL's dots.
    CHECK(replaced.err.find("100 %") != std::string::npos);
    CHECK(replaced.err.find("elapsed") != std::string::npos);
    CHECK(replaced.err.find("...10...") == std::string::npos);

    const auto help = run_cli("run --help");
    CHECK(help.exit_code == 0);
    CHECK(help.out.find("schemas/run_config.schema.json") != std::string::npos);
    CHECK(help.out.find("\"tile_size_px\"") != std::string::npos);
}

// ---------------------------------------------------------------- 9. audits

TEST_CASE("A footprint audit without a match says n/a (null) for the means over matches - report.md tables stay tables", "[inputs][audit]") {
    ScratchDir dir("inputs_audit");
    write_squares(dir / "far.geojson", {{90000.0, 447560.0}});
    const auto r = run_cli("audit footprints --pred " + (dir / "far.geojson") + " --ref " +
                           shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson") + " --out " + (dir / "a"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(r.out.find("mean IoU n/a") != std::string::npos);
    const json j = json::parse(slurp(dir / "a/report.json"));
    CHECK(j["totals"]["mean_iou"].is_null());
    CHECK(j["totals"]["mean_polis"].is_null());
    CHECK(j["totals"]["mean_abs_area_error_pct"].is_null());
    CHECK(cityforge::test::validate_json(cityforge::test::source_dir() + "/schemas/audit_report.schema.json", dir / "a/report.json").exit_code == 0);
    const std::string md = slurp(dir / "a/report.md");
    CHECK(md.find("| mean \\|area error\\| (%) | n/a |") != std::string::npos);
}

TEST_CASE("Rectangle and height audits without a comparable building say n/a (null), not 0", "[inputs][audit]") {
    ScratchDir dir("inputs_audit_na");
    const std::string ref = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    const std::string schema = cityforge::test::source_dir() + "/schemas/audit_report.schema.json";
    write_squares(dir / "far.geojson", {{90000.0, 447560.0}}, 4.0, R"({"height_m": 7.5})");
    // Heights: the one prediction matches no reference footprint.
    const auto h = run_cli("audit heights --pred " + (dir / "far.geojson") + " --ref " + ref + " --ref-field ref_height_m --out " + (dir / "h"));
    INFO(h.err);
    REQUIRE(h.exit_code == 0);
    CHECK(h.out.find("MAE n/a m RMSE n/a m bias n/a m max n/a m over 0 buildings") != std::string::npos);
    const json hj = json::parse(slurp(dir / "h/report.json"));
    for (const char* k : {"mae_m", "rmse_m", "bias_m", "max_abs_m"}) CHECK(hj["totals"][k].is_null());
    CHECK(hj["measures"].find("mae") == hj["measures"].end());
    CHECK(cityforge::test::validate_json(schema, dir / "h/report.json").exit_code == 0);
    CHECK(slurp(dir / "h/report.md").find("| MAE (m) | n/a |") != std::string::npos);
    // A gate on a measure that is not defined fails (exit 4), it does not pass on a 0.
    CHECK(run_cli("audit heights --pred " + (dir / "far.geojson") + " --ref " + ref + " --ref-field ref_height_m --fail-above mae=1 --out " +
                  (dir / "h2")).exit_code == 4);
    // Rectangles: fitted against original polygons that none of them matches.
    const auto r = run_cli("audit rectangles --in " + (dir / "far.geojson") + " --original " + ref + " --out " + (dir / "r"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(r.out.find("mean |area error| n/a % max n/a % mean signed n/a % over 0 of 1 footprints") != std::string::npos);
    const json rj = json::parse(slurp(dir / "r/report.json"));
    for (const char* k : {"mean_abs_error_pct", "max_abs_error_pct", "mean_error_pct", "mean_abs_error_m2"}) CHECK(rj["totals"][k].is_null());
    CHECK(cityforge::test::validate_json(schema, dir / "r/report.json").exit_code == 0);
    const std::string md = slurp(dir / "r/report.md");
    CHECK(md.find("| mean \\|area error\\| (%) | n/a |") != std::string::npos);
    CHECK(md.find("| max \\|area error\\| (%) | n/a |") != std::string::npos);
}

// ---------------------------------------------------------------- run's tile merge

namespace {
// "name: Type" of every field of a layer, from ogrinfo -so.
std::string ogr_schema(const std::string& path, const std::string& layer) {
    const auto r = run_command("ogrinfo -ro -so " + path + " " + layer);
    REQUIRE(r.exit_code == 0);
    return r.out;
}
}  // namespace

TEST_CASE("run's tile merge keeps the declared type of attributes whose values are all null", "[inputs][run]") {
    ScratchDir dir("inputs_run_types");
    // 12 Delft footprints in a GeoPackage with three empty fields (Real, Integer64, String).
    const std::string fp = dir / "fp.gpkg";
    REQUIRE(run_command("ogr2ogr -f GPKG -nln footprints -limit 12 " + fp + " " +
                        shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson")).exit_code == 0);
    for (const char* col : {"survey_z REAL", "floors INTEGER", "note TEXT"})
        REQUIRE(run_command("ogrinfo -q " + fp + " -sql \"ALTER TABLE footprints ADD COLUMN " + col + "\"").exit_code == 0);
    // Several tiles: the building lines of each are merged.
    const auto r = run_cli("run --quiet --footprints " + fp + " --cloud " + shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las") +
                           " --cloud-crs EPSG:7415 --tile-size 100 --out " + (dir / "run"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    REQUIRE(std::filesystem::exists(dir / "run/tiles/tile_00001.json"));
    const std::string schema = ogr_schema(dir / "run/buildings.gpkg", "buildings");
    CHECK(schema.find("survey_z: Real") != std::string::npos);
    CHECK(schema.find("floors: Integer64") != std::string::npos);
    CHECK(schema.find("note: String") != std::string::npos);
    CHECK(schema.find("check_p90_roof_nap_m: Real") != std::string::npos);
    CHECK(schema.find("Feature Count: 12") != std::string::npos);
}

TEST_CASE("run takes a lon/lat ortho (Rio) and a Web Mercator ortho (Banepa) as footprints does - outputs name their CRS", "[inputs][geographic][run]") {
    ScratchDir dir("inputs_run_geographic");
    const std::string rio = shared_data("spacenet1_rio_rgb/3band_013022223130_Public_img50_rgb.tif");
    // Same working grid and areas as `footprints` (one working-grid helper).
    REQUIRE(run_cli("footprints --quiet --ortho " + rio + " --out " + (dir / "fp.gpkg")).exit_code == 0);
    const auto r = run_cli("run --quiet --ortho " + rio + " --out " + (dir / "rio"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    const json rep = json::parse(slurp(dir / "rio/run_report.json"));
    CHECK(rep["inputs"]["ortho"]["crs"] == "EPSG:4326");
    CHECK(rep["working_crs"] == "EPSG:32723");  // UTM 23S, the zone of the tile centre
    CHECK(rep["crs"] == "EPSG:32723");          // a city model in degrees is refused: the working CRS
    const auto [fp_area, fp_geodesic] = area_sums(dir / "fp.gpkg");
    const auto [area, geodesic] = area_sums(dir / "rio/buildings.gpkg");
    CHECK(area == Approx(fp_area).epsilon(1e-9));
    CHECK(area == Approx(geodesic).epsilon(0.01));
    CHECK(rep["counts"]["buildings"] == info_json(dir / "fp.gpkg")["layers"][0]["feature_count"]);
    CHECK(info_json(dir / "rio/buildings.gpkg")["layers"][0]["crs"]["epsg"] == 32723);
    CHECK(json::parse(slurp(dir / "rio/buildings.city.json"))["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/32723");
    CHECK(slurp(dir / "rio/buildings_lod1.gml").find("srsName=\"urn:ogc:def:crs:EPSG::32723\"") != std::string::npos);
    // No cloud, no solids: the 3D-only formats are skipped with a warning, not a failed run.
    CHECK(rep["warnings"].dump().find("glTF and 3D Tiles not written") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "rio/buildings.glb"));
    // --out-crs: another projected CRS; areas stay ground values; a geographic one is refused before any tile runs.
    REQUIRE(run_cli("run --quiet --ortho " + rio + " --out-crs EPSG:3857 --formats gpkg --out " + (dir / "rio_3857")).exit_code == 0);
    CHECK(info_json(dir / "rio_3857/buildings.gpkg")["layers"][0]["crs"]["epsg"] == 3857);
    CHECK(area_sums(dir / "rio_3857/buildings.gpkg").first == Approx(area).epsilon(1e-9));
    const auto deg = run_cli("run --quiet --ortho " + rio + " --out-crs EPSG:4326 --out " + (dir / "rio_deg"));
    CHECK(deg.exit_code == 1);
    CHECK(deg.err.find("geographic") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "rio_deg/manifest.json"));

    // Web Mercator: the grid stays EPSG:3857, measures are ground metres (not x1.27).
    const std::string banepa = shared_data("oam_catanduanes_banepa/banepa_z19_a_rgba.tif");
    const auto b = run_cli("run --quiet --ortho " + banepa + " --formats gpkg,cityjson --out " + (dir / "banepa"));
    INFO(b.err);
    REQUIRE(b.exit_code == 0);
    const json brep = json::parse(slurp(dir / "banepa/run_report.json"));
    CHECK(brep["crs"] == "EPSG:3857");
    const auto [b_area, b_geodesic] = area_sums(dir / "banepa/buildings.gpkg");
    CHECK(b_area > 1000.0);
    CHECK(b_area == Approx(b_geodesic).epsilon(0.01));
}
