#include <catch2/catch.hpp>

#include "core/error.hpp"
#include "io/inspect.hpp"
#include "io/vector.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

TEST_CASE("Vector info of real footprint files", "[io][real]") {
    const VectorInfo atl = read_vector_info(shared_data("spacenet4_atlanta_pan_west/buildings_west.geojson"));
    REQUIRE(atl.layers.size() == 1);
    CHECK(atl.layers[0].feature_count == 25);
    CHECK(atl.layers[0].crs.horizontal_epsg == 32616);
    const VectorInfo delft = read_vector_info(shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson"));
    CHECK(delft.layers[0].feature_count == 135);
    CHECK(delft.layers[0].crs.horizontal_epsg == 28992);
    const auto& f = delft.layers[0].fields;
    CHECK(std::find(f.begin(), f.end(), "ref_height_m") != f.end());
}

TEST_CASE("Polygons with holes round-trip through GeoJSON and GeoPackage", "[io]") {
    ScratchDir dir("vector_rt");
    const CrsInfo crs = crs_from_user_input("EPSG:28992", "test");
    Feature f;
    Polygon p;
    p.outer = {{0, 0}, {0, 10}, {10, 10}, {10, 0}};  // clockwise on purpose
    p.holes = {{{2, 2}, {4, 2}, {4, 4}, {2, 4}}};
    orient_polygon(p);
    CHECK(signed_area(p.outer) > 0);
    CHECK(signed_area(p.holes[0]) < 0);
    CHECK(polygon_area(p) == Approx(96.0));
    CHECK(point_in_polygon(p, 1, 1));
    CHECK_FALSE(point_in_polygon(p, 3, 3));
    CHECK(distance_to_boundary(p, 5, 5) == Approx(std::sqrt(2.0)));  // to the hole corner (4, 4)
    f.geometry = {p};
    f.values = {int64_t(7), 12.5, std::string("gable"), std::monostate{}};
    const std::vector<FieldDefinition> fields{{"id", FieldType::integer}, {"height_m", FieldType::real},
                                              {"roof", FieldType::string}, {"missing", FieldType::real}};
    write_polygon_features(dir / "a.geojson", crs, fields, {f});
    VectorWriteOptions gpkg;
    gpkg.driver = "GPKG";
    write_polygon_features(dir / "a.gpkg", crs, fields, {f}, gpkg);
    for (const std::string name : {"a.geojson", "a.gpkg"}) {
        const VectorInfo v = read_vector_info(dir / name);
        REQUIRE(v.layers.size() == 1);
        CHECK(v.layers[0].name == "buildings");
        CHECK(v.layers[0].feature_count == 1);
        CHECK(v.layers[0].crs.horizontal_epsg == 28992);
        CHECK(v.layers[0].fields.size() == 4);
        const PolygonLayer back = read_polygon_layer(dir / name);
        REQUIRE(back.features.size() == 1);
        CHECK(polygon_area(back.features[0].geometry[0]) == Approx(96.0));
        CHECK(back.features[0].geometry[0].holes.size() == 1);
    }
}

TEST_CASE("inspect_dataset tells rasters - clouds and vectors apart", "[io]") {
    CHECK(inspect_dataset(shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif")).raster);
    CHECK(inspect_dataset(shared_data("autzen_oregon/autzen_trim.las")).cloud);
    CHECK(inspect_dataset(shared_data("autzen_oregon/autzen_coarse_class_polygons.geojson")).vector);
    InspectOptions o;
    o.assume_crs = "EPSG:7415";
    o.cloud_statistics = true;
    const DatasetInfo d = inspect_dataset(shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), o);
    REQUIRE(d.cloud);
    CHECK(d.cloud->crs.vertical_epsg == 5709);
    CHECK(d.cloud->class_counts.at(6) == 258469);
    CHECK(d.cloud->class_counts.at(2) == 209546);
    const auto j = to_json(d);
    CHECK(j["kind"] == "point_cloud");
    CHECK(j["crs"]["horizontal_epsg"] == 28992);
    CHECK_THROWS_WITH(inspect_dataset(test::source_dir() + "/CMakeLists.txt"), Catch::Contains("CMakeLists.txt") && Catch::Contains("not a raster"));
}
