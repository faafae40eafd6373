// Photogrammetry on synthetic photos with exact truth: synth views, stereo,
// densify (accuracy floors against surface.las, thread-count independence),
// orient (COLMAP) pose error and repeatability (our deterministic matcher),
// and bad input refused in one line.
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <tbb/global_control.h>

#include <opencv2/imgcodecs.hpp>

#include "audit/cloud_compare.hpp"
#include "cloud/las.hpp"
#include "core/error.hpp"
#include "photo/camera.hpp"
#include "photo/densify.hpp"
#include "photo/feature_matching.hpp"
#include "pipeline/photo_run.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::run_cli;
using cityforge::test::make_views;
using cityforge::test::ScratchDir;
namespace fs = std::filesystem;

namespace {

// Reference points inside the xy box of `pred` (a pair sees only part of the block).
PointCloud crop_to(const PointCloud& ref, const PointCloud& pred) {
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
    for (std::size_t i = 0; i < pred.size(); ++i)
        x0 = std::min(x0, pred.x[i]), x1 = std::max(x1, pred.x[i]), y0 = std::min(y0, pred.y[i]), y1 = std::max(y1, pred.y[i]);
    PointCloud out;
    for (std::size_t i = 0; i < ref.size(); ++i)
        if (ref.x[i] >= x0 && ref.x[i] <= x1 && ref.y[i] >= y0 && ref.y[i] <= y1) out.append(ref, i);
    return out;
}

std::vector<cv::Mat> read_views(const std::string& dir, const photo::CameraSet& set) {
    std::vector<cv::Mat> v;
    for (const auto& c : set.cameras) v.push_back(cv::imread(dir + "/" + c.image, cv::IMREAD_COLOR));
    return v;
}

}  // namespace

TEST_CASE("synth --views renders photos with exact cameras and the exact surface", "[photo][synth]") {
    ScratchDir dir("photo_views");
    const SynthResult r = make_views(dir);
    REQUIRE(r.views == 4);
    const photo::CameraSet set = photo::read_cameras_json(dir / "views/cameras_truth.json");
    REQUIRE(set.cameras.size() == 4);
    CHECK(set.crs == "EPSG:32650");
    CHECK(fs::exists(dir / "views/K.txt"));
    CHECK(test::count_lines(test::slurp(dir / "views/gps.txt")) == 5);
    for (const auto& c : set.cameras) {
        const cv::Mat m = cv::imread(dir / ("views/" + c.image), cv::IMREAD_COLOR);
        REQUIRE(m.cols == 320);
        REQUIRE(m.rows == 240);
        // The surface point below the image centre projects back to the centre.
        CHECK(c.rotation.row(2).z() < -0.99);  // looking down
    }
    const PointCloud surface = read_las(dir / "surface.las");
    CHECK(surface.size() == r.surface_points);
    CHECK(surface.size() > 100000);
    // Surface kinds: terrain 2, roofs 6, walls synth::kSurfaceWallClass; a
    // wall sample stands on its outline between the terrain and the roof.
    std::size_t kinds[3] = {0, 0, 0};
    for (std::size_t i = 0; i < surface.size(); ++i) {
        const uint8_t c = surface.classification[i];
        kinds[0] += c == las_class::ground, kinds[1] += c == las_class::building, kinds[2] += c == synth::kSurfaceWallClass;
    }
    CHECK(kinds[0] > 10000);
    CHECK(kinds[1] > 1000);
    CHECK(kinds[2] > 1000);
    // Every camera sees the surface it was rendered from: points project inside it.
    const auto& c0 = set.cameras[0];
    int inside = 0;
    for (std::size_t i = 0; i < surface.size(); i += 97) {
        const auto px = c0.project({surface.x[i], surface.y[i], surface.z[i]});
        inside += px && c0.inside(*px);
    }
    CHECK(inside > 50);
    // Without --views nothing of this is written.
    ScratchDir plain("photo_noviews");
    SynthOptions o;
    o.size_m = 60;
    o.cloud_density_m2 = 0;
    write_synthetic_town(plain.path.string(), o);
    CHECK(!fs::exists(plain / "views"));
    CHECK(!fs::exists(plain / "surface.las"));
}

TEST_CASE("stereo and densify reach accuracy floors on synthetic photos", "[photo][stereo][densify]") {
    ScratchDir dir("photo_dense");
    make_views(dir);
    const PointCloud surface = read_las(dir / "surface.las");

    // Stereo of the first forward pair (80 % overlap).
    const auto s = run_cli("stereo -q --left " + (dir / "views/view_000.png") + " --right " + (dir / "views/view_001.png") +
                           " --cameras " + (dir / "views/cameras_truth.json") + " --out " + (dir / "stereo.las"));
    REQUIRE(s.exit_code == 0);
    const PointCloud st = read_las(dir / "stereo.las");
    REQUIRE(st.size() > 10000);
    const CloudComparison cs = compare_clouds(st, crop_to(surface, st), {0.1, 0.25, 0.5});
    INFO("stereo P/R/F@0.25 " << cs.scores[1].precision << " " << cs.scores[1].recall << " " << cs.scores[1].f_score);
    CHECK(cs.scores[1].precision > 0.75);
    CHECK(cs.scores[2].f_score > 0.6);
    // Existing output is not replaced without --overwrite.
    const auto again = run_cli("stereo -q --left " + (dir / "views/view_000.png") + " --right " + (dir / "views/view_001.png") +
                               " --cameras " + (dir / "views/cameras_truth.json") + " --out " + (dir / "stereo.las"));
    CHECK(again.exit_code != 0);

    // Densify all views; thread-count independent output.
    const photo::CameraSet set = photo::read_cameras_json(dir / "views/cameras_truth.json");
    const auto images = read_views(dir / "views", set);
    photo::DensifyOptions o;
    photo::DensifyResult one, two;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        one = photo::densify_patches(images, set, {}, o, "views");
    }
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
        two = photo::densify_patches(images, set, {}, o, "views");
    }
    REQUIRE(one.cloud.size() == two.cloud.size());
    CHECK(one.cloud.x == two.cloud.x);
    CHECK(one.cloud.z == two.cloud.z);
    const CloudComparison cd = compare_clouds(one.cloud, surface, {0.1, 0.25, 0.5});
    INFO("densify P/R/F@0.25 " << cd.scores[1].precision << " " << cd.scores[1].recall << " " << cd.scores[1].f_score);
    CHECK(cd.scores[1].precision > 0.85);
    CHECK(cd.scores[2].f_score > 0.6);
    // Where the parent's plane misses (roof edges, wall feet), expansion also
    // starts from a wall and a level plane: more of the walls, as precise.
    photo::DensifyOptions plane_only = o;
    plane_only.wall_hypotheses = false;
    const photo::DensifyResult po = photo::densify_patches(images, set, {}, plane_only, "views");
    const auto wall_recall = [&](const PointCloud& pred) {
        PointCloud walls;
        for (std::size_t i = 0; i < surface.size(); ++i)
            if (surface.classification[i] == synth::kSurfaceWallClass) walls.append(surface, i);
        return compare_clouds(pred, walls, {0.25}).scores[0].recall;
    };
    const CloudComparison cpo = compare_clouds(po.cloud, surface, {0.25});
    INFO("walls R@0.25 " << wall_recall(one.cloud) << " (parent's plane only " << wall_recall(po.cloud) << "), P@0.25 " << cpo.scores[0].precision);
    CHECK(wall_recall(one.cloud) > wall_recall(po.cloud));
    CHECK(cd.scores[1].recall > cpo.scores[0].recall);
    CHECK(cd.scores[1].precision > cpo.scores[0].precision - 0.02);
    // Cells of at least cell_m on the surface: here 0.6 m = 4 px at 0.15 m,
    // fewer patches (about (3/4)^2 of them) of the same precision.
    photo::DensifyOptions coarse = o;
    coarse.cell_m = 0.6;
    const photo::DensifyResult co = photo::densify_patches(images, set, {}, coarse, "views");
    const CloudComparison cco = compare_clouds(co.cloud, surface, {0.25});
    INFO("cell_m 0.6: " << co.patches << " patches (" << one.patches << " at 3 px), P@0.25 " << cco.scores[0].precision);
    CHECK(double(co.patches) < 0.8 * double(one.patches));
    CHECK(double(co.patches) > 0.3 * double(one.patches));
    CHECK(cco.scores[0].precision > 0.85);
    // Patch centres stay within the scene's height range widened by half its
    // span, at least 5 m (a depth search that ran away along a weak-texture
    // ray, as on Seattle's plaza, km below the ground): a range cut 2 m above
    // the ground keeps every point below 2 + 5 m (plus a patch's half width).
    double zmin = 1e300, zmax = -1e300;
    for (double z : one.cloud.z) zmin = std::min(zmin, z), zmax = std::max(zmax, z);
    const double ground = set.scene_z_range_m[0];
    REQUIRE(zmax > ground + 8.0);  // buildings above the cut
    photo::CameraSet low = set;
    low.scene_z_range_m = {ground, ground + 2.0};
    const photo::DensifyResult lo = photo::densify_patches(images, low, {}, o, "views");
    double lo_max = -1e300;
    for (double z : lo.cloud.z) lo_max = std::max(lo_max, z);
    INFO("z range " << zmin << ".." << zmax << ", cut at " << ground + 2.0 << ": max " << lo_max);
    CHECK(lo_max < ground + 7.5);
    CHECK(lo.cloud.size() > 0);
    // A patch must also be confirmed by a share of the images that should see
    // it: all of them (share 1) keeps fewer patches, not less precise ones.
    photo::DensifyOptions strict = o;
    strict.min_view_share = 1.0;
    const photo::DensifyResult sv = photo::densify_patches(images, set, {}, strict, "views");
    const CloudComparison csv = compare_clouds(sv.cloud, surface, {0.25});
    INFO("min_view_share 1: " << sv.patches << " patches (" << one.patches << "), P@0.25 " << csv.scores[0].precision);
    CHECK(sv.patches < one.patches);
    CHECK(csv.scores[0].precision > cd.scores[1].precision - 0.01);
    // Densification beats its own seeds (the sparse, feature-based points) by far in recall.
    photo::DensifyOptions centres = o;
    centres.points_per_patch_side = 1;
    centres.iterations = 1;
    centres.max_expansion_steps = 1;
    const photo::DensifyResult sparse = photo::densify_patches(images, set, {}, centres, "views");
    const CloudComparison cp = compare_clouds(sparse.cloud, surface, {0.5});
    CHECK(cd.scores[2].recall > 3.0 * cp.scores[0].recall);
}

TEST_CASE("photo commands refuse bad input in one line and write nothing", "[photo][errors]") {
    ScratchDir dir("photo_bad");
    make_views(dir, 4);
    const std::string views = dir / "views";
    // Fewer than two images.
    fs::create_directories(dir / "one");
    fs::copy_file(views + "/view_000.png", dir / "one/view_000.png");
    auto r = run_cli("orient -q --images " + (dir / "one") + " --gps " + views + "/gps.txt --out " + (dir / "o1"));
    CHECK(r.exit_code != 0);
    CHECK(r.err.find("fewer than two images") != std::string::npos);
    CHECK(test::count_lines(r.err) == 1);
    CHECK(!fs::exists(dir / "o1"));
    // No EXIF (PNG) and no GPS file.
    r = run_cli("orient -q --images " + views + " --out " + (dir / "o2"));
    CHECK(r.exit_code != 0);
    CHECK(r.err.find("GPS") != std::string::npos);
    CHECK(!fs::exists(dir / "o2"));
    // A camera matrix of another image size.
    {
        std::ofstream k(dir / "K_wrong.txt");
        k << "2684.2 0 2005.7\n0 2660.7 1529.9\n0 0 1\n";
    }
    r = run_cli("orient -q --images " + views + " --gps " + views + "/gps.txt --camera " + (dir / "K_wrong.txt") + " --out " + (dir / "o3"));
    CHECK(r.exit_code != 0);
    CHECK(r.err.find("K_wrong.txt") != std::string::npos);
    CHECK(!fs::exists(dir / "o3"));
    // A cameras file whose size does not match the images.
    {
        std::string j = test::slurp(views + "/cameras_truth.json");
        for (std::size_t p = j.find("\"width\": 320"); p != std::string::npos; p = j.find("\"width\": 320")) j.replace(p, 12, "\"width\": 640");
        std::ofstream(dir / "cams_wrong.json") << j;
    }
    r = run_cli("stereo -q --left " + views + "/view_000.png --right " + views + "/view_001.png --cameras " + (dir / "cams_wrong.json") +
                " --out " + (dir / "s.las"));
    CHECK(r.exit_code != 0);
    CHECK(r.err.find("640") != std::string::npos);
    CHECK(!fs::exists(dir / "s.las"));
    // An unknown ortho for the run.
    r = run_cli("photo -q --images " + views + " --gps " + views + "/gps.txt --run --run-ortho satellite --out " + (dir / "p1"));
    CHECK(r.exit_code != 0);
    CHECK(r.err.find("--run-ortho") != std::string::npos);
    CHECK(test::count_lines(r.err) == 1);
    CHECK(!fs::exists(dir / "p1"));
    // GPS heights in a CRS that is not vertical.
    r = run_cli("orient -q --images " + views + " --gps " + views + "/gps.txt --gps-height-crs EPSG:32650 --out " + (dir / "o1"));
    CHECK(r.exit_code != 0);
    CHECK(r.err.find("--gps-height-crs") != std::string::npos);
    CHECK(test::count_lines(r.err) == 1);
    CHECK(!fs::exists(dir / "o1"));
    // Densify of a folder without cameras.
    r = run_cli("densify -q --model " + (dir / "one") + " --out " + (dir / "d.las"));
    CHECK(r.exit_code != 0);
    CHECK(!fs::exists(dir / "d.las"));
}

TEST_CASE("match_descriptors follows COLMAP's ratio, distance and cross-check rules", "[photo][matching]") {
    // Descriptors of length ~512 as COLMAP stores them: 181 in 8 of the 128
    // bins; two share k bins: dot k * 181^2, angle acos(k / 8).
    auto rows = [](std::initializer_list<std::vector<int>> descriptors) {
        std::vector<uint8_t> out;
        for (const auto& bins : descriptors) {
            std::vector<uint8_t> d(128, 0);
            for (int k : bins) d[static_cast<std::size_t>(k)] = 181;
            out.insert(out.end(), d.begin(), d.end());
        }
        return out;
    };
    // a0 = b1 exactly; a1 shares 7 bins with b0 and 7 with b2 (a tie for
    // best fails the ratio test); a2 = b3; a3 shares 7 with b3, whose best is a2.
    const auto a = rows({{0, 1, 2, 3, 4, 5, 6, 7}, {16, 17, 18, 19, 20, 21, 22, 23}, {40, 41, 42, 43, 44, 45, 46, 47},
                         {41, 42, 43, 44, 45, 46, 47, 48}});
    const auto b = rows({{17, 18, 19, 20, 21, 22, 23, 24}, {0, 1, 2, 3, 4, 5, 6, 7}, {16, 18, 19, 20, 21, 22, 23, 25},
                         {40, 41, 42, 43, 44, 45, 46, 47}});
    photo::FeatureMatchOptions o;
    using Matches = std::vector<std::pair<uint32_t, uint32_t>>;
    CHECK(photo::match_descriptors(a.data(), 4, b.data(), 4, o) == Matches{{0, 1}, {2, 3}});
    // Without the cross-check a3 -> b3 (one way only) is kept too.
    o.cross_check = false;
    CHECK(photo::match_descriptors(a.data(), 4, b.data(), 4, o) == Matches{{0, 1}, {2, 3}, {3, 3}});
    // The ratio: best at 0.02 rad, second at 0.51 rad.
    const auto c = rows({{60, 61, 62, 63, 64, 65, 66, 67}});
    const auto d = rows({{60, 61, 62, 63, 64, 65, 66, 67}, {60, 61, 62, 63, 64, 65, 66, 70}});
    CHECK(photo::match_descriptors(c.data(), 1, d.data(), 2, {}).size() == 1);
    photo::FeatureMatchOptions strict;
    strict.max_ratio = 0.03;
    CHECK(photo::match_descriptors(c.data(), 1, d.data(), 2, strict).empty());
    // The distance: an only neighbour sharing half the bins (1.05 rad) is no match.
    const auto e = rows({{80, 81, 82, 83, 90, 91, 92, 93}});
    const auto f = rows({{80, 81, 82, 83, 84, 85, 86, 87}});
    CHECK(photo::match_descriptors(e.data(), 1, f.data(), 1, {}).empty());
    // The match list of `colmap matches_importer`: pairs with matches only;
    // a name with a space (the importer would cut it) is refused.
    {
        ScratchDir dir("photo_match_list");
        std::vector<photo::ImageFeatures> images(3);
        images[0].name = "a.png", images[1].name = "b.png", images[2].name = "c.png";
        const std::vector<photo::PairMatches> pm{{0, 1, {{0, 1}, {2, 3}}}, {0, 2, {}}, {1, 2, {{4, 5}}}};
        photo::write_colmap_match_list(dir / "m.txt", images, pm);
        CHECK(test::slurp(dir / "m.txt") == "a.png b.png\n0 1\n2 3\n\nb.png c.png\n4 5\n\n");
        images[1].name = "b 1.png";
        CHECK_THROWS_AS(photo::write_colmap_match_list(dir / "m2.txt", images, pm), Error);
    }
    // Pair lists.
    CHECK(photo::exhaustive_pairs(4).size() == 6);
    CHECK(photo::sequential_pairs(5, 2) == std::vector<std::pair<int, int>>{{0, 1}, {0, 2}, {1, 2}, {1, 3}, {2, 3}, {2, 4}, {3, 4}});
}

TEST_CASE("orient gives the same bytes with 1 and 2 threads", "[photo][orient][repeat]") {
    if (std::system("colmap help >/dev/null 2>&1") != 0) {
        WARN("colmap is not installed: orient not tested");
        return;
    }
    ScratchDir dir("photo_orient_repeat");
    make_views(dir, 4);
    const std::string views = dir / "views";
    const std::string args = " --images " + views + " --gps " + views + "/gps.txt --camera " + views + "/K.txt --out ";
    const auto r1 = run_cli("orient -q --threads 1" + args + (dir / "o1"));
    INFO(r1.err);
    REQUIRE(r1.exit_code == 0);
    const auto r2 = run_cli("orient -q --threads 2" + args + (dir / "o2"));
    INFO(r2.err);
    REQUIRE(r2.exit_code == 0);
    const std::string c1 = test::slurp(dir / "o1/cameras.json");
    CHECK(photo::read_cameras_json(dir / "o1/cameras.json").cameras.size() == 4);
    CHECK(c1 == test::slurp(dir / "o2/cameras.json"));
    CHECK(test::slurp(dir / "o1/sparse.las") == test::slurp(dir / "o2/sparse.las"));
    CHECK(test::slurp(dir / "o1/colmap/matches.txt") == test::slurp(dir / "o2/colmap/matches.txt"));
    for (const auto& e : fs::directory_iterator(dir / "o1/images"))
        CHECK(test::slurp(e.path().string()) == test::slurp(dir / ("o2/images/" + e.path().filename().string())));
    // The matcher itself: the same matches whatever TBB's thread count.
    const auto features = photo::read_colmap_features(dir / "o1/colmap/database.db");
    REQUIRE(features.size() == 4);
    CHECK(features[0].name == "view_000.png");
    CHECK(features[0].count > 100);
    CHECK(features[0].xy.size() == 2 * features[0].count);
    CHECK(features[0].scale.size() == features[0].count);
    CHECK(features[0].width == 320);
    // Image ids follow the names (COLMAP numbers them as its threads finish).
    for (std::size_t k = 0; k < features.size(); ++k) CHECK(features[k].image_id == int(k) + 1);
    CHECK(features[3].name == "view_003.png");
    const auto pairs = photo::exhaustive_pairs(4);
    std::vector<photo::PairMatches> one, two;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        one = photo::match_image_pairs(features, pairs, {});
    }
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
        two = photo::match_image_pairs(features, pairs, {});
    }
    REQUIRE(one.size() == 6);
    // Keypoints at the image edge (COLMAP leaves their descriptors unset) are not matched.
    for (const auto& [x, y] : one[0].matches) {
        CHECK(photo::matchable_feature(features[0], x, {}));
        CHECK(photo::matchable_feature(features[1], y, {}));
    }
    for (std::size_t k = 0; k < one.size(); ++k) CHECK(one[k].matches == two[k].matches);
    CHECK(one[0].matches.size() > 50);  // forward neighbours overlap by 80 %
    // Mutual nearest neighbours: matching the other way round gives them swapped.
    const auto back = photo::match_image_pairs(features, {{1, 0}}, {});
    REQUIRE(back[0].matches.size() == one[0].matches.size());
    std::vector<std::pair<uint32_t, uint32_t>> swapped;
    for (const auto& [x, y] : back[0].matches) swapped.emplace_back(y, x);
    std::sort(swapped.begin(), swapped.end());
    CHECK(swapped == one[0].matches);
    // A corrupt database (a header claiming more keypoints than the blob
    // holds, a huge column count, 64-byte descriptors) is refused naming it.
    const auto corrupt = [&](const std::string& name, const std::string& sql) {
        const std::string db = dir / (name + ".db");
        fs::copy_file(dir / "o1/colmap/database.db", db, fs::copy_options::overwrite_existing);
        REQUIRE(test::run_command("python3 -c \"import sqlite3; c = sqlite3.connect('" + db + "'); c.execute('" + sql + "'); c.commit()\"").exit_code == 0);
        return db;
    };
    for (const std::string sql : {"UPDATE keypoints SET rows = rows + 1000000 WHERE image_id = 2", "UPDATE keypoints SET cols = 4611686018427387904 WHERE image_id = 1",
                                  "UPDATE descriptors SET cols = 64, rows = rows * 2 WHERE image_id = 3"}) {
        const std::string db = corrupt("bad", sql);
        INFO(sql);
        try {
            photo::read_colmap_features(db);
            FAIL("a corrupt database was read");
        } catch (const Error& e) {
            CHECK(std::string(e.what()).find("bad.db") != std::string::npos);
        }
    }
}

// It once ran past ctest's limit: a noisy photogrammetric roof gave thousands of
// plane pairs, and the LOD2 partition of their lines grew with their square
// (now a flat fallback past Lod2Options::max_partition_lines). About 45 s.
TEST_CASE("photo --run: orient, densify, true ortho and the building run on synthetic photos", "[photo][orient][run]") {
    if (std::system("colmap help >/dev/null 2>&1") != 0) {
        WARN("colmap is not installed: orient not tested");
        return;
    }
    ScratchDir dir("photo_orient");
    make_views(dir, 6);
    const std::string views = dir / "views";
    {
        std::ofstream cfg(dir / "run.json");
        cfg << R"({"export": {"formats": ["geojson"], "geojson_crs": "native"}})";
    }
    const std::string out = dir / "ph";
    const auto r = run_cli("photo -q --images " + views + " --gps " + views + "/gps.txt --camera " + views + "/K.txt --out " + out +
                           " --run --run-config " + (dir / "run.json"));
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    // Orientation: poses against the written truth.
    const photo::CameraSet est = photo::read_cameras_json(out + "/cameras.json");
    const photo::CameraSet truth = photo::read_cameras_json(views + "/cameras_truth.json");
    const photo::PoseError e = photo::compare_poses(est, truth);
    INFO("pose error " << e.mean_position_m << " m, " << e.mean_angle_deg << " deg");
    CHECK(e.matched == 6);
    CHECK(e.mean_position_m < 0.5);
    CHECK(e.mean_angle_deg < 0.5);
    // The dense cloud: LAS 1.4, RGB, class 1, in the cameras' CRS; it beats the sparse cloud by far in recall.
    const PointCloud dense = read_las(out + "/cloud.las");
    REQUIRE(dense.size() > 10000);
    CHECK(dense.has_color());
    CHECK(std::all_of(dense.classification.begin(), dense.classification.end(), [](uint8_t c) { return c == 1; }));
    CHECK(test::slurp(out + "/cloud.las").substr(24, 2) == std::string("\x01\x04", 2));  // version 1.4
    const PointCloud surface = read_las(dir / "surface.las");
    const CloudComparison cd = compare_clouds(dense, surface, {0.5});
    const CloudComparison cs = compare_clouds(read_las(out + "/sparse.las"), surface, {0.5});
    INFO("dense R " << cd.scores[0].recall << " sparse R " << cs.scores[0].recall);
    CHECK(cd.scores[0].recall > 5 * cs.scores[0].recall);
    CHECK(cd.scores[0].precision > 0.7);
    // The report names every step with its time and counts.
    const nlohmann::json rep = nlohmann::json::parse(test::slurp(out + "/photo_report.json"));
    REQUIRE(rep["steps"].size() == 5);
    CHECK(rep["steps"][0]["step"] == "orient");
    CHECK(rep["steps"][0]["oriented"] == 6);
    CHECK(rep["steps"][1]["points"] == dense.size());
    CHECK(rep["steps"][3]["step"] == "orthophoto");
    CHECK(rep["steps"][3]["cells_coloured"].get<long>() > rep["steps"][3]["cells_measured"].get<long>() / 2);
    CHECK(rep["steps"][3]["run_ortho"] == "photos");
    CHECK(rep["steps"][4]["step"] == "run");
    CHECK(rep["crs"] == "EPSG:32650+5773");  // GPS heights are EGM96 by default (--gps-height-crs)
    // The true ortho and the run: DSM mosaic and buildings at the truth's places and heights.
    CHECK(fs::exists(out + "/ortho.tif"));
    CHECK(fs::exists(out + "/orthophoto.tif"));
    CHECK(fs::exists(out + "/run/dsm.vrt"));
    const nlohmann::json found = nlohmann::json::parse(test::slurp(out + "/run/buildings.geojson"));
    const nlohmann::json truth_fp = nlohmann::json::parse(test::slurp(dir / "truth.geojson"));
    auto outer_ring = [](const nlohmann::json& f) -> const nlohmann::json& {
        const auto& geom = f["geometry"];
        return geom["type"] == "MultiPolygon" ? geom["coordinates"][0][0] : geom["coordinates"][0];
    };
    auto inside = [](double x, double y, const nlohmann::json& ring) {
        bool in = false;
        for (std::size_t k = 0; k + 1 < ring.size(); ++k) {
            const double x1 = ring[k][0], y1 = ring[k][1], x2 = ring[k + 1][0], y2 = ring[k + 1][1];
            if ((y1 > y) != (y2 > y) && x < x1 + (y - y1) * (x2 - x1) / (y2 - y1)) in = !in;
        }
        return in;
    };
    // A found building (often cut by the block's edge) matches the truth
    // building holding its vertex centroid when its height lies between that
    // building's eave and ridge (1 m slack).
    int ok = 0, matched = 0;
    for (const auto& f : found["features"]) {
        if (f["properties"]["status"] != "ok") continue;
        ++ok;
        const auto& ring = outer_ring(f);
        double x = 0, y = 0;
        for (std::size_t k = 0; k + 1 < ring.size(); ++k) x += ring[k][0].get<double>(), y += ring[k][1].get<double>();
        x /= double(ring.size() - 1), y /= double(ring.size() - 1);
        for (const auto& t : truth_fp["features"]) {
            if (!inside(x, y, outer_ring(t))) continue;
            const double h = f["properties"]["height_m"].get<double>();
            if (h > t["properties"]["eave_height_m"].get<double>() - 1.0 && h < t["properties"]["ridge_height_m"].get<double>() + 1.0)
                ++matched;
            break;
        }
    }
    // Orientation is repeatable (our matcher; one mapper thread), so the
    // count is too: every building found is a truth building at its height.
    INFO(ok << " buildings, " << matched << " at a truth building with its height");
    CHECK(matched >= 1);
    CHECK(matched == ok);
    // An existing output is refused.
    const auto again = run_cli("photo -q --images " + views + " --gps " + views + "/gps.txt --camera " + views + "/K.txt --out " + out);
    CHECK(again.exit_code != 0);
    CHECK(test::count_lines(again.err) == 1);
}

TEST_CASE("photo: photos without overlap give a one-line error and write nothing", "[photo][errors][orient]") {
    if (std::system("colmap help >/dev/null 2>&1") != 0) {
        WARN("colmap is not installed: orient not tested");
        return;
    }
    ScratchDir dir("photo_no_overlap");
    SynthOptions o;
    o.size_m = 120;
    o.seed = 4;
    o.cloud_density_m2 = 0;
    o.views.views = 4;
    o.views.gsd_m = 0.15;
    o.views.width_px = 320;
    o.views.height_px = 240;
    o.views.forward_overlap = 0.0;
    o.views.side_overlap = 0.0;
    o.views.surface_spacing_m = 1.0;
    write_synthetic_town(dir.path.string(), o);
    const std::string views = dir / "views";
    const auto r = run_cli("photo --images " + views + " --gps " + views + "/gps.txt --camera " + views + "/K.txt --out " + (dir / "ph"));
    INFO(r.err);
    CHECK(r.exit_code == 1);
    CHECK(test::count_lines(r.err) == 1);
    CHECK(r.err.find("overlap") != std::string::npos);
    CHECK(!fs::exists(dir / "ph"));
    for (const auto& e : fs::directory_iterator(dir.path)) CHECK(e.path().filename().string().find(".part-") == std::string::npos);
}

// The heights of a georeferenced photo block are in a named vertical CRS:
// EXIF's GPSAltitude is above sea level (EGM96 by default), ellipsoidal
// heights go through PROJ's EGM96 grid (Seattle: N = -22.3 m), and an output
// CRS with its own vertical part is kept.
TEST_CASE("orient: GPS heights and the output CRS carry a vertical datum", "[photo][orient][crs]") {
    OrientRunOptions o;
    const double lat = 47.61, lon = -122.32;
    const GpsFrames geoid = gps_frames(o, lat, lon);
    CHECK(geoid.gps.label() == "EPSG:4326+5773");
    CHECK(geoid.out.label() == "EPSG:32610+5773");
    CHECK(z_crs_label(geoid.out) == "EPSG:5773");
    std::vector<double> x{lon}, y{lat}, z{20.0};
    transform_points(geoid.gps, geoid.out, x, y, z, "test");
    CHECK(z[0] == Approx(20.0).margin(1e-6));  // same datum: heights unchanged

    o.gps_height_crs = "ellipsoid";
    const GpsFrames ell = gps_frames(o, lat, lon);
    CHECK(ell.gps.label() == "EPSG:4979");
    CHECK(ell.out.label() == "EPSG:32610+5773");
    x = {lon}, y = {lat}, z = {20.0};
    transform_points(ell.gps, ell.out, x, y, z, "test");
    CHECK(z[0] == Approx(42.30).margin(0.05));  // h - N, N(EGM96) = -22.30 m here

    o.gps_height_crs = "EPSG:5773";
    o.crs = "EPSG:32610+5703";  // NAVD88 height asked for: kept as the output's vertical CRS
    CHECK(gps_frames(o, lat, lon).out.label() == "EPSG:32610+5703");
    o.crs = "EPSG:2926";  // a projected CRS in US feet without a vertical part gets the GPS heights' one
    CHECK(gps_frames(o, lat, lon).out.vertical_epsg == 5773);

    o.crs.clear();
    o.gps_height_crs = "EPSG:32610";
    CHECK_THROWS_WITH(gps_frames(o, lat, lon), Catch::Contains("--gps-height-crs") && Catch::Contains("vertical CRS"));
    o.gps_height_crs = "EPSG:5773";
    o.crs = "EPSG:4326";
    CHECK_THROWS_WITH(gps_frames(o, lat, lon), Catch::Contains("--crs") && Catch::Contains("projected"));
}
