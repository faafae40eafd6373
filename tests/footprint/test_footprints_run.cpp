#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "audit/footprint_match.hpp"
#include "core/error.hpp"
#include "footprint/rectangle_fit.hpp"
#include "io/vector.hpp"
#include "pipeline/footprints_run.hpp"
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

TEST_CASE("Cloud-only footprints on a synthetic town match the truth (regression guard)", "[footprint][synth]") {
    ScratchDir dir("fp_run");
    const SynthResult s = make_town(dir, 300, 9, 8);
    FootprintsRunOptions o;
    o.cloud = s.cloud_path;
    o.ortho = s.ortho_path;
    o.fit = FootprintFit::raw;
    const FootprintsReport raw_rep = run_footprints(dir / "raw.gpkg", o);
    CHECK(raw_rep.used_classes);
    o.fit = FootprintFit::rectangle;
    run_footprints(dir / "rect.gpkg", o);
    o.fit = FootprintFit::recursive;
    const FootprintsReport rec_rep = run_footprints(dir / "rec.gpkg", o);
    const PolygonLayer truth = read_polygon_layer(s.truth_path);
    const FootprintScores raw = score(read_polygon_layer(dir / "raw.gpkg"), truth);
    const FootprintScores rect = score(read_polygon_layer(dir / "rect.gpkg"), truth);
    const FootprintScores rec = score(read_polygon_layer(dir / "rec.gpkg"), truth);
    std::printf("footprints (lidar, seed 9, 300 m): raw P %.3f R %.3f F1 %.3f IoU %.3f |area err| %.2f %%; rectangle F1 %.3f IoU %.3f |area err| %.2f %%; recursive F1 %.3f IoU %.3f |area err| %.2f %% (fit vs raw %.2f %%)\n",
                raw.precision, raw.recall, raw.f1, raw.mean_iou, raw.mean_abs_area_error_pct, rect.f1, rect.mean_iou,
                rect.mean_abs_area_error_pct, rec.f1, rec.mean_iou, rec.mean_abs_area_error_pct, rec_rep.mean_abs_fit_area_error_pct);
    double signed_err = 0.0;
    for (const auto& m : raw.matches) signed_err += m.area_error_pct;
    std::printf("raw outlines: mean signed area error %.2f %% over %zu matches\n", signed_err / double(raw.matches.size()), raw.matches.size());
    CHECK(rec.f1 >= 0.9);
    CHECK(rec_rep.mean_abs_fit_area_error_pct <= 6.0);  // regression guard: 4.55 % measured; the issue asks <= 1 % (open)
    CHECK(raw.f1 >= 0.9);
    CHECK(raw.mean_iou >= 0.85);
    CHECK(raw.mean_abs_area_error_pct <= 5.0);
    const PolygonLayer out = read_polygon_layer(dir / "rec.gpkg");
    CHECK(out.crs.epsg == 32650);
    const auto& names = out.field_names;
    for (const char* f : {"area_m2", "geodesic_area_m2", "perimeter_m", "orientation_deg", "fit", "fit_area_error_pct", "fit_iou", "n_vertices", "status"})
        CHECK(std::find(names.begin(), names.end(), f) != names.end());
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
    run_footprints(dir / "delft.gpkg", o);
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
    // Terraced Delft houses share walls: one detected block covers several BGT
    // footprints, so per-object recall stays low until height-step splitting
    // lands; the per-area measures show that the built-up area itself is found.
    // Correctness is not meaningful here: the reference set holds only this
    // split's buildings, while the cloud shows their unreferenced neighbours too.
    CHECK(s.area_completeness >= 0.85);
}

TEST_CASE("Ortho-only footprints on a synthetic town (regression guard)", "[footprint][synth]") {
    ScratchDir dir("fp_ortho");
    const SynthResult s = make_town(dir, 300, 4, 0);
    FootprintsRunOptions o;
    o.ortho = s.ortho_path;
    const FootprintsReport rep = run_footprints(dir / "fp.gpkg", o);
    CHECK(rep.mode == "ortho_only");
    const FootprintScores sc = score(read_polygon_layer(dir / "fp.gpkg"), read_polygon_layer(s.truth_path));
    std::printf("ortho-only footprints (seed 4, 300 m): P %.3f R %.3f F1 %.3f mean IoU %.3f |area err| %.2f %%\n", sc.precision, sc.recall,
                sc.f1, sc.mean_iou, sc.mean_abs_area_error_pct);
    CHECK(sc.f1 >= 0.6);
    CHECK(sc.mean_iou >= 0.85);
}
