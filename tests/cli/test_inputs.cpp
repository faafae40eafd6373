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
    // Footprints with heights have no LOD2 roofs: said, not left to the file.
    CHECK(e2.err.find("no building has LOD2 roofs") != std::string::npos);
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
    // A square in a gap between the reference's buildings (inputs that do not overlap at all are an error).
    write_squares(dir / "far.geojson", {{84830.0, 447480.0}});
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
    // A square in a gap between the reference's buildings (inputs that do not overlap at all are an error).
    write_squares(dir / "far.geojson", {{84830.0, 447480.0}}, 4.0, R"({"height_m": 7.5})");
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

// ---------------------------------------------------------------- the corpus of other writers' files

TEST_CASE("LAS 1.0-1.4 from other writers: version, points and CRS record (GeoKeys, WKT, both, none, unusable) through info and rasterize",
          "[inputs][corpus][crs]") {
    ScratchDir dir("inputs_las_corpus");
    // LAS 1.0: laz-perf's point10.las (LAS 1.2, PF0, GeoKeys 26910 and a libLAS WKT VLR) with version minor 0 (the 1.0
    // header has the same 227 bytes) and the libLAS VLR's user id renamed, so that only the GeoTIFF keys are left.
    std::string las = slurp(shared_data("laz_corpus/reference_las/point10.las"));
    REQUIRE(las.size() > 227);
    las[25] = 0;
    const std::size_t liblas = las.find(std::string("liblas\0", 7));
    REQUIRE(liblas != std::string::npos);
    las.replace(liblas, 6, "othrs_");
    std::ofstream(dir / "point10_1.0.las", std::ios::binary) << las;
    struct Case {
        std::string path, format;
        int points;
        int epsg;            // horizontal EPSG the CRS resolves to; 0 = no usable CRS
        std::string source;  // crs_source
    };
    const std::vector<Case> cases{
        {dir / "point10_1.0.las", "LAS 1.0", 1065, 26910, "GeoTIFF keys"},
        {shared_data("laz_corpus/lone-star.laz"), "LAS 1.1", 518862, 0, ""},  // geocentric keys over UTM-like numbers: ignored
        {shared_data("laz_corpus/reference_las/point-time.las"), "LAS 1.2", 1065, 26910, "libLAS WKT VLR"},  // keys + libLAS WKT
        {shared_data("laz_corpus/reference_las/point-color.las"), "LAS 1.2", 1065, 26910, "libLAS WKT VLR"},  // keys + libLAS WKT
        {shared_data("laz_corpus/reference_las/1.2-with-color.las"), "LAS 1.2", 1065, 0, ""},                 // none (PDAL)
        {shared_data("laz_corpus/reference_las/no-points-1.3.las"), "LAS 1.3", 0, 0, ""},
        {shared_data("laz_corpus/point-time-1.4.las.laz"), "LAS 1.4", 1065, 26910, "WKT VLR"},                // WKT only
        {shared_data("laz_corpus/las_with_several_extra_byte_bloc.laz"), "LAS 1.4", 697721, 2154, "WKT VLR"},  // WKT and keys
        {shared_data("laz_corpus/test_pdalfail_0643_6319_LA93_IGN69.laz"), "LAS 1.4", 89, 0, ""},            // keys 3072 = 65535, no parameters
    };
    for (const Case& c : cases) {
        INFO(c.path);
        const json j = info_json(c.path);
        CHECK(j["format"].get<std::string>().find(c.format) == 0);
        CHECK(j["point_count"] == c.points);
        if (c.epsg) {
            CHECK(j["crs"]["horizontal_epsg"] == c.epsg);
            CHECK(j["crs_source"] == c.source);
        } else {
            CHECK(j["crs"].is_null());
        }
        if (c.points == 0) continue;
        const std::string out = dir / ("r_" + std::filesystem::path(c.path).filename().string());
        const auto r = run_cli("cloud rasterize --cloud " + c.path + " --gsd 2 --out " + out);
        if (c.epsg) {
            INFO(r.err);
            REQUIRE(r.exit_code == 0);
            CHECK(run_command("gdalsrsinfo -o epsg " + out + "/dsm.tif").out.find("EPSG:" + std::to_string(c.epsg)) != std::string::npos);
        } else {
            // No usable CRS is an error naming the file and --cloud-crs; an unusable record is named in a warning.
            CHECK(r.exit_code == 1);
            CHECK(r.err.find("no CRS") != std::string::npos);
            CHECK(r.err.find("--cloud-crs") != std::string::npos);
            CHECK_FALSE(std::filesystem::exists(out + "/dsm.tif"));
        }
    }
    const auto geocentric = run_cli("info --json " + shared_data("laz_corpus/lone-star.laz"));
    CHECK(geocentric.err.find("ignored: a geocentric CRS") != std::string::npos);
    const auto local = run_cli("info --json " + shared_data("laz_corpus/test_pdalfail_0643_6319_LA93_IGN69.laz"));
    CHECK(local.err.find("ignored: a local CRS") != std::string::npos);
    // With the CRS given, the same file works; a geocentric --cloud-crs is refused.
    const std::string pf = shared_data("laz_corpus/test_pdalfail_0643_6319_LA93_IGN69.laz");
    CHECK(run_cli("cloud rasterize --quiet --cloud " + pf + " --cloud-crs EPSG:2154 --gsd 1 --out " + (dir / "pf")).exit_code == 0);
    const auto ecef = run_cli("cloud rasterize --quiet --cloud " + pf + " --cloud-crs EPSG:4978 --gsd 1 --out " + (dir / "pf_ecef"));
    CHECK(ecef.exit_code == 1);
    CHECK(ecef.err.find("geocentric") != std::string::npos);
}

TEST_CASE("Footprint files from other writers: MultiPolygonZ with holes, colliding fields, a GeoPackage with two polygon layers",
          "[inputs][corpus][ogr]") {
    ScratchDir dir("inputs_fp_corpus");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    // A MultiPolygonZ (z = 0.5, as 3D exports carry): a 20 m square with a 4 m hole on a Delft roof, and a second part;
    // fields named like ours (height_m, area_m2) and one of its own.
    auto ring = [](double x, double y, double h, bool cw) {
        json r = json::array();
        std::vector<std::pair<int, int>> c{{-1, -1}, {1, -1}, {1, 1}, {-1, 1}, {-1, -1}};
        if (cw) std::reverse(c.begin(), c.end());
        for (auto [dx, dy] : c) r.push_back(json::array({x + dx * h, y + dy * h, 0.5}));
        return r;
    };
    json geometry{{"type", "MultiPolygon"},
                  {"coordinates", json::array({json::array({ring(84905.0, 447560.0, 10.0, false), ring(84905.0, 447560.0, 2.0, true)}),
                                               json::array({ring(84960.0, 447500.0, 5.0, false)})})}};
    json fc{{"type", "FeatureCollection"}, {"crs", {{"type", "name"}, {"properties", {{"name", "urn:ogc:def:crs:EPSG::28992"}}}}}};
    fc["features"] = json::array({json{{"type", "Feature"}, {"properties", {{"height_m", 99.0}, {"area_m2", 1.0}, {"owner", "x"}}}, {"geometry", geometry}}});
    std::ofstream(dir / "mz.geojson") << fc.dump();
    REQUIRE(info_json(dir / "mz.geojson")["layers"][0]["geometry_type"].get<std::string>().find("Multi Polygon") != std::string::npos);
    const auto h = run_cli("heights --footprints " + (dir / "mz.geojson") + " --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "mz.gpkg"));
    INFO(h.err);
    REQUIRE(h.exit_code == 0);
    CHECK(h.err.find("height_m") != std::string::npos);  // the colliding fields are named and replaced
    const auto wkt = run_command("ogr2ogr -f CSV -lco GEOMETRY=AS_WKT /vsistdout/ " + (dir / "mz.gpkg") + " -select owner,height_m,area_m2");
    REQUIRE(wkt.exit_code == 0);
    CHECK(wkt.out.find("MULTIPOLYGON") != std::string::npos);
    CHECK(wkt.out.find("),(") != std::string::npos);  // the hole is kept
    CHECK(wkt.out.find(")),((") != std::string::npos);  // and both parts
    CHECK(wkt.out.find(",x,") != std::string::npos);    // the writer's own field passes through
    CHECK(wkt.out.find("99") == std::string::npos);     // ours replaced theirs
    const auto area = run_command("ogrinfo -q -ro " + (dir / "mz.gpkg") + " -sql \"SELECT ST_Area(geom) AS a FROM buildings\"");
    const std::size_t at = area.out.find("a (Real) = ");
    REQUIRE(at != std::string::npos);
    CHECK(std::stod(area.out.substr(at + 11)) == Approx(400.0 - 16.0 + 100.0).margin(0.01));  // both parts, minus the hole

    // Two polygon layers and no name: ambiguous, an error listing them; --layer (or GPKG:file:layer) chooses.
    const std::string two = dir / "two.gpkg";
    REQUIRE(run_command("ogr2ogr -f GPKG -nln buildings " + two + " " + (dir / "mz.geojson")).exit_code == 0);
    REQUIRE(run_command("ogr2ogr -update -f GPKG -nln parcels " + two + " " + (dir / "mz.geojson")).exit_code == 0);
    const auto amb = run_cli("heights --quiet --footprints " + two + " --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "amb.gpkg"));
    CHECK(amb.exit_code == 1);
    CHECK(count_lines(amb.err) == 1);
    CHECK(amb.err.find("2 polygon layers (buildings, parcels)") != std::string::npos);
    CHECK(amb.err.find("--layer") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "amb.gpkg"));
    CHECK(run_cli("heights --quiet --footprints " + two + " --layer parcels --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "p.gpkg"))
              .exit_code == 0);
    const auto missing = run_cli("heights --quiet --footprints " + two + " --layer roads --cloud " + delft + " --cloud-crs EPSG:7415 --out " +
                                 (dir / "m.gpkg"));
    CHECK(missing.exit_code == 1);
    CHECK(missing.err.find("has no layer 'roads' (layers: buildings, parcels)") != std::string::npos);
    // Commands without --layer take GDAL's dataset name for one layer.
    const auto audit = run_cli("audit footprints --pred GPKG:" + two + ":parcels --ref " + (dir / "mz.geojson") + " --out " + (dir / "audit"));
    INFO(audit.err);
    CHECK(audit.exit_code == 0);
}

// ---------------------------------------------------------------- the README's promises not tested elsewhere

TEST_CASE("Promises: inputs that are refused in one line with nothing written - out of memory exits 3", "[inputs][promises]") {
    ScratchDir dir("inputs_promises");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    const std::string fp = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    auto refused = [&](const std::string& args, const std::string& why, const std::string& out) {
        const auto r = run_cli("--quiet " + args + " --out " + out);
        INFO(args << "\n" << r.err);
        CHECK(r.exit_code == 1);
        CHECK(count_lines(r.err) == 1);
        CHECK(r.err.find(why) != std::string::npos);
        CHECK_FALSE(std::filesystem::exists(out));
    };
    // A cloud in a geographic CRS (heights need metres).
    refused("heights --footprints " + fp + " --cloud " + delft + " --cloud-crs EPSG:4326", "geographic CRS", dir / "geo.gpkg");
    // Footprints in a geographic CRS (a GeoJSON without a crs member is RFC 7946 lon/lat), and without any CRS.
    write_squares(dir / "sq.geojson", {{84905.0, 447560.0}});
    json lonlat = json::parse(slurp(dir / "sq.geojson"));
    lonlat.erase("crs");
    std::ofstream(dir / "lonlat.geojson") << lonlat.dump();
    // (lon/lat footprints are worked on in the cloud's CRS; these numbers are no longitudes and latitudes)
    refused("heights --footprints " + (dir / "lonlat.geojson") + " --cloud " + delft + " --cloud-crs EPSG:7415", "are not longitudes and latitudes", dir / "ll.gpkg");
    REQUIRE(run_command("ogr2ogr -f CSV -lco GEOMETRY=AS_WKT " + (dir / "nocrs.csv") + " " + (dir / "sq.geojson")).exit_code == 0);
    refused("roofs --footprints " + (dir / "nocrs.csv") + " --cloud " + delft + " --cloud-crs EPSG:7415", "CRS", dir / "roofs");
    // `footprints` that find no building: a featureless raster gives no file, not an empty one.
    REQUIRE(run_command("gdal_create -of GTiff -outsize 200 200 -bands 3 -burn 128 -a_srs EPSG:28992 -a_ullr 84900 447600 85000 447500 " +
                        (dir / "flat.tif")).exit_code == 0);
    refused("footprints --ortho " + (dir / "flat.tif"), "no building found", dir / "none.gpkg");
    // Out of memory is exit 3 with one line, not a crash (a 1 cm grid over Delft under a 1.5 GB address-space limit).
    const auto oom = run_command("bash -c \"" + cityforge::test::address_space_limit(1500000) + cityforge::test::cli() + " cloud rasterize --quiet --cloud " + delft +
                                 " --cloud-crs EPSG:7415 --gsd 0.01 --out " + (dir / "oom") + "\"");
    INFO(oom.err);
    CHECK(oom.exit_code == 3);
    CHECK(count_lines(oom.err) == 1);
}

namespace {
// Number of footprints and their summed area_m2 (ogrinfo SQL), to compare runs.
std::pair<int, double> count_and_area(const std::string& path) {
    const auto r = run_command("ogrinfo -q -ro " + path + " -sql \"SELECT COUNT(*) AS n, SUM(area_m2) AS a FROM buildings\"");
    const std::size_t n = r.out.find("n (Integer) = "), a = r.out.find("a (Real) = ");
    REQUIRE(n != std::string::npos);
    REQUIRE(a != std::string::npos);
    return {std::stoi(r.out.substr(n + 14)), std::stod(r.out.substr(a + 11))};
}
}  // namespace

TEST_CASE("GeoTIFFs with an alpha band, an internal mask band and internal overviews give the same footprints", "[inputs][corpus][raster]") {
    ScratchDir dir("inputs_masks");
    const std::string kampala = shared_data("oam_kampala_rgba/kampala_z19_east_rgba.tif");
    // The OpenAerialMap RGBA as delivered (band 4 = alpha, 0 where the drone saw nothing) ...
    const json i = info_json(kampala);
    REQUIRE(i["bands"].size() == 4);
    // ... the same as RGB with an internal mask band (GDAL_TIFF_INTERNAL_MASK), and that file with internal overviews.
    REQUIRE(run_command("gdal_translate -q -b 1 -b 2 -b 3 -mask 4 --config GDAL_TIFF_INTERNAL_MASK YES -co COMPRESS=DEFLATE " + kampala + " " +
                        (dir / "mask.tif")).exit_code == 0);
    REQUIRE(run_command("cp " + (dir / "mask.tif") + " " + (dir / "ovr.tif") + " && gdaladdo -q -r average " + (dir / "ovr.tif") + " 2 4 8")
                .exit_code == 0);
    REQUIRE(run_command("gdalinfo " + (dir / "ovr.tif")).out.find("Overviews:") != std::string::npos);
    REQUIRE(run_command("gdalinfo " + (dir / "mask.tif")).out.find("PER_DATASET") != std::string::npos);
    // ... and RGB with the mask thrown away (what a reader that ignores masks sees).
    REQUIRE(run_command("gdal_translate -q -b 1 -b 2 -b 3 -mask none -co COMPRESS=DEFLATE " + kampala + " " + (dir / "rgb.tif")).exit_code == 0);
    std::map<std::string, std::pair<int, double>> got;
    for (const char* name : {"rgba", "mask", "ovr", "rgb"}) {
        const std::string in = std::string(name) == "rgba" ? kampala : dir / (std::string(name) + ".tif");
        const auto r = run_cli("footprints --quiet --ortho " + in + " --out " + (dir / (std::string(name) + ".gpkg")));
        INFO(name << ": " << r.err);
        REQUIRE(r.exit_code == 0);
        got[name] = count_and_area(dir / (std::string(name) + ".gpkg"));
    }
    CHECK(got["mask"] == got["rgba"]);  // the alpha band is a mask, not a fourth colour
    CHECK(got["ovr"] == got["mask"]);   // overviews are not read in place of the full resolution
    CHECK(got["rgb"] != got["mask"]);   // and the mask does change what is found
}

TEST_CASE("A raster in feet (Autzen ortho, EPSG:2994, 1 ft pixels): GSD and areas in metres, output in feet", "[inputs][corpus][raster]") {
    ScratchDir dir("inputs_feet");
    // 700 x 700 px (213 m) of the PDAL Autzen ortho around the practice halls, still EPSG:2994 in international feet.
    REQUIRE(run_command("gdal_translate -q -srcwin 1300 2300 700 700 " + shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif") + " " +
                        (dir / "autzen.tif")).exit_code == 0);
    const json i = info_json(dir / "autzen.tif");
    CHECK(i["gsd_m"]["x"].get<double>() == Approx(0.3048).epsilon(1e-6));
    const auto r = run_cli("footprints --quiet --ortho " + (dir / "autzen.tif") + " --out " + (dir / "fp.gpkg"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(info_json(dir / "fp.gpkg")["layers"][0]["crs"]["epsg"] == 2994);
    // The window is mostly trees, dry grass and a paved yard (looked at): the
    // fine RGB model (0.3 m; session 15, 3 December 2026) finds one roof-like
    // 103 m² piece at its edge, where the joint model of 2 December found 72 m²
    // (the model before it 166 m² in three, two of them false). What is
    // checked here is the unit of what is found.
    const auto [area, geodesic] = area_sums(dir / "fp.gpkg");
    CHECK(area > 20.0);
    CHECK(area == Approx(geodesic).epsilon(0.01));  // m², not ft² (x10.76)
}

// ---------------------------------------------------------------- re-runs on our own output

TEST_CASE("Every command runs again on its own output, and again with --overwrite to the same bytes", "[inputs][rerun]") {
    ScratchDir dir("inputs_idempotent");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    const std::string fp = dir / "fp.gpkg";
    REQUIRE(run_command("ogr2ogr -f GPKG -nln footprints -limit 12 " + fp + " " +
                        shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson")).exit_code == 0);
    auto ok = [](const cityforge::test::CommandResult& r) {
        INFO(r.err);
        REQUIRE(r.exit_code == 0);
    };
    // footprints, rasterize, translate, audit: the same command again with --overwrite gives the same bytes.
    const std::string rio = shared_data("spacenet1_rio_rgb/3band_013022223130_Public_img51_rgb.tif");
    ok(run_cli("footprints --quiet --ortho " + rio + " --out " + (dir / "fp.geojson")));
    const std::string fp1 = slurp(dir / "fp.geojson");
    ok(run_cli("footprints --quiet --overwrite --ortho " + rio + " --out " + (dir / "fp.geojson")));
    CHECK(slurp(dir / "fp.geojson") == fp1);
    ok(run_cli("cloud rasterize --quiet --cloud " + delft + " --cloud-crs EPSG:7415 --gsd 2 --out " + (dir / "r")));
    const std::string dsm = slurp(dir / "r/dsm.tif");
    ok(run_cli("cloud rasterize --quiet --overwrite --cloud " + delft + " --cloud-crs EPSG:7415 --gsd 2 --out " + (dir / "r")));
    CHECK(slurp(dir / "r/dsm.tif") == dsm);
    // translate: of its own output, the same file (header, VLRs and records kept).
    const std::string las = shared_data("laz_corpus/reference_las/point-color.las");
    ok(run_cli("cloud translate --quiet " + las + " " + (dir / "t1.las")));
    ok(run_cli("cloud translate --quiet " + (dir / "t1.las") + " " + (dir / "t2.las")));
    CHECK(slurp(dir / "t2.las") == slurp(dir / "t1.las"));
    ok(run_cli("audit footprints --pred " + (dir / "fp.geojson") + " --ref " + (dir / "fp.geojson") + " --out " + (dir / "a")));
    const json a1 = json::parse(slurp(dir / "a/report.json"));
    ok(run_cli("audit footprints --overwrite --pred " + (dir / "fp.geojson") + " --ref " + (dir / "fp.geojson") + " --out " + (dir / "a")));
    CHECK(json::parse(slurp(dir / "a/report.json"))["totals"] == a1["totals"]);
    CHECK(a1["totals"]["f1"] == 1.0);

    // roofs and run on their own buildings.gpkg: the same buildings and fields again.
    ok(run_cli("roofs --quiet --footprints " + fp + " --cloud " + delft + " --cloud-crs EPSG:7415 --formats gpkg --out " + (dir / "roofs1")));
    ok(run_cli("roofs --quiet --footprints " + (dir / "roofs1/buildings.gpkg") + " --cloud " + delft + " --cloud-crs EPSG:7415 --formats gpkg --out " +
               (dir / "roofs2")));
    CHECK(layer_fields(dir / "roofs2/buildings.gpkg") == layer_fields(dir / "roofs1/buildings.gpkg"));
    CHECK(info_json(dir / "roofs2/buildings.gpkg")["layers"][0]["feature_count"] == 12);
    ok(run_cli("run --quiet --footprints " + fp + " --cloud " + delft + " --cloud-crs EPSG:7415 --formats gpkg --out " + (dir / "run1")));
    ok(run_cli("run --quiet --footprints " + (dir / "run1/buildings.gpkg") + " --cloud " + delft + " --cloud-crs EPSG:7415 --formats gpkg --out " +
               (dir / "run2")));
    CHECK(layer_fields(dir / "run2/buildings.gpkg") == layer_fields(dir / "run1/buildings.gpkg"));
    const std::string heights_sql = " -sql \"SELECT cityforge_id, height_m, roof_type FROM buildings ORDER BY cityforge_id\"";
    CHECK(run_command("ogrinfo -q -ro " + (dir / "run2/buildings.gpkg") + heights_sql).out ==
          run_command("ogrinfo -q -ro " + (dir / "run1/buildings.gpkg") + heights_sql).out);
    // A run folder is where a run resumes: the same command again keeps its tiles and gives the same model.
    const std::string model = slurp(dir / "run1/buildings.gpkg");
    ok(run_cli("run --quiet --footprints " + fp + " --cloud " + delft + " --cloud-crs EPSG:7415 --formats gpkg --out " + (dir / "run1")));
    CHECK(info_json(dir / "run1/buildings.gpkg")["layers"][0]["feature_count"] == 12);
}

// ---------------------------------------------------------------- lon/lat footprints and Web Mercator volumes

TEST_CASE("Lon/lat footprints (as OpenStreetMap extracts are) work in heights, roofs and run, on the cloud's projected CRS",
          "[inputs][geographic][cli]") {
    ScratchDir dir("inputs_lonlat_footprints");
    const std::string data = shared_data("delft_ahn3_bgt_west");
    const std::string rd = data + "/bgt_pand_west_with_ref_heights.geojson", cloud = data + "/ahn3_delft_west.las";
    const std::string ll = dir / "fp4326.gpkg";
    REQUIRE(run_command("ogr2ogr -t_srs EPSG:4326 " + ll + " " + rd).exit_code == 0);
    auto mean_height = [](const std::string& gpkg) {
        const auto r = run_command("ogrinfo -q -ro " + gpkg + " -sql \"SELECT avg(height_m) AS h, count(*) AS n FROM buildings\"");
        const std::size_t at = r.out.find("h (Real) = ");
        REQUIRE(at != std::string::npos);
        return std::stod(r.out.substr(at + 11));
    };
    const auto a = run_cli("heights --footprints " + rd + " --cloud " + cloud + " --cloud-crs EPSG:7415 --out " + (dir / "rd.gpkg"));
    REQUIRE(a.exit_code == 0);
    const auto b = run_cli("heights --footprints " + ll + " --cloud " + cloud + " --cloud-crs EPSG:7415 --out " + (dir / "ll.gpkg"));
    INFO(b.err);
    REQUIRE(b.exit_code == 0);
    CHECK(b.err.find("worked on and written in EPSG:28992") != std::string::npos);  // the cloud's CRS, not a third one
    CHECK(mean_height(dir / "ll.gpkg") == Approx(mean_height(dir / "rd.gpkg")).margin(0.002));
    CHECK(run_command("gdalsrsinfo -o epsg " + (dir / "ll.gpkg")).out.find("EPSG:7415") != std::string::npos);  // RD New + NAP, the cloud's
    // roofs and run take them too (run without an ortho: the grid is laid on the same CRS).
    const auto r = run_cli("roofs --quiet --footprints " + ll + " --cloud " + cloud + " --cloud-crs EPSG:7415 --out " + (dir / "roofs"));
    INFO(r.err);
    CHECK(r.exit_code == 0);
    const auto run = run_cli("run --quiet --footprints " + ll + " --cloud " + cloud + " --cloud-crs EPSG:7415 --out " + (dir / "run"));
    INFO(run.err);
    REQUIRE(run.exit_code == 0);
    const json rep = json::parse(slurp(dir / "run/run_report.json"));
    CHECK(rep.dump().find("28992") != std::string::npos);
    CHECK(count_lines(slurp(dir / "run/buildings.city.jsonl")) == 136);  // metadata + 135 buildings
    // Without a CRS from the cloud, the UTM zone of the footprints' centre (Delft: 31N).
    const auto utm = run_cli("heights --footprints " + ll + " --cloud " + cloud + " --cloud-crs EPSG:7415 --out " + (dir / "utm.gpkg") + " --overwrite");
    CHECK(utm.exit_code == 0);
}

TEST_CASE("Web Mercator models: volumes in ground cubic metres (the grid metre is 1/cos(latitude) ground metres)",
          "[inputs][geographic][cli]") {
    ScratchDir dir("inputs_webmercator_volume");
    // A town laid out on EPSG:3857 at 60 deg N, where one grid metre is 0.5 ground metres.
    REQUIRE(run_cli("synth --quiet --out " + (dir / "s") + " --size-m 120 --epsg 3857 --origin 1113195 8399737 --seed 3").exit_code == 0);
    REQUIRE(run_cli("heights --quiet --footprints " + (dir / "s/truth.geojson") + " --cloud " + (dir / "s/cloud.las") + " --out " +
                    (dir / "h.gpkg")).exit_code == 0);
    REQUIRE(run_cli("export --quiet --in " + (dir / "h.gpkg") + " --out " + (dir / "m") + " --formats geojson,cityjson").exit_code == 0);
    const json fc = json::parse(slurp(dir / "m/buildings.geojson"));
    REQUIRE(!fc["features"].empty());
    std::size_t checked = 0;
    for (const json& f : fc["features"]) {
        const json& p = f["properties"];
        if (p["lod1_volume_m3"].is_null() || p["height_m"].is_null()) continue;
        // The prism's volume: nominal area (the footprint's grid area, area_m2 of the synthetic truth) x 0.25 x height.
        const double nominal = p["area_m2"].get<double>(), h = p["height_m"].get<double>();
        CHECK(p["lod1_volume_m3"].get<double>() == Approx(nominal * 0.25 * h).epsilon(0.01));
        ++checked;
    }
    CHECK(checked > 3);
}

TEST_CASE("A lon/lat ortho with a cloud (ortho_cloud footprints) finds what the projected ortho finds", "[inputs][geographic][cli]") {
    ScratchDir dir("inputs_lonlat_ortho_cloud");
    REQUIRE(run_cli("synth --quiet --out " + (dir / "s") + " --size-m 150 --seed 4").exit_code == 0);
    // The ortho warped to EPSG:4326 (the warped grid read back on UTM carries the warper's alpha band).
    REQUIRE(run_command("gdalwarp -q -t_srs EPSG:4326 " + (dir / "s/ortho.tif") + " " + (dir / "lonlat.tif")).exit_code == 0);
    const auto utm = run_cli("footprints --quiet --ortho " + (dir / "s/ortho.tif") + " --cloud " + (dir / "s/cloud.las") + " --out " + (dir / "utm.gpkg"));
    REQUIRE(utm.exit_code == 0);
    const auto ll = run_cli("footprints --quiet --ortho " + (dir / "lonlat.tif") + " --cloud " + (dir / "s/cloud.las") + " --out " + (dir / "ll.gpkg"));
    INFO(ll.err);
    REQUIRE(ll.exit_code == 0);
    auto count_area = [](const std::string& gpkg) {
        const auto r = run_command("ogrinfo -q -ro " + gpkg + " -sql \"SELECT count(*) AS n, sum(area_m2) AS a FROM buildings\"");
        const std::size_t n = r.out.find("n (Integer) = "), a = r.out.find("a (Real) = ");
        REQUIRE(n != std::string::npos);
        REQUIRE(a != std::string::npos);
        return std::make_pair(std::stoi(r.out.substr(n + 14)), std::stod(r.out.substr(a + 11)));
    };
    const auto [n_utm, a_utm] = count_area(dir / "utm.gpkg");
    const auto [n_ll, a_ll] = count_area(dir / "ll.gpkg");
    CHECK(n_utm > 10);
    CHECK(n_ll == n_utm);
    CHECK(a_ll == Approx(a_utm).epsilon(0.01));
    CHECK(info_json(dir / "ll.gpkg")["layers"][0]["crs"]["epsg"] == 4326);  // written in the input's CRS
}

TEST_CASE("run: inputs that do not overlap are one-line errors naming both files and extents - partial overlap warns", "[inputs][overlap][cli]") {
    ScratchDir dir("inputs_run_overlap");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    const std::string fp = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    // Delft footprints with Autzen's cloud (in feet, Oregon).
    const auto a = run_cli("run --quiet --footprints " + fp + " --cloud " + shared_data("laz_corpus/autzen_trim.laz") + " --out " + (dir / "a"));
    INFO(a.err);
    CHECK(a.exit_code == 1);
    CHECK(count_lines(a.err) == 1);
    CHECK(a.err.find("autzen_trim.laz: does not overlap") != std::string::npos);
    CHECK(a.err.find("bgt_pand_west_with_ref_heights.geojson 84") != std::string::npos);  // its extent, in the grid's CRS
    CHECK_FALSE(std::filesystem::exists(dir / "a/buildings.gpkg"));
    // An ortho in Atlanta with the Delft cloud.
    const auto b = run_cli("run --quiet --ortho " + shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif") + " --cloud " + delft +
                           " --cloud-crs EPSG:7415 --out " + (dir / "b"));
    INFO(b.err);
    CHECK(b.exit_code == 1);
    CHECK(b.err.find("does not overlap") != std::string::npos);
    CHECK(b.err.find("atlanta_pan_0p5m_west.tif 733") != std::string::npos);
    // One footprint over the cloud, one 5 km away: a warning with the count, the run goes on.
    write_squares(dir / "two.geojson", {{84905.0, 447560.0}, {89905.0, 447560.0}});
    const auto c = run_cli("run --footprints " + (dir / "two.geojson") + " --cloud " + delft + " --cloud-crs EPSG:7415 --out " + (dir / "c"));
    INFO(c.err);
    CHECK(c.exit_code == 0);
    CHECK(c.err.find("1 of 2 footprints lie outside the cloud") != std::string::npos);
}

TEST_CASE("A compound CRS keeps its EPSG code: our GeoTIFFs and GeoKeys clouds give EPSG:7415 outputs", "[inputs][crs]") {
    ScratchDir dir("inputs_compound_7415");
    const std::string delft = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    // A GeoTIFF we write under EPSG:7415 reads back (here and in GDAL) as EPSG:7415, not as a user-defined CRS.
    const auto r = run_cli("cloud rasterize --quiet --cloud " + delft + " --cloud-crs EPSG:7415 --gsd 2 --out " + (dir / "r"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    const json d = info_json(dir / "r/dsm.tif");
    CHECK(d["crs"]["epsg"] == 7415);
    CHECK(d["crs"]["horizontal_epsg"] == 28992);
    CHECK(d["crs"]["vertical_epsg"] == 5709);
    CHECK(run_command("gdalsrsinfo -o epsg " + (dir / "r/dsm.tif")).out.find("EPSG:7415") != std::string::npos);
    // A GeoKeys-only cloud (28992 + vertical 5709) resolves to EPSG:7415 itself: footprints from it go to GeoPackage as 7415.
    write_geokeys_only_copy(delft, dir / "geokeys.las");
    CHECK(info_json(dir / "geokeys.las")["crs"]["epsg"] == 7415);
    const auto f = run_cli("footprints --quiet --cloud " + (dir / "geokeys.las") + " --out " + (dir / "fp.gpkg"));
    INFO(f.err);
    REQUIRE(f.exit_code == 0);
    const auto srs = run_command("ogrinfo -q -ro " + (dir / "fp.gpkg") + " -sql \"SELECT srs_id FROM gpkg_contents\"");
    CHECK(srs.out.find("srs_id (Integer64) = 7415") != std::string::npos);
    CHECK(run_command("gdalsrsinfo -o epsg " + (dir / "fp.gpkg")).out.find("EPSG:7415") != std::string::npos);
    // An ortho made from our DSM (gdal_translate keeps its CRS) gives footprints under 7415 too.
    REQUIRE(run_command("gdal_translate -q -ot Byte -scale -a_nodata none -b 1 -b 1 -b 1 " + (dir / "r/dsm.tif") + " " + (dir / "ortho.tif"))
                .exit_code == 0);
    CHECK(info_json(dir / "ortho.tif")["crs"]["epsg"] == 7415);
    const auto o = run_cli("footprints --quiet --ortho " + (dir / "ortho.tif") + " --out " + (dir / "fo.gpkg"));
    INFO(o.err);
    REQUIRE(o.exit_code == 0);
    CHECK(run_command("ogrinfo -q -ro " + (dir / "fo.gpkg") + " -sql \"SELECT srs_id FROM gpkg_contents\"").out.find("srs_id (Integer64) = 7415") !=
          std::string::npos);
    const auto e = run_cli("export --quiet --in " + (dir / "fp.gpkg") + " --formats citygml,cityjson --out " + (dir / "e"));
    INFO(e.err);
    REQUIRE(e.exit_code == 0);
    CHECK(slurp(dir / "e/buildings_lod1.gml").find("srsName=\"urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709\"") != std::string::npos);
    CHECK(json::parse(slurp(dir / "e/buildings.city.json"))["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/7415");
}

TEST_CASE("City models in a CRS without an EPSG code are written, with a warning, not failed half-way", "[inputs][crs]") {
    ScratchDir dir("inputs_crs_no_code");
    write_squares(dir / "sq.geojson", {{84905.0, 447560.0}, {84925.0, 447560.0}}, 4.0, R"({"ground_z": 0.5, "height_m": 6.0})");
    // RD New's parameters as a PROJ string: no EPSG code to name.
    REQUIRE(run_command("ogr2ogr -q -a_srs \"+proj=sterea +lat_0=52.1561605555556 +lon_0=5.38763888888889 +k=0.9999079 +x_0=155000 "
                        "+y_0=463000 +ellps=bessel +units=m +no_defs\" " + (dir / "custom.gpkg") + " " + (dir / "sq.geojson"))
                .exit_code == 0);
    const auto e = run_cli("export --in " + (dir / "custom.gpkg") + " --formats gpkg,citygml,cityjson --out " + (dir / "e"));
    INFO(e.err);
    REQUIRE(e.exit_code == 0);
    CHECK(e.err.find("has no EPSG code") != std::string::npos);
    CHECK(e.err.find("+proj=sterea") != std::string::npos);  // the warning says what the CRS is
    const std::string gml = slurp(dir / "e/buildings_lod1.gml");
    CHECK(gml.find("srsName") == std::string::npos);
    CHECK(gml.find("+proj=sterea") != std::string::npos);  // named in the header comment
    CHECK(gml.find("<bldg:lod1Solid>") != std::string::npos);
    const json cj = json::parse(slurp(dir / "e/buildings.city.json"));
    CHECK_FALSE(cj["metadata"].contains("referenceSystem"));
    CHECK(cj["CityObjects"].size() == 2);
    CHECK(std::filesystem::exists(dir / "e/buildings.gpkg"));
}

TEST_CASE("A sparse cloud the outlier filter empties is said to be so, not to miss the footprints", "[inputs][overlap]") {
    ScratchDir dir("inputs_sparse_cloud");
    // PDAL's point-color.las: 1065 points over about 1.4 km² (EPSG:26910); a 600 m square over it.
    json fc{{"type", "FeatureCollection"}, {"crs", {{"type", "name"}, {"properties", {{"name", "urn:ogc:def:crs:EPSG::26910"}}}}}};
    fc["features"] = json::array({json{{"type", "Feature"}, {"properties", {{"name", "a"}}},
                                       {"geometry", {{"type", "Polygon"},
                                                     {"coordinates", json::array({json::array({json::array({494200, 4877800}), json::array({494800, 4877800}),
                                                                                               json::array({494800, 4878400}), json::array({494200, 4878400}),
                                                                                               json::array({494200, 4877800})})})}}}}});
    std::ofstream(dir / "sq.geojson") << fc.dump();
    const std::string cloud = shared_data("laz_corpus/reference_las/point-color.las");
    const auto a = run_cli("heights --quiet --footprints " + (dir / "sq.geojson") + " --cloud " + cloud + " --out " + (dir / "a.gpkg"));
    INFO(a.err);
    CHECK(a.exit_code == 1);
    CHECK(count_lines(a.err) == 1);
    CHECK(a.err.find("all 1065 points were removed as outliers") != std::string::npos);
    CHECK(a.err.find("--no-outlier-filter") != std::string::npos);
    CHECK(a.err.find("no footprint overlaps") == std::string::npos);
    const auto b = run_cli("heights --quiet --no-outlier-filter --footprints " + (dir / "sq.geojson") + " --cloud " + cloud + " --out " + (dir / "b.gpkg"));
    INFO(b.err);
    CHECK(b.exit_code == 0);
}

TEST_CASE("run on a lon/lat ortho without a cloud: no false warnings, the page shows the ortho", "[inputs][geographic][run]") {
    ScratchDir dir("inputs_rio_warnings");
    const std::string rio = shared_data("spacenet1_rio_rgb/3band_013022223130_Public_img51_rgb.tif");
    const auto r = run_cli("run --ortho " + rio + " --out " + (dir / "rio"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(r.err.find("does not overlap") == std::string::npos);  // the viewer's quicklook is warped onto the model's UTM
    CHECK(r.err.find("no field 'ground_z'") == std::string::npos);  // "no cloud" says it once
    CHECK(r.err.find("no cloud") != std::string::npos);
    const std::string page = slurp(dir / "rio/view/index.html");
    CHECK(page.find("\"ortho\":{") != std::string::npos);
}
