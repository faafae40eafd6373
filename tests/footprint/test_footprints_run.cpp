#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/error.hpp"
#include "footprint/rectangle_fit.hpp"
#include "io/vector.hpp"
#include "pipeline/footprints_run.hpp"
#include "synth/synth.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;

namespace {
struct MatchScores {
    double precision = 0, recall = 0, f1 = 0, mean_iou = 0, mean_abs_area_error_pct = 0;
};
// One-to-one matching at IoU >= 0.5 (greedy by IoU, the SpaceNet rule).
MatchScores score(const PolygonLayer& pred, const PolygonLayer& truth) {
    struct Pair {
        double iou;
        std::size_t p, t;
    };
    std::vector<Pair> pairs;
    for (std::size_t p = 0; p < pred.features.size(); ++p) {
        const Extent ep = polygon_extent(pred.features[p].geometry[0]);
        for (std::size_t t = 0; t < truth.features.size(); ++t) {
            const Extent et = polygon_extent(truth.features[t].geometry[0]);
            if (ep.max_x < et.min_x || et.max_x < ep.min_x || ep.max_y < et.min_y || et.max_y < ep.min_y) continue;
            const double iou = polygon_iou(pred.features[p].geometry[0], truth.features[t].geometry[0]);
            if (iou >= 0.5) pairs.push_back({iou, p, t});
        }
    }
    std::sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) { return a.iou > b.iou; });
    std::vector<uint8_t> pu(pred.features.size(), 0), tu(truth.features.size(), 0);
    MatchScores s;
    std::size_t tp = 0;
    for (const Pair& m : pairs) {
        if (pu[m.p] || tu[m.t]) continue;
        pu[m.p] = tu[m.t] = 1;
        ++tp;
        s.mean_iou += m.iou;
        const double at = polygon_area(truth.features[m.t].geometry[0]);
        s.mean_abs_area_error_pct += std::abs(polygon_area(pred.features[m.p].geometry[0]) - at) / at * 100.0;
    }
    s.precision = pred.features.empty() ? 0 : double(tp) / double(pred.features.size());
    s.recall = double(tp) / double(truth.features.size());
    s.f1 = s.precision + s.recall > 0 ? 2 * s.precision * s.recall / (s.precision + s.recall) : 0;
    if (tp) s.mean_iou /= double(tp), s.mean_abs_area_error_pct /= double(tp);
    return s;
}
}  // namespace

TEST_CASE("Cloud-only footprints on a synthetic town match the truth (regression guard)", "[footprint][synth]") {
    ScratchDir dir("fp_run");
    SynthOptions so;
    so.size_m = 300;
    so.seed = 9;
    const SynthResult s = write_synthetic_town(dir.path.string(), so);
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
    const MatchScores raw = score(read_polygon_layer(dir / "raw.gpkg"), truth);
    const MatchScores rect = score(read_polygon_layer(dir / "rect.gpkg"), truth);
    const MatchScores rec = score(read_polygon_layer(dir / "rec.gpkg"), truth);
    std::printf("footprints (lidar, seed 9, 300 m): raw P %.3f R %.3f F1 %.3f IoU %.3f |area err| %.2f %%; rectangle F1 %.3f IoU %.3f |area err| %.2f %%; recursive F1 %.3f IoU %.3f |area err| %.2f %% (fit vs raw %.2f %%)\n",
                raw.precision, raw.recall, raw.f1, raw.mean_iou, raw.mean_abs_area_error_pct, rect.f1, rect.mean_iou,
                rect.mean_abs_area_error_pct, rec.f1, rec.mean_iou, rec.mean_abs_area_error_pct, rec_rep.mean_abs_fit_area_error_pct);
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
