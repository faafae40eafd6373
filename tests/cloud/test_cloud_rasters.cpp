#include <catch2/catch.hpp>
#include <cmath>

#include "cloud/las.hpp"
#include "core/grid_fill.hpp"
#include "pipeline/rasterize_run.hpp"
#include "raster/raster.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;

TEST_CASE("cloud rasterize on the ortho grid - DTM without holes - nDSM shows building heights", "[cloud][rasterize]") {
    ScratchDir dir("rasterize");
    const SynthResult s = make_town(dir, 150, 6, 8);
    RasterizeOptions o;
    o.grid_raster = s.ortho_path;
    const RasterizeReport r = rasterize_run(s.cloud_path, dir / "r", o);
    const RasterInfo ortho = read_raster_info(s.ortho_path);
    const RasterInfo dtm_info = read_raster_info(r.dtm_path);
    CHECK(dtm_info.width == ortho.width);
    CHECK(dtm_info.height == ortho.height);
    CHECK(dtm_info.extent.min_x == ortho.extent.min_x);
    CHECK(dtm_info.extent.max_y == ortho.extent.max_y);
    CHECK(dtm_info.crs.epsg == ortho.crs.epsg);
    const auto dtm = RasterReader(r.dtm_path).read_all<float>();
    for (float v : dtm.data) REQUIRE(v != -9999.0f);
    // Inside buildings (truth raster), the nDSM sits between 2 m and 40 m; on open ground near 0.
    const auto ndsm = RasterReader(r.ndsm_path).read_all<float>();
    const auto truth = RasterReader(s.truth_raster_path).read_all<uint32_t>();
    std::size_t roof = 0, roof_ok = 0, open = 0, open_ok = 0;
    for (std::size_t i = 0; i < ndsm.data.size(); ++i) {
        if (ndsm.data[i] == -9999.0f) continue;
        if (truth.data[i]) ++roof, roof_ok += ndsm.data[i] > 2.0f && ndsm.data[i] < 40.0f;
        else ++open, open_ok += std::abs(ndsm.data[i]) < 0.5f;
    }
    CHECK(double(roof_ok) / double(roof) > 0.95);
    CHECK(double(open_ok) / double(open) > 0.75);  // trees are the rest
    const auto density = RasterReader(r.density_path).read_all<float>();
    double sum = 0.0;
    for (float v : density.data) sum += v;
    CHECK(sum / double(density.data.size()) == Approx(8.0).epsilon(0.15));
}

TEST_CASE("cloud rasterize window by window (cloud above the memory budget) writes the same bytes as a whole-cloud run", "[cloud][rasterize][windows]") {
    ScratchDir dir("rasterize_windows");
    const SynthResult s = make_town(dir, 300, 9, 8);
    // On the ortho's grid and on a grid over the cloud; ground from class 2 and
    // from SMRF. The outlier limit is measured by both runs on the same sample.
    for (const bool grid : {true, false})
        for (const bool smrf : {false, true}) {
            if (!grid && smrf) continue;  // SMRF once is enough for the test time
            const std::string tag = std::string(grid ? "grid" : "gsd") + (smrf ? "_smrf" : "");
            INFO(tag);
            RasterizeOptions o;
            if (grid) o.grid_raster = s.ortho_path;
            o.gsd_m = 0.75;
            o.ground.trust_classification = !smrf;
            const RasterizeReport whole = rasterize_run(s.cloud_path, dir / (tag + "_whole"), o);
            CHECK(whole.tiles == 1);
            o.max_points_in_memory = 700000;  // the town has ~720 k points
            o.tile_m = 100.0;
            o.overlap_m = 100.0;  // longer than any gap-fill ray of this town (the DTM fill is local to its gaps)
            const RasterizeReport tiled = rasterize_run(s.cloud_path, dir / (tag + "_tiled"), o);
            CHECK(tiled.tiles >= 9);
            CHECK(tiled.width == whole.width);
            CHECK(tiled.ground_from_classification == !smrf);
            for (const std::string name : {"dsm.tif", "dtm.tif", "ndsm.tif", "density.tif"}) {
                INFO(name);
                const std::string a = test::slurp(dir / (tag + "_whole/" + name)), b = test::slurp(dir / (tag + "_tiled/" + name));
                CHECK(a.size() > 1000);
                const bool same = a == b;
                CHECK(same);
            }
        }
}

TEST_CASE("cloud rasterize - the DTM stays empty beyond the fill's reach of every point (an L-shaped survey's empty corner) - same bytes by windows", "[cloud][rasterize][windows]") {
    ScratchDir dir("rasterize_l_shape");
    const SynthResult s = make_town(dir, 300, 9, 8);
    LasHeader h;
    const PointCloud all = read_las(s.cloud_path, &h);
    double minx = all.x[0], miny = all.y[0];
    for (std::size_t i = 0; i < all.size(); ++i) minx = std::min(minx, all.x[i]), miny = std::min(miny, all.y[i]);
    // An L: the strips x < minx + 60 and y < miny + 60 (the box stays the town's).
    PointCloud l;
    for (std::size_t i = 0; i < all.size(); ++i)
        if (all.x[i] < minx + 60.0 || all.y[i] < miny + 60.0) l.append(all, i);
    {
        LasWriter w(dir / "l.las", h.scale, h.offset, h.crs.wkt);
        w.write(l);
        w.close();
    }
    RasterizeOptions o;
    o.gsd_m = 1.0;
    const RasterizeReport whole = rasterize_run(dir / "l.las", dir / "whole", o);
    const auto dtm = RasterReader(whole.dtm_path).read_all<float>();
    const RasterInfo info = read_raster_info(whole.dtm_path);
    std::size_t near_valid = 0, near = 0, far_empty = 0, far = 0, between_valid = 0, between = 0;
    for (int r = 0; r < dtm.height; ++r)
        for (int c = 0; c < dtm.width; ++c) {
            const double x = info.transform.origin_x + (c + 0.5) * info.transform.pixel_width;
            const double y = info.transform.origin_y + (r + 0.5) * info.transform.pixel_height;
            const float v = dtm.data[static_cast<std::size_t>(r) * dtm.width + c];
            const double d = std::min(x - (minx + 60.0), y - (miny + 60.0));  // distance past the L, along the nearer axis
            if (d < 0) ++near, near_valid += v != -9999.0f;                     // on the survey
            else if (d > kGapFillReach_m + 2.0) ++far, far_empty += v == -9999.0f;  // beyond the reach of any point
            else if (d < kGapFillReach_m - 2.0) ++between, between_valid += v != -9999.0f;  // filled from the survey's edge
        }
    REQUIRE(far > 10000);
    CHECK(far_empty == far);
    CHECK(near_valid == near);
    CHECK(between_valid == between);
    // Read by windows (a budget under the point count), the same bytes.
    o.max_points_in_memory = l.size() / 3;
    o.tile_m = 100.0;
    o.overlap_m = 100.0;
    const RasterizeReport tiled = rasterize_run(dir / "l.las", dir / "tiled", o);
    CHECK(tiled.tiles > 1);
    for (const std::string name : {"dsm.tif", "dtm.tif", "ndsm.tif", "density.tif"}) {
        INFO(name);
        CHECK(test::slurp(dir / ("whole/" + name)) == test::slurp(dir / ("tiled/" + name)));
    }
}
