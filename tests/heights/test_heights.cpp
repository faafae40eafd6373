#include <catch2/catch.hpp>
#include <cmath>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <ogrsf_frmts.h>

#include "cloud/las.hpp"
#include "core/error.hpp"
#include "heights/building_heights.hpp"
#include "io/vector.hpp"
#include "pipeline/heights_run.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

namespace {
struct Row {
    std::map<std::string, std::string> text;
    std::map<std::string, std::optional<double>> num;
};
std::vector<Row> read_rows(const std::string& path) {
    std::vector<Row> rows;
    GDALDataset* ds = GDALDataset::Open(path.c_str(), GDAL_OF_VECTOR);
    REQUIRE(ds);
    OGRLayer* layer = ds->GetLayer(0);
    for (auto& f : *layer) {
        Row r;
        for (int i = 0; i < f->GetFieldCount(); ++i) {
            const std::string name = f->GetFieldDefnRef(i)->GetNameRef();
            r.text[name] = f->IsFieldSetAndNotNull(i) ? f->GetFieldAsString(i) : "";
            r.num[name] = f->IsFieldSetAndNotNull(i) ? std::optional<double>(f->GetFieldAsDouble(i)) : std::nullopt;
        }
        rows.push_back(std::move(r));
    }
    GDALClose(ds);
    return rows;
}
double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}
}  // namespace

TEST_CASE("percentile interpolates like NumPy", "[heights]") {
    std::vector<double> v{4, 1, 3, 2};
    CHECK(*percentile(v, 0) == 1.0);
    CHECK(*percentile(v, 100) == 4.0);
    CHECK(*percentile(v, 50) == 2.5);
    CHECK(*percentile(v, 90) == Approx(3.7));
    std::vector<double> empty;
    CHECK_FALSE(percentile(empty, 50));
}

TEST_CASE("A flat box gets its exact height - too few points give nulls with a flag", "[heights]") {
    PointCloud c;
    auto add = [&](double x, double y, double z, uint8_t cls) {
        c.x.push_back(x), c.y.push_back(y), c.z.push_back(z), c.classification.push_back(cls);
        c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
    };
    for (double x = -10; x <= 30; x += 0.5)
        for (double y = -10; y <= 30; y += 0.5) {
            const bool roof = x > 0 && x < 20 && y > 0 && y < 10;
            add(x, y, roof ? 112.0 : 100.0, roof ? las_class::building : las_class::ground);
        }
    Polygon box;
    box.outer = {{0, 0}, {20, 0}, {20, 10}, {0, 10}};
    Polygon tiny;  // over open ground with no roof points
    tiny.outer = {{25, 25}, {26, 25}, {26, 26}, {25, 26}};
    std::vector<uint8_t> ground(c.size());
    for (std::size_t i = 0; i < c.size(); ++i) ground[i] = c.classification[i] == las_class::ground;
    const auto h = compute_building_heights(c, {}, ground, {{box}, {tiny}}, HeightOptions{});
    REQUIRE(h.size() == 2);
    CHECK(*h[0].ground_z == Approx(100.0));
    CHECK(*h[0].height_m == Approx(12.0));
    CHECK(*h[0].roof_z_90p == Approx(112.0));
    CHECK(h[0].point_density_m2 == Approx(4.0).margin(0.3));
    CHECK(h[0].nodata_fraction == Approx(0.0));
    CHECK(h[0].height_quality == "good");
    CHECK_FALSE(h[1].height_m);
    CHECK(h[1].height_quality == "no_roof_points");
}

TEST_CASE("The ground ring widens to 6 and 12 m when the 3 m ring lacks ground - its points are exactly those within the ring - in metres and in feet", "[heights]") {
    // A 20 x 10 m roof at 112 m; around it a yard of non-ground points out to
    // `yard` metres, then ground on a tilted plane. Four buildings, far
    // apart: yards of 0 (3 m ring), 4 (6 m ring) and 8 m (12 m ring), and one
    // whose 3 m ring holds only 4 ground points (one short of 5: widened to
    // 6 m). The same scene in a CRS of international feet gives the same
    // rings and points, and the same heights in metres.
    for (const double unit : {1.0, 0.3048}) {
        INFO("CRS unit " << unit << " m");
        PointCloud c;
        auto add = [&](double x, double y, double z, uint8_t cls) {  // metres in, CRS units stored
            c.x.push_back(x / unit), c.y.push_back(y / unit), c.z.push_back(z / unit), c.classification.push_back(cls);
            c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
        };
        auto outside_distance = [](double x, double y, double x0, double y0) {  // metres, to the box [x0, x0+20] x [y0, y0+10]
            const double dx = std::max({x0 - x, 0.0, x - (x0 + 20)}), dy = std::max({y0 - y, 0.0, y - (y0 + 10)});
            return std::hypot(dx, dy);
        };
        struct Site { double x0, yard; int extra; double ring; };
        const std::vector<Site> sites{{0, 0, 0, 3}, {200, 4, 0, 6}, {400, 8, 0, 12}, {600, 4, 4, 6}};
        std::vector<std::vector<Polygon>> footprints;
        std::vector<uint8_t> ground;
        std::vector<double> mx, my;  // metres, per point
        for (const Site& s : sites) {
            // Points a quarter cell off the edges: none lies exactly at a ring's distance.
            for (double x = s.x0 - 19.75; x <= s.x0 + 40; x += 0.5)
                for (double y = -19.75; y <= 30; y += 0.5) {
                    const double d = outside_distance(x, y, s.x0, 0);
                    const bool roof = d == 0;
                    if (roof) add(x, y, 112.0, las_class::building);
                    else if (d > 0 && d <= s.yard) add(x, y, 100.0, 1);  // unclassified, not ground
                    else add(x, y, 100.0 + 0.02 * (x - s.x0) + 0.01 * y, las_class::ground);
                    mx.push_back(x), my.push_back(y);
                }
            for (int k = 0; k < s.extra; ++k) {
                add(s.x0 + 2 + 4 * k, -1.1, 100.0 + 0.02 * (2 + 4 * k) - 0.01, las_class::ground);
                mx.push_back(s.x0 + 2 + 4 * k), my.push_back(-1.1);
            }
            Polygon box;
            box.outer = {{s.x0 / unit, 0}, {(s.x0 + 20) / unit, 0}, {(s.x0 + 20) / unit, 10 / unit}, {s.x0 / unit, 10 / unit}};
            footprints.push_back({box});
        }
        for (std::size_t i = 0; i < c.size(); ++i) ground.push_back(c.classification[i] == las_class::ground);
        HeightOptions o;
        o.unit_m = o.z_unit_m = unit;
        const auto h = compute_building_heights(c, {}, ground, footprints, o);
        REQUIRE(h.size() == sites.size());
        for (std::size_t b = 0; b < sites.size(); ++b) {
            INFO("site " << b);
            const Site& s = sites[b];
            int64_t within = 0;  // ground points within the ring, counted directly
            for (std::size_t i = 0; i < c.size(); ++i) {
                const double d = outside_distance(mx[i], my[i], s.x0, 0);
                if (ground[i] && d > 0 && d <= s.ring) ++within;
            }
            CHECK(h[b].ground_buffer_used_m == Approx(s.ring));
            CHECK(h[b].n_points_ground == within);
            CHECK(h[b].height_quality == (s.ring == 3 ? "good" : "ground_buffer_widened"));
            REQUIRE(h[b].ground_z);
            CHECK(*h[b].ground_z * unit == Approx(100.0 + 0.02 * 10 + 0.01 * 5).margin(0.02));  // the plane at the centroid
            REQUIRE(h[b].height_m);
            CHECK(*h[b].height_m == Approx(112.0 - *h[b].ground_z * unit).margin(1e-6));
        }
    }
}

TEST_CASE("Delft AHN3 - roof p90 agrees with 3dfier's reference (median |diff| <= 0.40 m)", "[heights][real]") {
    ScratchDir dir("delft");
    HeightsRunOptions o;
    o.cloud_crs = "EPSG:7415";
    const auto rep = run_heights(shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson"),
                                 shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), dir / "delft.gpkg", o);
    CHECK(rep.buildings == 135);
    CHECK(rep.ground_from_classification);
    CHECK(rep.crs == "EPSG:28992+5709");
    const auto rows = read_rows(dir / "delft.gpkg");
    REQUIRE(rows.size() == 135);
    std::vector<double> roof, ground, height;
    for (const Row& r : rows) {
        REQUIRE(r.num.at("roof_z_90p"));
        roof.push_back(std::abs(*r.num.at("roof_z_90p") - std::stod(r.text.at("ref_roof_nap_m"))));
        ground.push_back(std::abs(*r.num.at("ground_z") - std::stod(r.text.at("ref_ground_nap_m"))));
        CHECK(r.text.at("z_crs") == "EPSG:5709");
    }
    INFO("median |roof p90 - ref| = " << median(roof) << ", median |ground (plane) - ref| = " << median(ground));
    CHECK(median(roof) <= 0.40);
    // 3dfier's reference ground is a low percentile of the ring: the plane
    // (the mean terrain under the footprint) sits a little above it ...
    CHECK(median(ground) <= 0.15);
    // ... and our percentile method reproduces 3dfier's convention.
    HeightsRunOptions po = o;
    po.heights.ground_method = GroundMethod::percentile;
    run_heights(shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson"), shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"),
                dir / "delft_pct.gpkg", po);
    std::vector<double> ground_pct;
    for (const Row& r : read_rows(dir / "delft_pct.gpkg")) {
        CHECK(r.text.at("ground_method") == "ring_percentile");
        ground_pct.push_back(std::abs(*r.num.at("ground_z") - std::stod(r.text.at("ref_ground_nap_m"))));
    }
    INFO("median |ground (percentile) - ref| = " << median(ground_pct));
    CHECK(median(ground_pct) <= 0.05);
    // The cloud has no CRS: without --cloud-crs it is refused, naming the file.
    CHECK_THROWS_WITH(run_heights(shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson"),
                                  shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), dir / "x.gpkg", HeightsRunOptions{}),
                      Catch::Contains("ahn3_delft_west.las") && Catch::Contains("--cloud-crs"));
    CHECK_FALSE(std::filesystem::exists(dir / "x.gpkg"));
}

TEST_CASE("Synthetic town - flat roof heights within 0.15 m (lidar) - reprojected footprints give the same heights", "[heights][synth]") {
    ScratchDir dir("synth_heights");
    const SynthResult s = make_town(dir, 300, 2, 8);
    const auto rep = run_heights(s.truth_path, s.cloud_path, dir / "h.gpkg", HeightsRunOptions{});
    CHECK_FALSE(rep.reprojected);
    const auto rows = read_rows(dir / "h.gpkg");
    double err = 0.0;
    int n = 0;
    for (const Row& r : rows)
        if (r.text.at("roof_type") == "flat" && r.num.at("height_m")) {
            err += std::abs(*r.num.at("height_m") - std::stod(r.text.at("eave_height_m")));
            ++n;
        }
    REQUIRE(n > 5);
    INFO("flat-roof MAE " << err / n << " m over " << n);
    CHECK(err / n <= 0.15);

    // Footprints in the neighbouring UTM zone: the cloud is reprojected to them.
    const std::string moved = dir / "truth_32651.geojson";
    const std::string cmd = "ogr2ogr -q -t_srs EPSG:32651 " + moved + " " + s.truth_path;
    REQUIRE(std::system(cmd.c_str()) == 0);
    const auto rep2 = run_heights(moved, s.cloud_path, dir / "h2.gpkg", HeightsRunOptions{});
    CHECK(rep2.reprojected);
    const auto rows2 = read_rows(dir / "h2.gpkg");
    REQUIRE(rows2.size() == rows.size());
    int same = 0;
    for (std::size_t i = 0; i < rows.size(); ++i)
        if (rows[i].num.at("height_m") && rows2[i].num.at("height_m"))
            same += std::abs(*rows[i].num.at("height_m") - *rows2[i].num.at("height_m")) < 0.05;
    CHECK(same >= static_cast<int>(rows.size()) - 2);
}

TEST_CASE("heights refuses bad inputs with the file named", "[heights][errors]") {
    ScratchDir dir("heights_bad");
    const std::string fp = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    { std::ofstream(dir / "empty.xyz") << "x y z\n"; }
    HeightsRunOptions o;
    o.cloud_crs = "EPSG:7415";
    CHECK_THROWS_WITH(run_heights(fp, dir / "empty.xyz", dir / "o.gpkg", o), Catch::Contains("empty.xyz") && Catch::Contains("empty"));
    CHECK_THROWS_WITH(run_heights(fp, dir / "none.las", dir / "o.gpkg", o), Catch::Contains("none.las: file not found"));
    CHECK_THROWS_WITH(run_heights(fp, dir / "empty.xyz", dir / "o.txt", o), Catch::Contains("o.txt") && Catch::Contains("unknown vector output format"));
    {
        std::ofstream(dir / "bowtie.geojson")
            << R"({"type":"FeatureCollection","crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::28992"}},)"
            << R"("features":[{"type":"Feature","properties":{},"geometry":{"type":"Polygon","coordinates":[[[0,0],[10,10],[10,0],[0,10],[0,0]]]}}]})";
    }
    CHECK_THROWS_WITH(run_heights(dir / "bowtie.geojson", shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), dir / "o.gpkg", o),
                      Catch::Contains("bowtie.geojson feature") && Catch::Contains("invalid polygon"));
    CHECK_FALSE(std::filesystem::exists(dir / "o.gpkg"));
}

TEST_CASE("audit heights on Delft - our roof p90 against 3dfier's reference", "[heights][audit][real]") {
    ScratchDir dir("audit_heights");
    HeightsRunOptions o;
    o.cloud_crs = "EPSG:7415";
    const std::string ref = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    run_heights(ref, shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), dir / "h.gpkg", o);
    const auto cli = test::run_cli("audit heights --pred " + (dir / "h.gpkg") + " --ref " + ref +
                                   " --pred-field roof_z_90p --ref-field ref_roof_nap_m --out " + (dir / "audit"));
    REQUIRE(cli.exit_code == 0);
    const auto j = nlohmann::json::parse(test::slurp(dir / "audit/report.json"));
    CHECK(j["totals"]["matched"] == 135);
    CHECK(j["totals"]["with_values"] == 135);
    CHECK(j["totals"]["mae_m"].get<double>() < 0.8);
    CHECK(std::abs(j["totals"]["bias_m"].get<double>()) < 0.3);  // no systematic offset against 3dfier (+0.01 m when written)
    // The ground method and its fit residual, per building and per method.
    REQUIRE(j.contains("by_ground_method"));
    CHECK(j["by_ground_method"]["ring_plane"]["buildings"].get<int>() >= 120);
    CHECK(j["by_ground_method"]["ring_plane"]["mean_ground_rmse_m"].get<double>() < 0.3);
    CHECK(j["buildings"][0].contains("ground_method"));
    CHECK(j["buildings"][0].contains("ground_rmse_m"));
    CHECK(test::slurp(dir / "audit/report.md").find("ground method") != std::string::npos);
    CHECK(test::validate_json(test::source_dir() + "/schemas/audit_report.schema.json", dir / "audit/report.json").exit_code == 0);
    const auto gated = test::run_cli("audit heights --pred " + (dir / "h.gpkg") + " --ref " + ref +
                                     " --pred-field roof_z_90p --ref-field ref_roof_nap_m --out " + (dir / "g") + " --fail-above mae=0.05");
    CHECK(gated.exit_code == 4);
    CHECK(gated.err.find("audit failed its gates: mae") != std::string::npos);
    const auto bad = test::run_cli("audit heights --pred " + (dir / "h.gpkg") + " --ref " + ref + " --ref-field nope --out " + (dir / "x"));
    CHECK(bad.exit_code != 0);
    CHECK(bad.err.find("has no field 'nope'") != std::string::npos);
}

TEST_CASE("heights read window by window (cloud larger than the memory budget) write the same bytes as the whole-cloud heights on Delft", "[heights][real][windows]") {
    ScratchDir dir("heights_windows");
    HeightsRunOptions o;
    o.cloud_crs = "EPSG:7415";
    const std::string fp = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    const std::string cloud = shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    const HeightsRunReport whole = run_heights(fp, cloud, dir / "whole.geojson", o);
    CHECK(whole.tiles == 1);
    o.max_points_in_memory = 100000;
    o.tile_m = 60.0;
    const HeightsRunReport tiled = run_heights(fp, cloud, dir / "tiled.geojson", o);
    CHECK(tiled.tiles > 4);
    // The outlier limit is measured once on the same sample by both runs, and
    // each window's points have the neighbours they have in the whole cloud.
    const std::string a = test::slurp(dir / "whole.geojson"), b = test::slurp(dir / "tiled.geojson");
    CHECK(a.find("\"height_m\"") != std::string::npos);
    const bool same = a == b;
    CHECK(same);
    CHECK(read_polygon_layer(dir / "tiled.geojson").features.size() == 135);
}

TEST_CASE("heights over a cloud whose bounding box dwarfs its points (one point 30 km away) are read by windows, with the same bytes as held whole", "[heights][windows]") {
    ScratchDir dir("heights_far_point");
    const SynthResult s = make_town(dir, 300, 3, 6.0);
    LasHeader h;
    PointCloud c = read_las(s.cloud_path, &h);
    const PointCloud first = [&] {
        PointCloud one;
        one.append(c, 0);
        return one;
    }();
    c.append(first, 0);
    c.x.back() += 30000.0, c.y.back() += 20000.0;  // a stray point: the box is 30 x 20 km, the ground grid 6e8 cells
    {
        LasWriter w(dir / "far.las", h.scale, h.offset, h.crs.wkt);
        w.write(c);
        w.close();
    }
    HeightsRunOptions o;
    o.ground.trust_classification = false;  // SMRF, whose grid follows the box
    o.tile_m = 150.0;
    const HeightsRunReport windows = run_heights(s.truth_path, dir / "far.las", dir / "windows.geojson", o);
    CHECK(windows.tiles > 1);  // below the point budget, but read by windows
    o.max_points_in_memory = 0;  // held whole
    const HeightsRunReport whole = run_heights(s.truth_path, dir / "far.las", dir / "whole.geojson", o);
    CHECK(whole.tiles == 1);
    const std::string a = test::slurp(dir / "whole.geojson"), b = test::slurp(dir / "windows.geojson");
    CHECK(a.find("\"height_m\"") != std::string::npos);
    const bool same = a == b;
    CHECK(same);
}

TEST_CASE("heights by windows warn about footprints beyond the cloud, as held whole", "[heights][windows]") {
    ScratchDir dir("heights_windows_outside");
    const SynthResult s = make_town(dir, 300, 3, 2.0);
    LasHeader h;
    const PointCloud all = read_las(s.cloud_path, &h);
    PointCloud west;
    for (std::size_t i = 0; i < all.size(); ++i)
        if (all.x[i] < 500120.0) west.append(all, i);
    {
        LasWriter w(dir / "west.las", h.scale, h.offset, h.crs.wkt);
        w.write(west);
        w.close();
    }
    const auto whole = test::run_cli("heights --footprints " + s.truth_path + " --cloud " + (dir / "west.las") + " --out " + (dir / "whole.geojson"));
    const auto windows = test::run_cli("heights --footprints " + s.truth_path + " --cloud " + (dir / "west.las") + " --out " +
                                       (dir / "windows.geojson") + " --max-points-in-memory 20000 --tile-m 100");
    REQUIRE(whole.exit_code == 0);
    REQUIRE(windows.exit_code == 0);
    const auto said = [](const std::string& err) {
        const auto at = err.find(" footprints lie outside the cloud ");
        return at == std::string::npos ? std::string() : err.substr(err.rfind(": ", at) + 2, at - err.rfind(": ", at) - 2);
    };
    INFO(whole.err + windows.err);
    CHECK_FALSE(said(whole.err).empty());
    CHECK(said(windows.err) == said(whole.err));  // the same "N of M"
}
