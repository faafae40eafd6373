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
[[maybe_unused]] void write_squares(const std::string& path, const std::vector<std::pair<double, double>>& centres, double half = 4.0,
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

[[maybe_unused]] std::vector<std::string> layer_fields(const std::string& path) {
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
