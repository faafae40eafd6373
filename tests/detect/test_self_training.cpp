#include <catch2/catch.hpp>
#include <tbb/global_control.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "audit/footprint_match.hpp"
#include "core/error.hpp"
#include "detect/detector.hpp"
#include "detect/self_training.hpp"
#include "io/vector.hpp"
#include "pipeline/footprints_run.hpp"
#include "footprints_threads.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;

TEST_CASE("Height coverage is the data pixels closed by a radius - borders are not eroded", "[detect]") {
    const int w = 20, h = 10;
    std::vector<uint8_t> has(std::size_t(w) * h, 0);
    // Sparse points every 3rd pixel over the west half.
    for (int y = 0; y < h; y += 3)
        for (int x = 0; x < 10; x += 3) has[std::size_t(y) * w + x] = 1;
    const std::vector<uint8_t> c = detect::coverage_mask(has, w, h, 2);
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x <= 9; ++x) CHECK(c[std::size_t(y) * w + x] == 1);    // gaps between points closed
        for (int x = 12; x < w; ++x) CHECK(c[std::size_t(y) * w + x] == 0);  // no data: not covered
    }
    CHECK(detect::coverage_mask(has, w, h, 0) == has);
    CHECK_THROWS_AS(detect::coverage_mask(has, w, h - 1, 2), Error);
}

TEST_CASE("ortho_cloud with a cloud over part of the ortho: an image model self-trained on the cloud's buildings finds the others (CLI, source field)",
          "[detect][synth][cli]") {
    ScratchDir dir("detect_self_training");
    const double size = 300.0, x0 = 500000.0, y0 = 4400000.0;
    const SynthResult t = make_town(dir, size, 41, 4.0);
    // The cloud keeps the western 45 % of the town.
    const double cut = x0 + 0.45 * size;
    const std::string west = dir / "cloud_west.las";
    char bounds[128];
    std::snprintf(bounds, sizeof bounds, "%.1f,%.1f,%.1f,%.1f", x0 - 10.0, y0 - 10.0, cut, y0 + size + 10.0);
    REQUIRE(test::run_cli("cloud translate --quiet " + t.cloud_path + " " + west + " --bounds " + bounds).exit_code == 0);

    const std::string out = dir / "fp.geojson";
    const auto r = test::run_cli("footprints --ortho " + t.ortho_path + " --cloud " + west + " --out " + out);
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    CHECK(r.err.find("from the image") != std::string::npos);
    const PolygonLayer fp = read_polygon_layer(out);
    const auto field = std::find(fp.field_names.begin(), fp.field_names.end(), "source");
    REQUIRE(field != fp.field_names.end());
    const auto source_f = static_cast<std::size_t>(field - fp.field_names.begin());
    // Buildings wholly on one side of the cloud's edge (a margin for the coverage closing).
    auto side = [&](const std::vector<Polygon>& g) {
        const Extent e = parts_extent(g);
        return e.max_x < cut - 5.0 ? -1 : e.min_x > cut + 5.0 ? 1 : 0;
    };
    std::vector<std::vector<Polygon>> image_east, cloud_west, truth_east, truth_west;
    std::size_t image_in_west = 0;
    for (const Feature& f : fp.features) {
        const std::string src = std::get<std::string>(f.values[source_f]);
        REQUIRE((src == "cloud" || src == "image_model"));
        const int s = side(f.geometry);
        if (src == "image_model" && s == 1) image_east.push_back(f.geometry);
        if (src == "image_model" && s == -1) ++image_in_west;
        if (src == "cloud" && s == -1) cloud_west.push_back(f.geometry);
        if (src == "cloud") CHECK(s != 1);  // the cloud has no point there
    }
    for (const Feature& f : read_polygon_layer(t.truth_path).features) {
        const int s = side(f.geometry);
        if (s == 1) truth_east.push_back(f.geometry);
        if (s == -1) truth_west.push_back(f.geometry);
    }
    REQUIRE(truth_east.size() >= 20);
    // Under the cloud the cloud decides; only a roof without returns (synth's
    // dark roofs absorb most pulses) is a gap the image model may fill.
    CHECK(image_in_west <= 2);
    const FootprintScores east = match_footprints(image_east, truth_east, 0.5);
    const FootprintScores wests = match_footprints(cloud_west, truth_west, 0.5);
    std::printf("self-training: outside the cloud (image model) %zu predicted, %zu reference, P %.3f R %.3f F1 %.3f; under it (cloud) F1 %.3f\n",
                east.predicted, east.reference, east.precision, east.recall, east.f1, wests.f1);
    CHECK(east.f1 >= 0.9);
    CHECK(wests.f1 >= 0.9);

    // Same bytes for 1 and 2 threads (the scene model trains on one thread).
    {
        FootprintsRunOptions o;
        o.ortho = t.ortho_path, o.cloud = west;
        test::run_footprints_1_and_2_threads(dir / "t1.geojson", dir / "t2.geojson", o);
        CHECK(test::slurp(dir / "t1.geojson") == test::slurp(out));
    }

    // Off: the buildings outside the cloud are not found.
    const std::string off = dir / "off.geojson";
    REQUIRE(test::run_cli("footprints --quiet --self-training off --ortho " + t.ortho_path + " --cloud " + west + " --out " + off).exit_code == 0);
    const PolygonLayer fo = read_polygon_layer(off);
    for (const Feature& f : fo.features) CHECK(std::get<std::string>(f.values[source_f]) == "cloud");
    CHECK(fo.features.size() + image_east.size() <= fp.features.size());
}

TEST_CASE("run config: extraction.detector and extraction.model are read, recorded and applied - unknown values refused", "[detect][run][cli]") {
    ScratchDir dir("detect_run_config");
    const SynthResult t = make_town(dir, 100, 43, 0.0);
    auto config = [&](const std::string& name, const std::string& extraction) {
        std::ofstream(dir / name) << R"({"extraction": )" + extraction + "}";
        return dir / name;
    };
    const std::string rules = config("rules.json", R"({"detector": "rules"})");
    REQUIRE(test::run_cli("plan --quiet --ortho " + t.ortho_path + " --config " + rules + " --out " + (dir / "m.json")).exit_code == 0);
    const auto m = nlohmann::json::parse(test::slurp(dir / "m.json"));
    CHECK(m["options"]["extraction"]["detector"] == "rules");
    CHECK(m["options"]["extraction"]["model"] == "");
    CHECK(test::validate_json(test::source_dir() + "/schemas/run_config.schema.json", rules).exit_code == 0);

    const std::string bad = config("bad.json", R"({"detector": "cnn"})");
    CHECK(test::validate_json(test::source_dir() + "/schemas/run_config.schema.json", bad).exit_code == 1);
    const auto refused = test::run_cli("plan --ortho " + t.ortho_path + " --config " + bad + " --out " + (dir / "x.json"));
    CHECK(refused.exit_code == 1);
    CHECK(refused.err.find("extraction.detector") != std::string::npos);
    CHECK(test::count_lines(refused.err) == 1);

    // The model named in the config is the one applied: a missing file fails the run, naming it.
    const std::string missing = config("missing.json", R"({"detector": "model", "model": ")" + (dir / "none.cfdet") + R"("})");
    const auto run = test::run_cli("run --quiet --ortho " + t.ortho_path + " --config " + missing + " --out " + (dir / "out"));
    CHECK(run.exit_code == 1);
    CHECK(run.err.find("none.cfdet") != std::string::npos);
}

TEST_CASE("train --cloud: heights as an nDSM band - the model records it, needs it (cloud or nDSM raster) and refuses an image without it",
          "[detect][synth][cli]") {
    ScratchDir dir("detect_ndsm_band");
    const SynthResult a = make_town(dir, 200, 51, 3.0);
    ScratchDir bdir("detect_ndsm_band_b");
    const SynthResult b = make_town(bdir, 200, 52, 3.0);
    const std::string model = dir / "h.cfdet";
    const auto tr = test::run_cli("train --quiet --ortho " + a.ortho_path + " --cloud " + a.cloud_path + " --labels " + a.truth_path +
                                  " --folds 0 --rounds 80 --out " + model);
    INFO(tr.err);
    REQUIRE(tr.exit_code == 0);
    const detect::DetectorModel m = detect::read_model_file(model);
    CHECK(m.layout.ndsm_band == 3);
    CHECK(detect::describe_bands(m.layout) == "RGB+nDSM");
    CHECK(std::find(m.features.begin(), m.features.end(), "ndsm_mean") != m.features.end());

    // Applied with an nDSM raster on B's grid (rasterised from B's cloud by `cloud rasterize`).
    REQUIRE(test::run_cli("cloud rasterize --quiet --cloud " + b.cloud_path + " --grid " + b.ortho_path + " --out " + (bdir / "r")).exit_code == 0);
    const auto fp = test::run_cli("footprints --quiet --ortho " + b.ortho_path + " --ndsm " + (bdir / "r/ndsm.tif") + " --model " + model +
                                  " --out " + (bdir / "fp.geojson"));
    INFO(fp.err);
    REQUIRE(fp.exit_code == 0);
    std::vector<std::vector<Polygon>> p, t;
    for (const auto& f : read_polygon_layer(bdir / "fp.geojson").features) p.push_back(f.geometry);
    for (const auto& f : read_polygon_layer(b.truth_path).features) t.push_back(f.geometry);
    const FootprintScores s = match_footprints(p, t, 0.5);
    std::printf("nDSM band model: town A (RGB + cloud) applied to town B (RGB + nDSM raster): P %.3f R %.3f F1 %.3f\n", s.precision, s.recall, s.f1);
    CHECK(s.f1 >= 0.9);

    // Without heights: refused in one line naming the image and what is missing.
    const auto no = test::run_cli("footprints --ortho " + b.ortho_path + " --model " + model + " --out " + (bdir / "no.geojson"));
    CHECK(no.exit_code == 1);
    CHECK(no.err.find("ortho.tif") != std::string::npos);
    CHECK(no.err.find("RGB+nDSM") != std::string::npos);
    CHECK(test::count_lines(no.err) == 1);
    CHECK_FALSE(std::filesystem::exists(bdir / "no.geojson"));
    // One cloud per ortho.
    const auto two = test::run_cli("train --quiet --ortho " + a.ortho_path + " --ortho " + b.ortho_path + " --cloud " + a.cloud_path + " --labels " +
                                   a.truth_path + " --folds 0 --out " + (dir / "x.cfdet"));
    CHECK(two.exit_code == 1);
    CHECK(two.err.find("one cloud per ortho") != std::string::npos);
}
