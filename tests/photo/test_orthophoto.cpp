// The orthophoto of `photo --run`: the photos' colours on the cloud's surface,
// checked against the synthetic town's exact nadir ortho (same albedo and
// shading as its perspective views), with and without the occlusion test,
// for 1 and 2 threads, and bad input refused.
#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <filesystem>
#include <tbb/global_control.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "cloud/las.hpp"
#include "core/error.hpp"
#include "photo/camera.hpp"
#include "photo/orthophoto.hpp"
#include "raster/raster.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;

namespace {
struct Agreement {
    double mean_abs = 0;     ///< mean |difference| over bands and coloured cells, grey levels
    double coloured = 0;     ///< share of the grid's cells coloured
    double near_walls = 0;   ///< mean |difference| on coloured cells within 3 m of a building's edge (ground side)
};
// `ortho` against the exact nadir ortho `ref` (same grid).
Agreement agreement(const Image<uint8_t>& ortho, const Image<uint8_t>& ref, const Image<uint32_t>& buildings, int cells_3m) {
    Agreement a;
    double sum = 0, wall_sum = 0;
    long n = 0, wall_n = 0;
    const int w = ortho.width, h = ortho.height;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            if (!ortho.at(0, x, y) && !ortho.at(1, x, y) && !ortho.at(2, x, y)) continue;
            double d = 0;
            for (int b = 0; b < 3; ++b) d += std::abs(double(ortho.at(b, x, y)) - double(ref.at(b, x, y)));
            sum += d / 3, ++n;
            bool near = false;
            if (!buildings.at(0, x, y))
                for (int dy = -cells_3m; dy <= cells_3m && !near; ++dy)
                    for (int dx = -cells_3m; dx <= cells_3m && !near; ++dx) {
                        const int xx = x + dx, yy = y + dy;
                        near = xx >= 0 && yy >= 0 && xx < w && yy < h && buildings.at(0, xx, yy);
                    }
            if (near) wall_sum += d / 3, ++wall_n;
        }
    a.mean_abs = n ? sum / static_cast<double>(n) : 1e9;
    a.coloured = static_cast<double>(n) / (static_cast<double>(w) * h);
    a.near_walls = wall_n ? wall_sum / static_cast<double>(wall_n) : 0;
    return a;
}
}  // namespace

TEST_CASE("The orthophoto takes the photos' colours where the surface does not hide them", "[photo][orthophoto]") {
    ScratchDir dir("orthophoto");
    const SynthResult s = test::make_views(dir, 6);
    const photo::CameraSet set = photo::read_cameras_json((dir / "views/cameras_truth.json"));
    std::vector<cv::Mat> images;
    for (const auto& c : set.cameras) images.push_back(cv::imread(dir / ("views/" + c.image), cv::IMREAD_COLOR));
    const PointCloud surface = read_las(s.surface_path);
    RasterReader ref_reader(s.ortho_path);
    const Image<uint8_t> ref = ref_reader.read_all<uint8_t>({1, 2, 3});
    const Image<uint32_t> buildings = RasterReader(s.truth_raster_path).read_all<uint32_t>();
    const GridSpec grid{ref_reader.info().transform, ref_reader.info().width, ref_reader.info().height};
    REQUIRE(buildings.width == grid.width);
    REQUIRE(buildings.height == grid.height);
    const int cells_3m = static_cast<int>(std::lround(3.0 / std::abs(grid.transform.pixel_width)));

    photo::OrthophotoOptions o;
    photo::OrthophotoStats st;
    const Image<uint8_t> ortho = photo::orthophoto_from_photos(surface, grid, images, set, o, "views", &st);
    const Agreement with = agreement(ortho, ref, buildings, cells_3m);
    photo::OrthophotoOptions blind = o;
    blind.occlusion_tolerance_m = 100.0;  // nothing ever hides a point
    const Agreement without = agreement(photo::orthophoto_from_photos(surface, grid, images, set, blind, "views"), ref, buildings, cells_3m);
    INFO("coloured " << with.coloured << ", mean |diff| " << with.mean_abs << " (blind " << without.mean_abs << "), near walls "
                     << with.near_walls << " (blind " << without.near_walls << "); cells measured " << st.cells_measured << ", filled "
                     << st.cells_filled << ", coloured " << st.cells_coloured << ", occluded " << st.cells_occluded);
    CHECK(st.cells_coloured > 0);
    CHECK(with.coloured > 0.15);       // the six views cover part of the town (0.21)
    CHECK(with.mean_abs < 12.0);       // the photos' colours on the right cells (8.1 grey levels)
    CHECK(with.near_walls < without.near_walls);  // beside walls, the leaning roofs are not taken for ground
    CHECK(st.cells_occluded > 0);

    // Same bytes for 1 and 2 threads.
    Image<uint8_t> one;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        one = photo::orthophoto_from_photos(surface, grid, images, set, o, "views");
    }
    CHECK(one.data == ortho.data);

    // Photos read on demand: each at most once, in camera order, one at a
    // time (the caller's loader), and the same bytes as with all in memory.
    std::vector<std::size_t> loaded;
    const Image<uint8_t> streamed = photo::orthophoto_from_photos(
        surface, grid, [&](std::size_t i) { loaded.push_back(i); return images[i].clone(); }, set, o, "views");
    CHECK(streamed.data == ortho.data);
    REQUIRE(!loaded.empty());
    CHECK(std::is_sorted(loaded.begin(), loaded.end()));
    CHECK(std::adjacent_find(loaded.begin(), loaded.end()) == loaded.end());

    // An image that is not its camera's size is refused, naming it.
    std::vector<cv::Mat> bad = images;
    cv::resize(bad[1], bad[1], cv::Size(100, 80));
    CHECK_THROWS_WITH(photo::orthophoto_from_photos(surface, grid, bad, set, o, "views"), Catch::Contains(set.cameras[1].image));
    // No point on the grid.
    PointCloud far = surface;
    for (auto& x : far.x) x += 1e5;
    CHECK_THROWS_WITH(photo::orthophoto_from_photos(far, grid, images, set, o, "views"), Catch::Contains("no point"));
    o.max_off_nadir_deg = 95;
    CHECK_THROWS_WITH(o.validate(), Catch::StartsWith("orthophoto max_off_nadir_deg"));
}
