#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <map>

#include "io/vector.hpp"
#include <nlohmann/json.hpp>

#include "model/cgal_solid_check.hpp"
#include "pipeline/roofs_run.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;
using test::shared_data;

TEST_CASE("roofs on a synthetic town (lidar) - roof types against the truth - valid LOD2 in CityGML and CityJSON", "[roof][pipeline]") {
    ScratchDir dir("roofs_synth");
    const SynthResult s = test::make_town(dir, 400, 3, 8.0);
    const auto cli = test::run_cli("roofs --footprints " + s.truth_path + " --cloud " + s.cloud_path + " --out " + (dir / "out") +
                                   " --vertical-crs EPSG:5773 --formats geojson,citygml,cityjson");
    INFO(cli.err);
    REQUIRE(cli.exit_code == 0);
    const auto truth = nlohmann::json::parse(test::slurp(s.truth_path));
    std::map<int64_t, std::string> roof_of;
    for (const auto& f : truth["features"]) roof_of[f["properties"]["id"].get<int64_t>()] = f["properties"]["roof_type"].get<std::string>();
    const auto out = nlohmann::json::parse(test::slurp(dir / "out/buildings.geojson"));
    int correct = 0, total = 0, valid = 0;
    for (const auto& f : out["features"]) {
        const auto& p = f["properties"];
        ++total;
        correct += p["roof_type"] == roof_of.at(p["id"].get<int64_t>());
        valid += p["lod2_valid"] == 1;
        if (p["lod2_kind"] == "LOD2.2 roof planes") CHECK(p["lod2_median_residual_m"].get<double>() < 0.1);
    }
    CHECK(total == s.buildings);
    CHECK(valid == total);
    CHECK(double(correct) / total >= 0.9);
    CHECK(test::run_command("xmllint --noout --nonet --schema " + shared_data("citygml2_schemas/CityGML.xsd") + " " + (dir / "out/buildings_lod2.gml")).exit_code == 0);
    const std::string lod2 = test::slurp(dir / "out/buildings_lod2.gml");
    CHECK(lod2.find("<bldg:RoofSurface") != std::string::npos);
    CHECK(lod2.find("<bldg:roofType>gable</bldg:roofType>") != std::string::npos);
    std::vector<std::string> parts;
    for (const char* n : {"cityobjects.schema.json", "geomprimitives.schema.json", "appearance.schema.json", "geomtemplates.schema.json", "metadata.schema.json"})
        parts.push_back(shared_data(std::string("cityjson/schemas-2.0.2/") + n));
    CHECK(test::validate_json(shared_data("cityjson/schemas-2.0.2/cityjson.schema.json"), dir / "out/buildings.city.json", parts).exit_code == 0);
}

TEST_CASE("roofs on Delft AHN3 - every solid valid - roof types found (regression guard)", "[roof][pipeline][real]") {
    ScratchDir dir("roofs_delft");
    RoofsRunOptions o;
    o.heights.cloud_crs = "EPSG:7415";
    o.model.formats = {"gpkg", "cityjson"};
    o.model.id_field = "gml_id";
    const RoofsRunReport r = run_roofs(shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson"),
                                       shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), dir / "out", o);
    CHECK(r.model.buildings == 135);
    CHECK(r.model.with_lod2 == 135);
    CHECK(r.model.valid_lod2 == 135);
    CHECK(r.lod2 == 135);  // no fallback on these valid footprints (131 before the alternative plane settings, 126 before the retried partitions)
    CHECK(r.fallbacks == 0);
    CHECK(r.roof_types.count("gable") == 1);
    // Per-building RMSE (3-D point-to-model distance, as 3DBAG's b3_rmse_lod22) and fallback reasons.
    const PolygonLayer out = read_polygon_layer(dir / "out/buildings.gpkg", "");
    auto col = [&](const std::string& name) {
        const auto it = std::find(out.field_names.begin(), out.field_names.end(), name);
        REQUIRE(it != out.field_names.end());
        return static_cast<std::size_t>(it - out.field_names.begin());
    };
    const std::size_t rmse_col = col("lod2_rmse_m"), fb_col = col("lod2_fallback"), settings_col = col("lod2_plane_settings");
    int retried = 0;
    std::vector<double> rmse;
    int geometric_fallbacks = 0;
    for (const Feature& f : out.features) {
        if (std::holds_alternative<double>(f.values[rmse_col])) rmse.push_back(std::get<double>(f.values[rmse_col]));
        REQUIRE(std::holds_alternative<std::string>(f.values[settings_col]));
        retried += std::get<std::string>(f.values[settings_col]) != "default";
        if (std::holds_alternative<std::string>(f.values[fb_col])) {
            const std::string why = std::get<std::string>(f.values[fb_col]);
            INFO(why);
            CHECK(why.find("RING_SELF_INTERSECTION") == std::string::npos);  // 7 of these on valid footprints before
            geometric_fallbacks += why.find("invalid") != std::string::npos;
        }
    }
    REQUIRE(rmse.size() == 135);
    std::sort(rmse.begin(), rmse.end());
    const double median = 0.5 * (rmse[67] + rmse[67]);
    INFO("median LOD2 RMSE " << median << " m, p90 " << rmse[121] << " m");
    // 0.192 / 0.338 / 0.653 m when written; 0.206 / 0.361 / 0.733 m since the outlier filter keeps the
    // steep gables' points (4,557 class-6 points it removed before now count in the RMSE).
    CHECK(median <= 0.21);    // (0.198 before the alternatives; roofer on AHN4: 0.13-0.38 m per building on the 3DBAG sample)
    CHECK(rmse[121] <= 0.40); // p90 (0.458 m before the alternatives)
    CHECK(rmse.back() <= 0.80); // max
    CHECK(geometric_fallbacks == 0);
    CHECK(retried >= 15);       // 30 of 135 models come from an alternative plane setting
    CHECK(retried <= 45);

    // Refined LODs as written: every LOD1.2, LOD1.3 and LOD2.2 solid of the CityJSON file closed, manifold,
    // outward and free of self-intersections by CGAL (independent of validate_solid), and valid by ours;
    // stepped roofs split into BuildingParts whose LOD2.2 volumes add up to the building's LOD2 volume.
    std::vector<std::string> schemas;
    for (const char* n : {"cityobjects.schema.json", "geomprimitives.schema.json", "appearance.schema.json", "geomtemplates.schema.json", "metadata.schema.json"})
        schemas.push_back(shared_data(std::string("cityjson/schemas-2.0.2/") + n));
    CHECK(test::validate_json(shared_data("cityjson/schemas-2.0.2/cityjson.schema.json"), dir / "out/buildings.city.json", schemas).exit_code == 0);
    const auto cj = nlohmann::json::parse(test::slurp(dir / "out/buildings.city.json"));
    std::map<std::string, double> lod2_volume;  // from the GeoPackage, by building id
    const std::size_t id_col = col("cityforge_id"), v2_col = col("lod2_volume_m3");
    for (const Feature& f : out.features)
        if (std::holds_alternative<double>(f.values[v2_col])) lod2_volume[std::get<std::string>(f.values[id_col])] = std::get<double>(f.values[v2_col]);
    std::map<std::string, int> solids, cgal_ok, ours_ok;
    int split = 0, volume_kept = 0, with22 = 0, unsplit = 0;
    for (const auto& [id, obj] : cj["CityObjects"].items()) {
        for (const auto& g : obj["geometry"])
            for (const Solid& s : test::solids_from_cityjson(g, cj["vertices"], cj["transform"])) {
                const std::string lod = g["lod"];
                ++solids[lod];
                const std::string why = test::cgal_check_solid(s);
                INFO(id << " LOD " << lod << ": " << why);
                CHECK(why == "");
                cgal_ok[lod] += why.empty();
                ours_ok[lod] += validate_solid(s, {0.01, 1e-6, 1e-6}).empty();
            }
        if (obj["type"] != "Building" || !obj["attributes"].contains("lod22_parts")) continue;
        ++with22;
        split += obj["attributes"]["lod22_parts"].get<int>() > 1;
        unsplit += obj["attributes"].contains("lod22_unsplit");
        volume_kept += lod2_volume.count(id) && std::abs(obj["attributes"]["lod22_volume_m3"].get<double>() - lod2_volume[id]) < 1e-3;
    }
    INFO(split << " of " << with22 << " buildings split into roof parts");
    CHECK(solids["1.2"] == 135);
    CHECK(solids["2.2"] >= 135);
    CHECK(solids["1.3"] == solids["2.2"]);
    for (const char* lod : {"1.2", "1.3", "2.2"}) {
        CHECK(cgal_ok[lod] == solids[lod]);
        CHECK(ours_ok[lod] == solids[lod]);
    }
    CHECK(with22 == 135);
    CHECK(split >= 80);  // 86 of 135 (44 before the part walls took each outline edge's own end heights: 42 parts were not closed)
    CHECK(unsplit == 0);
    CHECK(volume_kept == with22);
}
