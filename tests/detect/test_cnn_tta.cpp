// Test-time augmentation of the CNN pixel stage (CnnOptions::tta): exact
// equivariance under the averaged transforms, the same map for any thread
// count, the header key written only when on.
#include <catch2/catch.hpp>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/random.hpp"
#include "detect/cnn_pixel_stage.hpp"
#include "detect/detector.hpp"
#include "pipeline/footprints_run.hpp"
#include "pipeline/train_run.hpp"
#include "footprints_threads.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;

namespace {
constexpr int kChannels = 3;

// A planar grid (kChannels x h x w) of smooth blobs plus noise, so the network
// sees structure and its output is not flat.
std::vector<float> blob_grid(int w, int h, uint64_t seed) {
    std::vector<float> v(std::size_t(kChannels) * w * h);
    for (int c = 0; c < kChannels; ++c)
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const bool roof = ((x / 11 + y / 7 + c) % 3) == 0;
                v[(std::size_t(c) * h + y) * w + x] =
                    (roof ? 1.0f : -0.5f) + 0.3f * static_cast<float>(unit_from_hash(hash64(seed, uint64_t(c), uint64_t(y), uint64_t(x))) - 0.5);
            }
    return v;
}

// A few steps of training on one grid: weights that are not symmetric.
std::vector<uint8_t> small_weights(detect::CnnOptions& o) {
    o.base_channels = 4, o.levels = 2, o.crop_cells = 32, o.batch = 2, o.steps = 15;
    detect::CnnGrid g;
    g.width = 96, g.height = 80;
    g.input = blob_grid(g.width, g.height, 7);
    g.target.resize(std::size_t(g.width) * g.height), g.weight.assign(g.target.size(), 1.0f);
    for (int y = 0; y < g.height; ++y)
        for (int x = 0; x < g.width; ++x) g.target[std::size_t(y) * g.width + x] = g.input[std::size_t(y) * g.width + x] > 0.2f ? 1.0f : 0.0f;
    return detect::train_cnn({&g}, kChannels, o);
}

// The grid moved by `t` (bit 0: left-right flip, bit 1: up-down flip, bit 2:
// then transposed); planar with `channels` planes of a square side n.
std::vector<float> moved(const std::vector<float>& v, int n, int channels, int t) {
    std::vector<float> out(v.size());
    for (int c = 0; c < channels; ++c)
        for (int y = 0; y < n; ++y)
            for (int x = 0; x < n; ++x) {
                int mx = t & 1 ? n - 1 - x : x, my = t & 2 ? n - 1 - y : y;
                if (t & 4) std::swap(mx, my);
                out[(std::size_t(c) * n + my) * n + mx] = v[(std::size_t(c) * n + y) * n + x];
            }
    return out;
}
}  // namespace

TEST_CASE("CNN test-time augmentation: a flipped or transposed tile gives exactly the moved map, same map for 1 and 2 threads", "[detect][cnn]") {
    detect::CnnOptions o;
    const std::vector<uint8_t> w = small_weights(o);
    // A grid that is exactly one tile, padded alike on every side: training's
    // tiling on 128 x 128 cells; detection's clipped tiling on 192 x 192
    // (one tile of 256 x 256 with its margins, a multiple of 2^levels).
    const std::vector<std::pair<int, detect::CnnTiling>> single{{128, detect::kCnnTrainingTiling}, {192, detect::kCnnDetectionTiling}};
    for (const auto& [n, tiling] : single) {
        INFO("grid " << n << " x " << n << ", tiles of " << tiling.kept_cells);
        const std::vector<float> in = blob_grid(n, n, 11);
        const auto predict = [&](const std::vector<float>& x, int tta) {
            detect::CnnOptions p = o;
            p.tta = tta;
            return detect::predict_cnn(w, x, n, n, kChannels, p, tiling);
        };
        const std::vector<float> m1 = predict(in, 1), m4 = predict(in, 4), m8 = predict(in, 8);
        CHECK(m4 != m1);
        CHECK(m8 != m4);
        for (const float v : m8) REQUIRE((v >= 0.0f && v <= 1.0f));
        for (int t = 1; t < 8; ++t) {
            INFO("transform " << t);
            CHECK(predict(moved(in, n, kChannels, t), 8) == moved(m8, n, 1, t));
            if (t < 4) CHECK(predict(moved(in, n, kChannels, t), 4) == moved(m4, n, 1, t));  // flips and rot180: the 4-group
        }
        // Without augmentation the network alone is not equivariant.
        CHECK(predict(moved(in, n, kChannels, 1), 1) != moved(m1, n, 1, 1));
    }

    detect::CnnOptions p = o;
    p.tta = 8;
    // One map for 1 and 2 threads; every cell gets a probability.
    const auto one_two = [&](const std::vector<float>& g, int gw, int gh, const detect::CnnTiling& tiling) {
        std::vector<float> s1, s2;
        {
            tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
            s1 = detect::predict_cnn(w, g, gw, gh, kChannels, p, tiling);
        }
        {
            tbb::global_control two(tbb::global_control::max_allowed_parallelism, 2);
            s2 = detect::predict_cnn(w, g, gw, gh, kChannels, p, tiling);
        }
        CHECK(s1 == s2);
        REQUIRE(s1.size() == std::size_t(gw) * gh);
        for (const float v : s1) REQUIRE((v >= 0.0f && v <= 1.0f));
        return s1;
    };
    // Several tiles (600 x 300 cells: training's tiling 5 x 3 tiles,
    // detection's 3 x 2 of up to 256 x 256, the last column and row partial).
    const std::vector<float> big = blob_grid(600, 300, 13);
    const std::vector<float> a = one_two(big, 600, 300, detect::kCnnTrainingTiling), b = one_two(big, 600, 300, detect::kCnnDetectionTiling);
    // This network's reach (2 poolings: about 24 cells) is inside the
    // 32-cell margin, so both tilings see every cell's whole neighbourhood,
    // zeros past the grid alike: the same map, to float rounding (other
    // tile shapes may sum in another order). (The shipped 3-level network
    // reaches past the margin: its maps differ near seams; README.)
    double diff = 0.0;
    for (std::size_t k = 0; k < a.size(); ++k) diff = std::max(diff, std::abs(double(a[k]) - b[k]));
    CHECK(diff < 1e-5);

    // Detection's clipped edge tiles on odd shapes: a grid smaller than a
    // tile whose sides are not multiples of 2^levels (37 x 5), one just past
    // a tile (257 x 259: a 1-cell last column and a 3-cell last row), 1 x 1,
    // and 1-cell strips (one 600-cell row: 3 tiles of 1 x up to 256 kept
    // cells; one column).
    for (const auto& [gw, gh] : std::vector<std::pair<int, int>>{{37, 5}, {257, 259}, {1, 1}, {1, 600}}) {
        INFO(gw << " x " << gh);
        one_two(blob_grid(gw, gh, 19), gw, gh, detect::kCnnDetectionTiling);
    }
    {
        // A row's map transposed is its transposed column's map (TTA 8: the
        // same tiles moved). blob_grid of a 600 x 1 row and of a 1 x 600 column
        // hold different values; the column is the row's transpose
        // (planar c x 1 x 600 == c x 600 x 1).
        const std::vector<float> row = blob_grid(600, 1, 23);
        const std::vector<float> mr = one_two(row, 600, 1, detect::kCnnDetectionTiling), mc = one_two(row, 1, 600, detect::kCnnDetectionTiling);
        CHECK(mc == mr);
        std::size_t distinct = 0;
        for (std::size_t k = 1; k < mr.size(); ++k) distinct += mr[k] != mr[0];
        CHECK(distinct > 0);  // not a constant map
    }
    // A non-square tile (120 x 72 cells, one clipped tile of 184 x 136 with
    // its margins): transposed, its 8-transform map is exactly the transposed map.
    {
        const int gw = 120, gh = 72;
        const std::vector<float> g = blob_grid(gw, gh, 17);
        std::vector<float> gt(g.size());
        for (int c = 0; c < kChannels; ++c)
            for (int y = 0; y < gh; ++y)
                for (int x = 0; x < gw; ++x) gt[(std::size_t(c) * gw + x) * gh + y] = g[(std::size_t(c) * gh + y) * gw + x];
        const std::vector<float> mg = detect::predict_cnn(w, g, gw, gh, kChannels, p, detect::kCnnDetectionTiling),
                                 mt = detect::predict_cnn(w, gt, gh, gw, kChannels, p, detect::kCnnDetectionTiling);
        int same = 0;
        for (int y = 0; y < gh; ++y)
            for (int x = 0; x < gw; ++x) same += mt[std::size_t(x) * gh + y] == mg[std::size_t(y) * gw + x];
        CHECK(same == gw * gh);
    }
    p.tta = 2;
    CHECK_THROWS_WITH(p.validate(), Catch::Contains("must be 1, 4 or 8"));
    CHECK_THROWS_WITH(detect::predict_cnn(w, big, 600, 300, kChannels, o, detect::CnnTiling{100, true}), Catch::Contains("multiple of 16"));
}

TEST_CASE("CNN test-time augmentation in a model file: key only when on, old files keep their bytes, same footprints for 1 and 2 threads",
          "[detect][cnn][synth]") {
    test::ScratchDir dir("detect_cnn_tta");
    const std::string fine = default_model_path(detect::BandLayout{3, -1}, 0.3);
    const detect::DetectorModel m = detect::read_model_file(fine);
    REQUIRE(m.options.pixel.kind == detect::PixelStageKind::cnn);
    // A file without the key reads as tta 1 and writes back the same bytes.
    const std::string old_bytes = test::slurp(fine);
    if (old_bytes.find("\"tta\"") == std::string::npos) {
        CHECK(m.options.pixel.cnn.tta == 1);
        const std::vector<uint8_t> again = detect::serialize_model(m);
        CHECK(std::string(again.begin(), again.end()) == old_bytes);
    }
    detect::DetectorModel m4 = m;
    m4.options.pixel.cnn.tta = 4;
    const std::vector<uint8_t> b4 = detect::serialize_model(m4);
    CHECK(std::string(b4.begin(), b4.end()).find("\"tta\"") != std::string::npos);
    const detect::DetectorModel back = detect::parse_model(b4, "tta.cfdet");
    CHECK(back.options.pixel.cnn.tta == 4);
    CHECK(detect::serialize_model(back) == b4);
    // A header option out of range (a hand-made file: the checksum matches) is refused naming the file.
    detect::DetectorModel m3 = m;
    m3.options.pixel.cnn.tta = 3;
    CHECK_THROWS_WITH(detect::parse_model(detect::serialize_model(m3), "hand_made.cfdet"),
                      Catch::StartsWith("hand_made.cfdet: invalid option in the detector model header: pixel.cnn.tta: must be 1, 4 or 8"));
    detect::DetectorModel m1 = m;
    m1.options.pixel.cnn.tta = 1;
    const std::vector<uint8_t> b1 = detect::serialize_model(m1);
    CHECK(std::string(b1.begin(), b1.end()).find("\"tta\"") == std::string::npos);
    // Such a file (as every model before session 19) reads as tta 1 and
    // writes back the same bytes, whatever the shipped model holds.
    const detect::DetectorModel old_file = detect::parse_model(b1, "old.cfdet");
    CHECK(old_file.options.pixel.cnn.tta == 1);
    CHECK(detect::serialize_model(old_file) == b1);
    detect::write_model_file(dir / "tta4.cfdet", m4);
    detect::write_model_file(dir / "tta1.cfdet", m1);

    // Applied to a synthetic town with 1 and 2 threads: the same footprints;
    // the augmented map changes them a little, not wholesale.
    test::ScratchDir town_dir("detect_cnn_tta_town");
    const SynthResult town = test::make_town(town_dir, 160, 41, 0);
    FootprintsRunOptions fo;
    fo.ortho = town.ortho_path;
    fo.model = dir / "tta4.cfdet";
    const FootprintsReport r4 = test::run_footprints_1_and_2_threads(dir / "a1.geojson", dir / "a2.geojson", fo);
    fo.model = dir / "tta1.cfdet";
    const FootprintsReport r1 = test::run_footprints_1_and_2_threads(dir / "b1.geojson", dir / "b2.geojson", fo);
    CHECK(r4.buildings > 0);
    CHECK(r1.buildings > 0);
    // The header's tta is what the applied model uses: the maps differ, a little
    // (a mean over transforms of one network), and so do the footprint files.
    const DetectionImage di = read_detection_image(town.ortho_path);
    const detect::Detection d4 = detect::detect_buildings(m4, di.normalised, di.valid, di.gsd_m);
    const detect::Detection d1 = detect::detect_buildings(m1, di.normalised, di.valid, di.gsd_m);
    REQUIRE(d4.pixel_probability.size() == d1.pixel_probability.size());
    std::size_t changed = 0, agree = 0;
    for (std::size_t k = 0; k < d4.pixel_probability.size(); ++k) {
        changed += d4.pixel_probability[k] != d1.pixel_probability[k];
        agree += (d4.pixel_probability[k] >= 0.5f) == (d1.pixel_probability[k] >= 0.5f);
    }
    CHECK(changed > d4.pixel_probability.size() / 2);
    CHECK(agree > d4.pixel_probability.size() * 9 / 10);
    CHECK(test::slurp(dir / "a1.geojson") != test::slurp(dir / "b1.geojson"));
}
