#include <catch2/catch.hpp>
#include <cmath>
#include <algorithm>
#include <cstdio>
#include <map>
#include <string>

#include "io/vector.hpp"
#include "pipeline/heights_run.hpp"
#include "pipeline/roofs_run.hpp"
#include "roof/lod2_builder.hpp"
#include "roof/roof_planes.hpp"
#include "core/random.hpp"
#include "roof_scene.hpp"
#include "synth/synth.hpp"
#include "test_support.hpp"

using namespace cityforge;

namespace {
// Vertical RMS distance of the model's roof faces to the scene's exact roof, on a 0.5 m grid.
double rmse_to_truth(const Lod2Result& r, const synth::SceneBuilding& b, const std::vector<Polygon>& footprint) {
    double s2 = 0;
    std::size_t n = 0;
    const Extent e = polygon_extent(footprint[0]);
    for (double y = e.min_y + 0.25; y < e.max_y; y += 0.5)
        for (double x = e.min_x + 0.25; x < e.max_x; x += 0.5) {
            if (!point_in_polygon(footprint[0], x, y)) continue;
            for (const Solid& s : r.solids)
                for (const Face& f : s.faces) {
                    if (f.type != SurfaceType::roof) continue;
                    const std::optional<double> z = face_z_at(f, x, y);
                    if (!z) continue;
                    const double t = b.ground_z + b.roof_height(x, y);
                    s2 += (*z - t) * (*z - t), ++n;
                    goto next;
                }
        next:;
        }
    return n ? std::sqrt(s2 / double(n)) : INFINITY;
}
}  // namespace

TEST_CASE("LOD2 on synthetic roofs - roof types - RMSE to the exact planes - valid solids", "[roof][synth]") {
    synth::SceneLayout layout;
    layout.size_m = 600;
    layout.seed = 11;
    const synth::Scene scene = synth::generate_scene(layout);
    std::map<std::string, std::pair<int, int>> per_type;  // truth type -> (correct, total)
    int correct = 0, total = 0, valid = 0, fallbacks = 0;
    double rmse_sum = 0;
    for (const synth::SceneBuilding& b : scene.buildings) {
        const test::RoofSample s = test::sample_roof(b, 8.0, 0.03, 5);
        const Lod2Result r = reconstruct_lod2(s.footprint, s.points, s.ground_z, s.ground_z + b.eave_height_m);
        const std::string truth = synth::to_string(b.roof);
        ++total;
        auto& pt = per_type[truth + "/" + synth::to_string(b.shape)];
        ++pt.second;
        if (r.roof_type == truth) ++correct, ++pt.first;
        bool ok = true;
        for (const Solid& solid : r.solids) ok = ok && validate_solid(solid).empty();
        valid += ok;
        fallbacks += r.fallback;
        const double e = rmse_to_truth(r, b, s.footprint);
        rmse_sum += e;
        if (r.roof_type != truth || e > 0.3)
            std::printf("building %d %s/%s -> %s planes %d fallback %d (%s) rmse %.3f truth-rmse %.3f\n", b.id, truth.c_str(),
                        synth::to_string(b.shape).c_str(), r.roof_type.c_str(), r.roof_planes, int(r.fallback), r.fallback_reason.c_str(),
                        r.rmse_m, e);
    }
    for (const auto& [k, v] : per_type) std::printf("%-20s %d / %d\n", k.c_str(), v.first, v.second);
    std::printf("roof type accuracy %d / %d, valid %d, fallbacks %d, mean RMSE to truth %.3f m\n", correct, total, valid, fallbacks,
                rmse_sum / total);
    CHECK(valid == total);
    CHECK(double(correct) / total >= 0.9);
    CHECK(rmse_sum / total <= 0.15);
}

TEST_CASE("Roof planes of a gable - two planes with the right slope and azimuths - thin clouds fall back to a flat roof", "[roof]") {
    // Gable 12 m (east-west) x 8 m, ridge along x at y = 4, 30 degree pitch, eaves at 6 m.
    const double t = std::tan(30.0 * 3.14159265358979 / 180.0);
    std::vector<std::array<double, 3>> pts;
    Rng rng(3);
    for (double y = 0.1; y < 8; y += 0.35)
        for (double x = 0.1; x < 12; x += 0.35) pts.push_back({x, y, 6.0 + t * (4.0 - std::abs(y - 4.0)) + 0.02 * rng.normal()});
    const std::vector<RoofPlane> planes = detect_roof_planes(pts);
    REQUIRE(planes.size() == 2);
    for (const RoofPlane& p : planes) {
        CHECK(p.slope_deg == Approx(30.0).margin(1.0));
        CHECK(p.rmse_m < 0.05);
    }
    // One slope faces north (azimuth 0 / 360), the other south (180).
    auto from_north = [](double az) { return std::min(az, 360.0 - az); };
    const double n0 = from_north(planes[0].azimuth_deg), n1 = from_north(planes[1].azimuth_deg);
    CHECK(std::min(n0, n1) == Approx(0.0).margin(2.0));
    CHECK(std::max(n0, n1) == Approx(180.0).margin(2.0));
    const std::vector<Polygon> footprint{Polygon{{{0, 0}, {12, 0}, {12, 8}, {0, 8}}, {}}};
    const Lod2Result r = reconstruct_lod2(footprint, pts, 0.0, 7.0);
    CHECK_FALSE(r.fallback);
    CHECK(r.roof_type == "gable");
    CHECK(r.roof_planes == 2);
    REQUIRE(r.solids.size() == 1);
    CHECK(validate_solid(r.solids[0]).empty());
    // Volume: box 12 x 8 x 6 plus the gable prism 12 x (8 x 4 t / 2), within the ridge's fitting error.
    CHECK(solid_volume(r.solids[0]) == Approx(12 * 8 * 6.0 + 12 * 8 * 4 * t / 2).epsilon(0.02));
    const std::vector<std::array<double, 3>> few(pts.begin(), pts.begin() + 10);
    const Lod2Result thin = reconstruct_lod2(footprint, few, 0.0, 7.0);
    CHECK(thin.fallback);
    CHECK(thin.fallback_reason == "too few roof points for planes");
    CHECK(thin.roof_type == "flat");
    REQUIRE(thin.solids.size() == 1);
    CHECK(solid_volume(thin.solids[0]) == Approx(12 * 8 * 7.0));
}

TEST_CASE("A roof model that misses most of its points (vegetation over a flat roof) falls back to a flat roof and says why", "[roof]") {
    // A third of the points on a flat roof at 6 m, the rest scattered 1-6 m above it (a tree crown).
    std::vector<std::array<double, 3>> pts;
    Rng rng(9);
    for (double y = 0.1; y < 10; y += 0.3)
        for (double x = 0.1; x < 10; x += 0.3) {
            const bool roof = rng.uniform() < 0.33;
            pts.push_back({x, y, roof ? 6.0 + 0.02 * rng.normal() : 7.0 + 5.0 * rng.uniform()});
        }
    const std::vector<Polygon> footprint{Polygon{{{0, 0}, {10, 0}, {10, 10}, {0, 10}}, {}}};
    const Lod2Result r = reconstruct_lod2(footprint, pts, 0.0, 6.0);
    CHECK(r.fallback);
    CHECK(r.fallback_reason.find("miss") != std::string::npos);
    REQUIRE(r.solids.size() == 1);
    CHECK(validate_solid(r.solids[0]).empty());
    Lod2Options lenient;
    lenient.max_median_residual_m = 10.0;  // accepted when the limit allows it
    const Lod2Result kept = reconstruct_lod2(footprint, pts, 0.0, 6.0, lenient);
    CHECK_FALSE(kept.fallback);
    CHECK(kept.median_residual_m > 0.5);
}

TEST_CASE("A roof of very many planes falls back flat at once instead of partitioning their square (noisy photogrammetric roofs)", "[roof]") {
    // 36 m x 36 m of little pyramids, 6 m each: 144 planes, hundreds of adjacent pairs.
    std::vector<std::array<double, 3>> pts;
    for (double y = 0.1; y < 36; y += 0.3)
        for (double x = 0.1; x < 36; x += 0.3) {
            const double u = std::fmod(x, 6.0) - 3.0, v = std::fmod(y, 6.0) - 3.0;
            pts.push_back({x, y, 8.0 + 0.6 * (3.0 - std::max(std::abs(u), std::abs(v)))});
        }
    const std::vector<Polygon> footprint{Polygon{{{0, 0}, {36, 0}, {36, 36}, {0, 36}}, {}}};
    Lod2Options o;
    const Lod2Result r = reconstruct_lod2(footprint, pts, 0.0, 9.0, o);
    INFO(r.fallback_reason);
    CHECK(r.fallback);
    CHECK(r.fallback_reason.find("roof too complex") != std::string::npos);
    REQUIRE(r.solids.size() == 1);
    CHECK(validate_solid(r.solids[0]).empty());
    // The same roof with the limit lifted is attempted (and is no longer refused for its complexity).
    o.max_partition_lines = 100000;
    o.retry_alternatives = false;
    const Lod2Result all = reconstruct_lod2(footprint, pts, 0.0, 9.0, o);
    CHECK(all.fallback_reason.find("roof too complex") == std::string::npos);
}

namespace {
// A rectangular house W x D m (ridge along u), eave 6 m, pitch 35 deg, rotated by `angle_rad`.
synth::SceneBuilding house(synth::RoofType roof, double W, double D, double angle_rad) {
    synth::SceneBuilding b;
    b.id = 1;
    b.roof = roof;
    b.cx = 40, b.cy = 30, b.angle_rad = angle_rad;
    b.wings = {{-W / 2, -D / 2, W / 2, D / 2}};
    b.outline = {{-W / 2, -D / 2}, {W / 2, -D / 2}, {W / 2, D / 2}, {-W / 2, D / 2}};
    b.ground_z = 12.0;
    b.eave_height_m = 6.0;
    b.pitch_tan = std::tan(35.0 * 3.14159265358979 / 180.0);
    b.ridge_height_m = b.eave_height_m + 0.5 * std::min(W, D) * b.pitch_tan;
    return b;
}
// A dark roof: four pulses in five lost at random (the generator's rule).
test::RoofSample dark(test::RoofSample s, uint64_t seed) {
    Rng rng(seed, 77);
    std::vector<std::array<double, 3>> kept;
    for (const auto& q : s.points)
        if (rng.uniform() >= 0.8) kept.push_back(q);
    s.points = std::move(kept);
    return s;
}
}  // namespace

TEST_CASE("Sparse hip roofs (a dark roof at 4 pts/m2 returns about 0.8) stay hips, with their planes - sparse gables stay gables", "[roof]") {
    // At about a point per 1.2 m the small end facets of a hip often find no
    // plane, and the partition lines, drawn between coarse adjacency samples,
    // stopped short of closing the roof's cells (one plane for the whole roof,
    // "roof planes miss their points"). Near both ends of the ridge a hip's
    // points lie half its rise below the two long planes; a gable's do not.
    int hips = 0, hip_models = 0, gables = 0, n = 0;
    std::string misread;
    for (uint64_t seed = 1; seed <= 12; ++seed) {
        const double angle = 0.13 * double(seed);
        for (const auto& [W, D] : {std::pair<double, double>{18.0, 10.0}, {24.0, 12.0}}) {
            ++n;
            const synth::SceneBuilding hip = house(synth::RoofType::hip, W, D, angle);
            const test::RoofSample hs = dark(test::sample_roof(hip, 4.0, 0.03, seed), seed);
            const Lod2Result hr = reconstruct_lod2(hs.footprint, hs.points, hs.ground_z, hs.ground_z + hip.eave_height_m);
            hips += hr.roof_type == "hip";
            hip_models += !hr.fallback && hr.roof_planes >= 2 && rmse_to_truth(hr, hip, hs.footprint) < 1.0;
            for (const Solid& solid : hr.solids) CHECK(validate_solid(solid).empty());
            const synth::SceneBuilding gable = house(synth::RoofType::gable, W, D, angle);
            const test::RoofSample gs = dark(test::sample_roof(gable, 4.0, 0.03, seed), seed);
            const Lod2Result gr = reconstruct_lod2(gs.footprint, gs.points, gs.ground_z, gs.ground_z + gable.eave_height_m);
            gables += gr.roof_type == "gable";
            if (gr.roof_type != "gable") misread += " " + std::to_string(int(W)) + "x" + std::to_string(int(D)) + " seed " + std::to_string(seed) + ": " + gr.roof_type;
        }
    }
    INFO("hips read as hips " << hips << ", modelled " << hip_models << ", gables as gables " << gables << " of " << n << "; gables misread:" << misread);
    CHECK(hips >= n - 2);
    CHECK(hip_models == n);
    CHECK(gables >= n - 1);
}

TEST_CASE("A town of every roof family with 40 % dark roofs at 4 pts/m2 and a 25-degree sun - roof types >= 0.95, no flat fallback", "[roof][synth]") {
    // bench_accuracy families=1 dark=0.4 density=4 sun_el=25 size=300 seed=215:
    // 0.926 with 2 fallbacks before the partition lines reached past their
    // sparse samples and hips were told by their ridge ends; 0.985 after.
    test::ScratchDir dir("sparse_dark_roof_types");
    SynthOptions o;
    o.size_m = 300;
    o.seed = 215;
    o.cloud_density_m2 = 4.0;
    o.sun_elevation_deg = 25.0;
    o.variation.dark_roof_share = 0.4;
    o.variation.all_roof_families = true;
    const SynthResult s = write_synthetic_town(dir.path.string(), o);
    const PolygonLayer truth = read_polygon_layer(s.truth_path, "");
    RoofsRunOptions ro;
    ro.heights.heights.keep_roof_points = true;
    const HeightsStage st = compute_heights_stage(s.truth_path, s.cloud_path, ro.heights);
    RoofsRunReport rep;
    const CityModel model = build_lod2_model(st, st.table.crs, ro, s.truth_path, rep);
    const auto type_at = std::find(truth.field_names.begin(), truth.field_names.end(), "roof_type");
    REQUIRE(type_at != truth.field_names.end());
    REQUIRE(model.buildings.size() == truth.features.size());
    int correct = 0, hips = 0, hips_right = 0;
    for (std::size_t i = 0; i < model.buildings.size(); ++i) {
        const std::string t = std::get<std::string>(truth.features[i].values[static_cast<std::size_t>(type_at - truth.field_names.begin())]);
        correct += model.buildings[i].roof_type == t;
        hips += t == "hip", hips_right += t == "hip" && model.buildings[i].roof_type == "hip";
        CHECK(model.buildings[i].lod2_errors.empty());
    }
    INFO(correct << " of " << model.buildings.size() << " roof types right, hips " << hips_right << " of " << hips << ", fallbacks " << rep.fallbacks);
    CHECK(double(correct) / double(model.buildings.size()) >= 0.95);
    CHECK(hips_right >= hips - 2);
    CHECK(rep.fallbacks == 0);
}
