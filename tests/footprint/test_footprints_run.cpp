#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "audit/footprint_match.hpp"
#include "core/error.hpp"
#include "footprint/rectangle_fit.hpp"
#include "io/vector.hpp"
#include "pipeline/cloud_cells.hpp"
#include "pipeline/footprints_run.hpp"
#include "pipeline/rasterize_run.hpp"
#include "pipeline/segment_raster.hpp"
#include "raster/raster.hpp"
#include <filesystem>
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;

namespace {
FootprintScores score(const PolygonLayer& pred, const PolygonLayer& truth) {
    std::vector<std::vector<Polygon>> p, t;
    for (const auto& f : pred.features) p.push_back(f.geometry);
    for (const auto& f : truth.features) t.push_back(f.geometry);
    return match_footprints(p, t, 0.5);
}
}  // namespace

TEST_CASE("Lidar footprints meet the issue's targets on two synthetic towns in both cloud modes", "[footprint][synth]") {
    // Targets of issue #5 with a lidar-mode cloud: F1 >= 0.95, mean IoU >=
    // 0.85, mean |area error| of the fitted polygons against the truth <= 1 %.
    for (const uint64_t seed : {3u, 7u}) {
        ScratchDir dir("fp_run_" + std::to_string(seed));
        const SynthResult s = make_town(dir, 600, seed, 8);
        const PolygonLayer truth = read_polygon_layer(s.truth_path);
        for (const DetectionMode mode : {DetectionMode::cloud_only, DetectionMode::ortho_cloud}) {
            for (const FootprintFit fit : {FootprintFit::recursive, FootprintFit::regularised}) {
                FootprintsRunOptions o;
                o.cloud = s.cloud_path;
                o.ortho = s.ortho_path;
                o.mode = mode;
                o.fit = fit;
                const std::string name = to_string(mode) + "_" + to_string(fit) + ".gpkg";
                const FootprintsReport rep = run_footprints(dir / name, o);
                CHECK(rep.mode == to_string(mode));
                CHECK(rep.used_classes);
                const FootprintScores sc = score(read_polygon_layer(dir / name), truth);
                std::printf("footprints (lidar, seed %d, 600 m, %s, %s): %zu buildings; P %.3f R %.3f F1 %.3f mean IoU %.3f |area err| %.2f %% (fit vs raw %.3f %%)\n",
                            int(seed), to_string(mode).c_str(), to_string(fit).c_str(), sc.reference, sc.precision, sc.recall, sc.f1, sc.mean_iou,
                            sc.mean_abs_area_error_pct, rep.mean_abs_fit_area_error_pct);
                CHECK(sc.f1 >= 0.95);
                CHECK(sc.mean_iou >= 0.85);
                CHECK(sc.mean_abs_area_error_pct <= 1.0);
            }
        }
        const PolygonLayer out = read_polygon_layer(dir / "ortho_cloud_recursive.gpkg");
        CHECK(out.crs.epsg == 32650);
        const auto& names = out.field_names;
        for (const char* f : {"area_m2", "geodesic_area_m2", "perimeter_m", "orientation_deg", "fit", "fit_area_error_pct", "fit_iou", "n_vertices", "status", "mode"})
            CHECK(std::find(names.begin(), names.end(), f) != names.end());
    }
}

TEST_CASE("Photo-mode footprints: the ortho sharpens the smeared cloud edges (regression guard)", "[footprint][synth]") {
    ScratchDir dir("fp_photo");
    const SynthResult s = make_town(dir, 400, 5, 8, CloudMode::photo);
    const PolygonLayer truth = read_polygon_layer(s.truth_path);
    FootprintsRunOptions o;
    o.cloud = s.cloud_path;
    o.ortho = s.ortho_path;
    const FootprintsReport combined = run_footprints(dir / "combined.gpkg", o);
    CHECK(combined.mode == "ortho_cloud");
    o.mode = DetectionMode::cloud_only;
    run_footprints(dir / "cloud.gpkg", o);
    const FootprintScores c = score(read_polygon_layer(dir / "combined.gpkg"), truth);
    const FootprintScores p = score(read_polygon_layer(dir / "cloud.gpkg"), truth);
    std::printf("footprints (photo, seed 5, 400 m): ortho+cloud F1 %.3f IoU %.3f |area err| %.2f %%; cloud only F1 %.3f IoU %.3f |area err| %.2f %%\n",
                c.f1, c.mean_iou, c.mean_abs_area_error_pct, p.f1, p.mean_iou, p.mean_abs_area_error_pct);
    CHECK(c.f1 >= 0.95);
    CHECK(c.mean_iou >= 0.93);
    CHECK(c.mean_iou > p.mean_iou);
    CHECK(c.mean_abs_area_error_pct < p.mean_abs_area_error_pct);
}

TEST_CASE("A detection mode without its input is refused", "[footprint][errors]") {
    ScratchDir dir("fp_mode");
    FootprintsRunOptions o;
    o.ortho = "x.tif";
    o.mode = DetectionMode::ortho_cloud;
    CHECK_THROWS_WITH(run_footprints(dir / "x.gpkg", o), Catch::StartsWith("--mode") && Catch::Contains("needs a point cloud"));
    CHECK(dir.file_count() == 0);
}

TEST_CASE("A negative --ortho-edge-odds is refused before anything is read or written", "[footprint][errors]") {
    ScratchDir dir("fp_edge_odds");
    FootprintsRunOptions o;
    o.ortho = "missing.tif", o.cloud = "missing.las";
    o.segmentation.ortho_edge_odds = -1.0;
    CHECK_THROWS_WITH(run_footprints(dir / "x.gpkg", o), Catch::StartsWith("--ortho-edge-odds") && Catch::Contains(">= 0"));
    CHECK(dir.file_count() == 0);
}

TEST_CASE("footprints refuses to run without a cloud", "[footprint][errors]") {
    ScratchDir dir("fp_bad");
    FootprintsRunOptions o;
    CHECK_THROWS_WITH(run_footprints(dir / "x.gpkg", o), Catch::StartsWith("--cloud"));
    CHECK(dir.file_count() == 0);
}

TEST_CASE("Delft AHN3 cloud-only footprints against the 135 BGT footprints (regression guard)", "[footprint][real]") {
    ScratchDir dir("fp_delft");
    FootprintsRunOptions o;
    o.cloud = test::shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las");
    o.cloud_crs = "EPSG:7415";
    o.fit = FootprintFit::raw;
    const FootprintsReport rep = run_footprints(dir / "delft.gpkg", o);
    CHECK(rep.mode == "cloud_only");
    const PolygonLayer pred = read_polygon_layer(dir / "delft.gpkg");
    const PolygonLayer ref = read_polygon_layer(test::shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson"));
    // The cloud covers more than the reference area: score predictions whose
    // centre lies inside the references' extent only.
    Extent e{INFINITY, INFINITY, -INFINITY, -INFINITY};
    for (const auto& f : ref.features)
        for (const Polygon& p : f.geometry) {
            const Extent q = polygon_extent(p);
            e.min_x = std::min(e.min_x, q.min_x), e.min_y = std::min(e.min_y, q.min_y), e.max_x = std::max(e.max_x, q.max_x), e.max_y = std::max(e.max_y, q.max_y);
        }
    std::vector<std::vector<Polygon>> p, r;
    for (const auto& f : pred.features) {
        const Extent q = polygon_extent(f.geometry[0]);
        const double cx = 0.5 * (q.min_x + q.max_x), cy = 0.5 * (q.min_y + q.max_y);
        if (cx >= e.min_x && cx <= e.max_x && cy >= e.min_y && cy <= e.max_y) p.push_back(f.geometry);
    }
    for (const auto& f : ref.features) r.push_back(f.geometry);
    const FootprintScores s = match_footprints(p, r, 0.5);
    std::printf("Delft cloud-only footprints: %zu predicted in the reference extent, %zu reference; P %.3f R %.3f F1 %.3f mean IoU %.3f |area err| %.2f %%; per-area completeness %.3f correctness %.3f quality %.3f\n",
                s.predicted, s.reference, s.precision, s.recall, s.f1, s.mean_iou, s.mean_abs_area_error_pct, s.area_completeness,
                s.area_correctness, s.area_quality);
    // Terraced Delft houses share walls and, mostly, one continuous roof: the
    // split at height steps separates blocks of different heights, but BGT's
    // parcel-wide houses under one roof stay one block, so per-object recall
    // stays low; the per-area measures show that the built-up area is found.
    // Correctness is not meaningful here: the reference set holds only this
    // split's buildings, while the cloud shows their unreferenced neighbours too.
    CHECK(s.area_completeness >= 0.85);
    CHECK(s.recall >= 0.014);  // regression guard: 2 of 135 matched at IoU >= 0.5 (3 before sparse surfaces were restored, with the same per-area completeness 0.92)
}

TEST_CASE("Ortho-only footprints on a synthetic town (regression guard)", "[footprint][synth]") {
    ScratchDir dir("fp_ortho");
    const SynthResult s = make_town(dir, 300, 4, 0);
    FootprintsRunOptions o;
    o.ortho = s.ortho_path;
    o.detector = OrthoDetector::rules;  // the hand-set rules; the learned model is tested in tests/detect
    const FootprintsReport rep = run_footprints(dir / "fp.gpkg", o);
    CHECK(rep.mode == "ortho_only");
    CHECK(rep.detector == "rules");
    const FootprintScores sc = score(read_polygon_layer(dir / "fp.gpkg"), read_polygon_layer(s.truth_path));
    std::printf("ortho-only footprints (seed 4, 300 m): P %.3f R %.3f F1 %.3f mean IoU %.3f |area err| %.2f %%\n", sc.precision, sc.recall,
                sc.f1, sc.mean_iou, sc.mean_abs_area_error_pct);
    CHECK(sc.f1 >= 0.75);  // regression guard: 0.780 measured (0.705 before rectangular grouping and rectilinear shapes)
    CHECK(sc.mean_iou >= 0.9);
}

TEST_CASE("SpaceNet Atlanta panchromatic ortho-only footprints against its 25 references (regression guard)", "[footprint][real]") {
    ScratchDir dir("fp_spacenet");
    FootprintsRunOptions o;
    o.ortho = test::shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif");
    o.fit = FootprintFit::raw;
    o.detector = OrthoDetector::rules;  // the shipped pan model was trained on this tile
    const FootprintsReport rep = run_footprints(dir / "sn.gpkg", o);
    CHECK(rep.mode == "ortho_only");
    const PolygonLayer pred = read_polygon_layer(dir / "sn.gpkg");
    CHECK(pred.crs.epsg == 32616);
    const FootprintScores s = score(pred, read_polygon_layer(test::shared_data("spacenet4_atlanta_pan_west/buildings_west.geojson")));
    std::printf("SpaceNet ortho-only footprints: %zu predicted, %zu reference; P %.3f R %.3f F1 %.3f; per-area completeness %.3f correctness %.3f\n",
                s.predicted, s.reference, s.precision, s.recall, s.f1, s.area_completeness, s.area_correctness);
    // Off-nadir panchromatic, houses under canopy: roof segments have the
    // brightness and texture of lawns and crowns, so spectral and shape rules
    // find little (measured: F1 0, per-area completeness 0.041). Guard the
    // part that is found.
    CHECK(s.area_completeness >= 0.03);
}

TEST_CASE("Footprints from an nDSM raster or an nDSM band of the ortho - and from segments made by cityforge segment", "[footprint][synth]") {
    ScratchDir dir("fp_ndsm");
    const SynthResult s = make_town(dir, 300, 9, 8);
    const PolygonLayer truth = read_polygon_layer(s.truth_path);
    RasterizeOptions ro;
    ro.grid_raster = s.ortho_path;
    rasterize_run(s.cloud_path, dir / "rasters", ro);
    const std::string ndsm = dir / "rasters/ndsm.tif";

    FootprintsRunOptions o;
    o.ortho = s.ortho_path;
    o.ndsm = ndsm;
    const FootprintsReport rep = run_footprints(dir / "ndsm.gpkg", o);
    CHECK(rep.mode == "ortho_cloud");
    CHECK(rep.height_source == "nDSM raster");
    CHECK_FALSE(rep.used_classes);
    const FootprintScores a = score(read_polygon_layer(dir / "ndsm.gpkg"), truth);

    // The same heights as a fourth band of the ortho.
    {
        RasterReader rgb(s.ortho_path), h(ndsm);
        const Image<float> colours = rgb.read_all<float>();
        const Image<float> z = h.read_all<float>();
        Image<float> four(colours.width, colours.height, 4, 0.0f);
        for (int b = 0; b < 3; ++b) std::copy(colours.band_data(b), colours.band_data(b) + colours.pixel_count(), four.band_data(b));
        std::copy(z.data.begin(), z.data.end(), four.band_data(3));
        GeoTiffWriteOptions wo;
        wo.nodata = -9999.0;  // the nDSM's; no colour reaches it
        write_geotiff(dir / "rgbh.tif", four, rgb.info().transform, rgb.info().crs.wkt, wo);
    }
    FootprintsRunOptions ob;
    ob.ortho = dir / "rgbh.tif";
    ob.ndsm_band = 4;
    const FootprintsReport rep_b = run_footprints(dir / "band.gpkg", ob);
    CHECK(rep_b.height_source == "ortho band 4");
    const FootprintScores b = score(read_polygon_layer(dir / "band.gpkg"), truth);

    // Segments made beforehand: the folder of `cityforge segment`, level 30.
    SegmentOptions so;
    so.merging.scales = {20, 30};
    segment_raster(s.ortho_path, dir / "segments", so);
    FootprintsRunOptions oc;
    oc.ortho = s.ortho_path;
    oc.cloud = s.cloud_path;
    oc.segments = dir / "segments";
    const FootprintsReport rep_s = run_footprints(dir / "segs.gpkg", oc);
    CHECK(rep_s.segments_path.find("segments_scale_30.tif") != std::string::npos);
    const FootprintScores c = score(read_polygon_layer(dir / "segs.gpkg"), truth);
    std::printf("footprints (seed 9, 300 m): ortho + nDSM raster F1 %.3f IoU %.3f |area err| %.2f %%; nDSM band F1 %.3f IoU %.3f; ortho + cloud with given segments F1 %.3f IoU %.3f |area err| %.2f %%\n",
                a.f1, a.mean_iou, a.mean_abs_area_error_pct, b.f1, b.mean_iou, c.f1, c.mean_iou, c.mean_abs_area_error_pct);
    CHECK(a.f1 >= 0.95);  // no classes: the image's ExG vetoes crowns (1.0 measured)
    CHECK(a.mean_iou >= 0.9);
    CHECK(b.f1 == Approx(a.f1));  // the same heights and colours give the same buildings
    CHECK(c.f1 >= 0.95);
    CHECK(c.mean_iou >= 0.9);

    oc.segmentation.segment_scale = 25;
    CHECK_THROWS_WITH(run_footprints(dir / "bad.gpkg", oc), Catch::Contains("segments_scale_20.tif, segments_scale_30.tif"));
    FootprintsRunOptions both = o;
    both.cloud = s.cloud_path;
    CHECK_THROWS_WITH(run_footprints(dir / "bad.gpkg", both), Catch::StartsWith("--ndsm") && Catch::Contains("one height source"));
    CHECK_FALSE(std::filesystem::exists(dir / "bad.gpkg"));
}

TEST_CASE("A sparse cloud is rasterised on coarser cells and the ortho draws the edges", "[footprint][synth]") {
    CHECK(cloud_cell_factor(8.0, 0.5) == 1);
    CHECK(cloud_cell_factor(2.0, 0.5) == 2);
    CHECK(cloud_cell_factor(2.0, 0.25) == 3);
    CHECK(cloud_cell_factor(0.0, 0.5) == 1);
    ScratchDir dir("fp_sparse");
    const SynthResult s = make_town(dir, 400, 3, 2);  // 2 pts/m² under a 0.5 m ortho: 0.5 points per pixel
    const PolygonLayer truth = read_polygon_layer(s.truth_path);
    FootprintsRunOptions o;
    o.cloud = s.cloud_path;
    o.ortho = s.ortho_path;
    const FootprintsReport rep = run_footprints(dir / "auto.gpkg", o);
    CHECK(rep.cloud_cell_factor == 2);
    o.cloud_cell_factor = 1;
    run_footprints(dir / "fine.gpkg", o);
    const FootprintScores a = score(read_polygon_layer(dir / "auto.gpkg"), truth);
    const FootprintScores f = score(read_polygon_layer(dir / "fine.gpkg"), truth);
    std::printf("footprints (lidar 2 pts/m2, seed 3, 400 m, ortho + cloud): 2 x 2 pixel cloud cells F1 %.3f IoU %.3f |area err| %.2f %%; pixel cells F1 %.3f IoU %.3f\n",
                a.f1, a.mean_iou, a.mean_abs_area_error_pct, f.f1, f.mean_iou);
    CHECK(a.f1 >= 0.95);
    CHECK(a.mean_iou >= 0.93);
    CHECK(a.f1 > f.f1);
}

TEST_CASE("Footprints from a cloud read window by window (above the memory budget) are the same bytes as a whole-cloud run", "[footprint][synth][windows]") {
    ScratchDir dir("fp_windows");
    const SynthResult s = make_town(dir, 300, 11, 8);  // ~720 k points
    for (const DetectionMode mode : {DetectionMode::cloud_only, DetectionMode::ortho_cloud}) {
        INFO(to_string(mode));
        FootprintsRunOptions o;
        o.cloud = s.cloud_path;
        if (mode == DetectionMode::ortho_cloud) o.ortho = s.ortho_path;
        o.mode = mode;
        const std::string tag = to_string(mode);
        const FootprintsReport whole = run_footprints(dir / (tag + "_whole.geojson"), o);
        CHECK(whole.cloud_windows == 0);
        o.max_points_in_memory = 700000;
        o.cloud_tile_m = 100.0;
        o.cloud_overlap_m = 100.0;
        const FootprintsReport tiled = run_footprints(dir / (tag + "_tiled.geojson"), o);
        CHECK(tiled.cloud_windows >= 9);
        CHECK(tiled.buildings == whole.buildings);
        CHECK(whole.buildings > 10);
        const bool same = test::slurp(dir / (tag + "_whole.geojson")) == test::slurp(dir / (tag + "_tiled.geojson"));
        CHECK(same);
    }
}

TEST_CASE("A building outline through one vertex twice (a pocket open only diagonally) is written as a simple ring, not a failed fit", "[footprints][vectorize]") {
    // 6 x 6 cells with the corner cell (6,6) cut off and the cell (5,5)
    // beside it empty: the 4-connected outline enters that pocket and leaves
    // it through one vertex (seen on IGN Lidar HD, 1 of 625 buildings).
    BuildingMask mask;
    mask.labels = Image<uint32_t>(10, 10, 1, 0u);
    for (int y = 1; y <= 6; ++y)
        for (int x = 1; x <= 6; ++x) mask.labels.at(0, x, y) = 1;
    mask.labels.at(0, 6, 6) = 0, mask.labels.at(0, 5, 5) = 0;
    mask.count = 1;
    FootprintsRunOptions o;
    o.fit = FootprintFit::raw;
    o.simplify_m = 0.0;  // the exact pixel outline, as the fits may keep it
    const GeoTransform grid{500000.0, 0.5, 4400100.0, -0.5};
    const FootprintTable t = footprint_table(mask, Image<float>(), grid, 0, 0, {}, "cloud_only", 1.0, 1.0,
                                             crs_from_user_input("EPSG:32650", "test"), o);
    REQUIRE(t.features.size() == 1);
    const auto field = [&](const std::string& name) {
        for (std::size_t i = 0; i < t.fields.size(); ++i)
            if (t.fields[i].name == name) return t.features[0].values[i];
        FAIL("no field " << name);
        return AttributeValue();
    };
    CHECK(std::get<std::string>(field("status")) == "ok");
    CHECK(std::get<std::string>(field("reason")) == "a pocket open only diagonally was filled");
    REQUIRE(t.features[0].geometry.size() == 1);
    const Polygon& p = t.features[0].geometry[0];
    CHECK(polygon_is_valid(p));
    CHECK(polygon_area(p) == Approx(35 * 0.25));  // the pocket filled, the corner still cut off
}
