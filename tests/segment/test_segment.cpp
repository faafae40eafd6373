#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include "segment/watershed_reference.hpp"
#include "core/error.hpp"
#include "pipeline/segment_raster.hpp"
#include "raster/raster.hpp"
#include "segment/region_merging.hpp"
#include "segment/watershed.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

namespace {
// Four flat-colour rectangles with exact truth labels 1..4.
void four_regions(Image<float>& img, Image<uint32_t>& truth) {
    img = Image<float>(60, 40, 3, 0.0f);
    truth = Image<uint32_t>(60, 40, 1, 0u);
    const float colours[4][3] = {{200, 40, 40}, {40, 200, 40}, {40, 40, 200}, {220, 220, 60}};
    for (int r = 0; r < 40; ++r)
        for (int c = 0; c < 60; ++c) {
            const int k = (c < 25 ? 0 : 1) + (r < 15 ? 0 : 2);
            truth.at(0, c, r) = static_cast<uint32_t>(k + 1);
            for (int b = 0; b < 3; ++b) img.at(b, c, r) = colours[k][b];
        }
}
// True when a and b induce the same partition of the pixels.
bool same_partition(const Image<uint32_t>& a, const Image<uint32_t>& b) {
    std::map<uint32_t, uint32_t> ab, ba;
    for (std::size_t i = 0; i < a.data.size(); ++i) {
        auto [x, inserted_x] = ab.emplace(a.data[i], b.data[i]);
        auto [y, inserted_y] = ba.emplace(b.data[i], a.data[i]);
        if (x->second != b.data[i] || y->second != a.data[i]) return false;
    }
    return true;
}
// The 150 m synthetic town (seed 3) with its bands normalised, and its
// finest seeds: every regional minimum of the watershed (h 0, no smoothing),
// thousands of regions.
Oversegmentation fine_town_seeds(const ScratchDir& dir, Image<float>& img) {
    make_town(dir, 150, 3, 0);
    img = RasterReader(dir / "ortho.tif").read_all<float>();
    normalize_bands(img, {});
    WatershedOptions fine;
    fine.h_minima = 0.0;
    fine.smoothing_sigma_px = 0.0;
    return watershed_oversegment(img, {}, fine);
}
}  // namespace

TEST_CASE("Merging recovers flat-colour regions exactly with every strategy", "[segment]") {
    Image<float> img;
    Image<uint32_t> truth;
    four_regions(img, truth);
    WatershedOptions wo;
    wo.smoothing_sigma_px = 0.0;
    wo.h_minima = 0.0;
    const Oversegmentation over = watershed_oversegment(img, {}, wo);
    REQUIRE(over.region_count >= 4);
    for (uint32_t v : over.labels.data) REQUIRE(v >= 1);  // every pixel labelled, no watershed lines
    for (auto s : {QueueStrategy::rag, QueueStrategy::nng, QueueStrategy::mutual}) {
        INFO(to_string(s));
        RegionMergingOptions mo;
        mo.scales = {20};
        mo.strategy = s;
        const auto res = merge_regions(img, over.labels, over.region_count, mo);
        CHECK(res.levels[0].regions_after == 4);
        CHECK(same_partition(relabel(over.labels, res.levels[0].label_of_input), truth));
    }
}

TEST_CASE("Merging preserves totals and adjacency symmetry - hierarchy consistent - labels contiguous - same labels for every strategy", "[segment]") {
    ScratchDir dir("seg_synth");
    make_town(dir, 150, 1, 0);
    Image<float> img = RasterReader(dir / "ortho.tif").read_all<float>();
    normalize_bands(img, {});
    const Oversegmentation over = watershed_oversegment(img, {}, WatershedOptions{});
    RegionMergingOptions mo;
    mo.scales = {10, 20, 40, 80};
    mo.verify_invariants = true;  // totals (area, band sums) kept, adjacency symmetric, after every scale
    std::vector<std::vector<uint32_t>> tables[3];
    int k = 0;
    for (auto s : {QueueStrategy::rag, QueueStrategy::nng, QueueStrategy::mutual}) {
        mo.strategy = s;
        const auto res = merge_regions(img, over.labels, over.region_count, mo);
        uint32_t previous = over.region_count;
        const Image<uint32_t>* prev_labels = &over.labels;
        Image<uint32_t> prev_store;
        for (const auto& l : res.levels) {
            CHECK(l.regions_before == previous);
            CHECK(l.regions_after <= l.regions_before);
            CHECK(l.regions_before - l.regions_after == l.merges);
            const Image<uint32_t> cur = relabel(over.labels, l.label_of_input);
            std::set<uint32_t> used(cur.data.begin(), cur.data.end());
            CHECK(used.size() == l.regions_after);
            CHECK(*used.begin() == 1);
            CHECK(*used.rbegin() == l.regions_after);
            bool consistent = true;
            for (std::size_t i = 0; i < cur.data.size(); ++i) consistent = consistent && l.parent[prev_labels->data[i]] == cur.data[i];
            CHECK(consistent);
            prev_store = cur;
            prev_labels = &prev_store;
            previous = l.regions_after;
            tables[k].push_back(l.label_of_input);
        }
        ++k;
    }
    CHECK(tables[0] == tables[1]);
    CHECK(tables[0] == tables[2]);
    CHECK(tables[0].back().size() == over.region_count + 1);
}

TEST_CASE("Merged labels ascend with each region's lowest input label - input labels without pixels map to 0 - at every level", "[segment][merging]") {
    ScratchDir dir("seg_label_order");
    make_town(dir, 150, 3, 0);
    Image<float> img = RasterReader(dir / "ortho.tif").read_all<float>();
    normalize_bands(img, {});
    WatershedOptions fine;  // fine seeds: many merges at every scale
    fine.h_minima = 0.0;
    fine.smoothing_sigma_px = 0.0;
    const Oversegmentation over = watershed_oversegment(img, {}, fine);
    REQUIRE(over.region_count > 500);
    // Input labels spread out and shuffled: label l becomes new_label[l], a
    // permutation of the even numbers 2..2N, so every odd label has no pixel.
    std::vector<uint32_t> new_label(over.region_count + 1, 0);
    for (uint32_t l = 1; l <= over.region_count; ++l) new_label[l] = 2 * l;
    std::mt19937 rng(5);
    std::shuffle(new_label.begin() + 1, new_label.end(), rng);
    Image<uint32_t> labels = over.labels;
    for (auto& v : labels.data) v = new_label[v];
    const uint32_t count = 2 * over.region_count + 1;
    RegionMergingOptions mo;
    mo.scales = {10, 20, 40, 80};
    for (auto strategy : {QueueStrategy::rag, QueueStrategy::nng, QueueStrategy::mutual}) {
        mo.strategy = strategy;
        const auto res = merge_regions(img, labels, count, mo);
        for (const auto& level : res.levels) {
            REQUIRE(level.label_of_input.size() == count + 1);
            std::vector<uint32_t> lowest(level.regions_after + 1, UINT32_MAX);  // region -> its lowest input label
            bool unused_zero = true;
            for (uint32_t l = 1; l <= count; ++l) {
                const uint32_t k = level.label_of_input[l];
                if (l % 2 == 1) unused_zero = unused_zero && k == 0;
                else if (k >= 1 && k <= level.regions_after) lowest[k] = std::min(lowest[k], l);
            }
            CHECK(unused_zero);
            CHECK(level.parent[0] == 0);
            bool ascending = lowest[1] != UINT32_MAX;
            for (uint32_t k = 2; k <= level.regions_after; ++k) ascending = ascending && lowest[k] != UINT32_MAX && lowest[k - 1] < lowest[k];
            CHECK(ascending);
        }
    }
}

TEST_CASE("Merging down to a region count through one huge scale: every strategy the same labels, and fewer regions coarsen more", "[segment][merging]") {
    // One scale of 1e9 lets every pair merge, so costs grow far past the
    // initial ones: the merge queue's buckets overflow and are spread again
    // many times. rag queues every pair and mutual only mutual nearest
    // pairs, so equal labels need the exact same pop order from both.
    ScratchDir dir("seg_min_regions");
    Image<float> img;
    const Oversegmentation over = fine_town_seeds(dir, img);
    REQUIRE(over.region_count > 2000);
    RegionMergingOptions mo;
    mo.scales = {1e9};
    std::map<uint32_t, std::vector<uint32_t>> by_count;
    for (uint32_t target : {1000u, 100u, 10u}) {
        mo.min_regions = target;
        std::vector<uint32_t> first;
        for (auto s : {QueueStrategy::rag, QueueStrategy::nng, QueueStrategy::mutual}) {
            mo.strategy = s;
            const auto res = merge_regions(img, over.labels, over.region_count, mo);
            CHECK(res.levels[0].regions_after == target);
            if (first.empty()) first = res.levels[0].label_of_input;
            else CHECK(res.levels[0].label_of_input == first);
        }
        by_count[target] = first;
    }
    // Stopping later is the same merge sequence cut later: every region of
    // 1000 lies within one region of 100, and every region of 100 within one of 10.
    for (auto [fine, coarse] : {std::pair{1000u, 100u}, std::pair{100u, 10u}}) {
        std::map<uint32_t, uint32_t> parent;
        bool nested = true;
        for (uint32_t l = 1; l <= over.region_count; ++l) {
            const auto [it, fresh] = parent.emplace(by_count[fine][l], by_count[coarse][l]);
            nested = nested && it->second == by_count[coarse][l];
        }
        CHECK(nested);
        CHECK(parent.size() == fine);
    }
}

TEST_CASE("Real panchromatic UInt16 tile segments - region count falls with scale", "[segment][real]") {
    ScratchDir dir("seg_atl");
    SegmentOptions o;
    o.merging.scales = {10, 20, 40};
    const SegmentReport r = segment_raster(shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif"), dir / "out", o);
    CHECK(r.oversegmentation_regions > 500);
    REQUIRE(r.levels.size() == 3);
    CHECK(r.levels[0].regions_after < r.oversegmentation_regions);
    CHECK(r.levels[1].regions_after < r.levels[0].regions_after);
    CHECK(r.levels[2].regions_after < r.levels[1].regions_after);
    const RasterInfo li = read_raster_info(r.levels[2].labels_path);
    CHECK(li.crs.epsg == 32616);
    CHECK(li.width == 450);
    CHECK(li.bands[0].type == SampleType::uint32);
    // Nodata (0) pixels of the input stay 0 in the labels and never merge.
    RasterReader in(shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif"));
    const auto src = in.read_all<uint16_t>();
    const auto lab = RasterReader(r.levels[2].labels_path).read_all<uint32_t>();
    for (std::size_t i = 0; i < src.data.size(); ++i) REQUIRE((src.data[i] == 0) == (lab.data[i] == 0));
}

TEST_CASE("Autzen ortho in feet is resampled to the 0.5 m working grid and labels come back on the input grid", "[segment][real]") {
    ScratchDir dir("seg_autzen");
    SegmentOptions o;
    o.merging.scales = {20};
    // A 600 x 600 px crop keeps the test fast.
    RasterReader reader(shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif"));
    const auto crop = reader.read<uint8_t>({1000, 1000, 600, 600});
    write_geotiff(dir / "crop.tif", crop, reader.info().transform.window(1000, 1000), reader.info().crs.wkt);
    const SegmentReport r = segment_raster(dir / "crop.tif", dir / "out", o);
    CHECK(r.working_width == Approx(600 * 0.3048 / 0.5).margin(1));
    const RasterInfo li = read_raster_info(r.levels[0].labels_path);
    CHECK(li.width == 600);
    CHECK(li.crs.horizontal_epsg == 2994);
}

TEST_CASE("Bad segmentation input is refused before anything is written", "[segment][errors]") {
    ScratchDir dir("seg_bad");
    const std::string tif = shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif");
    SegmentOptions o;
    o.merging.scales = {20, 10};
    CHECK_THROWS_WITH(segment_raster(tif, dir / "o", o), Catch::Contains("--scales") && Catch::Contains("increasing"));
    o.merging.scales = {0, 10};
    CHECK_THROWS_WITH(segment_raster(tif, dir / "o", o), Catch::Contains("--scales") && Catch::Contains("> 0"));
    o.merging.scales = {10};
    o.merging.band_weights = {1, 1, 1};
    CHECK_THROWS_WITH(segment_raster(tif, dir / "o", o), Catch::Contains("--band-weights") && Catch::Contains("1 band"));
    o.merging.band_weights.clear();
    Image<uint8_t> flat(50, 50, 3, 128);
    const GeoTransform gt{500000, 0.5, 4400000, -0.5};
    const std::string wkt = read_raster_info(tif).crs.wkt;
    write_geotiff(dir / "flat.tif", flat, gt, wkt);
    CHECK_THROWS_WITH(segment_raster(dir / "flat.tif", dir / "o", o), Catch::Contains("flat.tif") && Catch::Contains("single value"));
    Image<uint16_t> empty(50, 50, 1, 0);
    GeoTiffWriteOptions nd;
    nd.nodata = 0;
    write_geotiff(dir / "nodata.tif", empty, gt, wkt, nd);
    CHECK_THROWS_WITH(segment_raster(dir / "nodata.tif", dir / "o", o), Catch::Contains("nodata.tif") && Catch::Contains("only nodata"));
    CHECK_FALSE(std::filesystem::exists(dir / "o"));
    CHECK_THROWS_WITH(segment_options_from_json(nlohmann::json{{"scalez", {1}}}, "cfg.json"), Catch::Contains("cfg.json") && Catch::Contains("unknown key 'scalez'"));
}

TEST_CASE("Segmentation gives the same labels with 1 thread and with all threads", "[segment][determinism]") {
    ScratchDir dir("seg_threads");
    make_town(dir, 200, 11, 0);
    auto run = [&] {
        Image<float> img = RasterReader(dir / "ortho.tif").read_all<float>();
        normalize_bands(img, {});
        const Oversegmentation over = watershed_oversegment(img, {}, WatershedOptions{});
        RegionMergingOptions mo;
        mo.scales = {10, 30, 60};
        const auto res = merge_regions(img, over.labels, over.region_count, mo);
        return std::make_pair(over.labels.data, res.levels.back().label_of_input);
    };
    const auto all_threads = run();
    // Arenas of 1, 3 and 8 threads: the graph build cuts its work into as
    // many chunks as its arena has threads (up to 8), whatever the cores.
    for (int threads : {1, 3, 8}) {
        INFO(threads << " threads");
        tbb::task_arena arena(threads);
        const auto in_arena = arena.execute(run);
        CHECK(all_threads.first == in_arena.first);
        CHECK(all_threads.second == in_arena.second);
    }
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    const auto one_thread = run();
    CHECK(all_threads.first == one_thread.first);
    CHECK(all_threads.second == one_thread.second);
}

TEST_CASE("Watershed without smoothing (levels straight from the bands, sorted by row chunks - h 0 floods on two threads): same labels for 1 thread and all threads", "[segment][determinism]") {
    ScratchDir dir("seg_threads_unsmoothed");
    make_town(dir, 300, 12, 0);  // 600 x 600 px: h 0 floods on two threads when two are allowed
    Image<float> img = RasterReader(dir / "ortho.tif").read_all<float>();
    normalize_bands(img, {});
    std::vector<uint8_t> valid(img.pixel_count(), 1);
    for (std::size_t i = 0; i < valid.size(); i += 7) valid[i] = 0;  // nodata scattered over every row chunk
    for (double h : {0.0, 2.0}) {
        WatershedOptions wo;
        wo.smoothing_sigma_px = 0.0;
        wo.h_minima = h;
        const Oversegmentation all_threads = watershed_oversegment(img, valid, wo);
        Oversegmentation one_thread;
        {
            tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
            one_thread = watershed_oversegment(img, valid, wo);
        }
        CHECK(all_threads.region_count == one_thread.region_count);
        CHECK(all_threads.labels.data == one_thread.labels.data);
        // Every valid pixel labelled, nodata left 0, labels 1..N.
        std::size_t bad = 0;
        for (std::size_t i = 0; i < valid.size(); ++i) {
            const uint32_t l = all_threads.labels.data[i];
            bad += valid[i] ? (l == 0 || l > all_threads.region_count) : l != 0;
        }
        CHECK(bad == 0);
        if (h == 0.0) CHECK(all_threads.region_count > 100);
    }
}

TEST_CASE("Merging with regions of thousands of neighbours: same labels for every strategy, invariants kept", "[segment][merging]") {
    // A flat background cut into 3 x 3 blocks with 2 x 2 dots of varied
    // colour every 6 pixels: the background merges into one region that
    // borders every dot (1600), then absorbs them as the scale grows. Many
    // costs tie exactly (identical blocks), so the tie order is exercised too.
    const int size = 240;
    Image<float> img(size, size, 3, 100.0f);
    Image<uint32_t> labels(size, size, 1, 0u), truth(size, size, 1, 0u);
    uint32_t next = 0;
    std::map<std::pair<int, int>, uint32_t> block;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            const bool dot = x % 6 >= 2 && x % 6 < 4 && y % 6 >= 2 && y % 6 < 4;
            const auto cell = dot ? std::make_pair(-1 - x / 6, y / 6) : std::make_pair(x / 3, y / 3);
            auto [it, inserted] = block.emplace(cell, 0);
            if (inserted) it->second = ++next;
            labels.at(0, x, y) = it->second;
            truth.at(0, x, y) = dot ? it->second : 0;
            if (dot) {
                const uint32_t h = (uint32_t(x / 6) * 73856093u) ^ (uint32_t(y / 6) * 19349663u);
                for (int b = 0; b < 3; ++b) img.at(b, x, y) = 100.0f + float(int((h >> (4 * b)) % 41) - 20);
            }
        }
    RegionMergingOptions mo;
    mo.scales = {1, 20, 30};
    mo.color_weight = 1.0;  // flat blocks merge at cost 0, ties broken by labels
    mo.verify_invariants = true;
    std::vector<std::vector<uint32_t>> tables[3];
    uint32_t max_degree = 0;
    int k = 0;
    for (auto s : {QueueStrategy::rag, QueueStrategy::nng, QueueStrategy::mutual}) {
        INFO(to_string(s));
        mo.strategy = s;
        const auto res = merge_regions(img, labels, next, mo);
        for (const auto& l : res.levels) {
            CHECK(l.regions_before - l.regions_after == l.merges);
            tables[k].push_back(l.label_of_input);
            max_degree = std::max(max_degree, l.max_degree);
        }
        // Finest scale: exactly the background and the 1600 dots; then the
        // background absorbs every dot.
        CHECK(res.levels[0].regions_after == 1601);
        CHECK(same_partition(relabel(labels, res.levels[0].label_of_input), truth));
        CHECK(res.levels[2].regions_after == 1);
        ++k;
    }
    CHECK(max_degree >= 1500);  // the background borders (nearly) every dot
    CHECK(tables[0] == tables[1]);
    CHECK(tables[0] == tables[2]);
}

TEST_CASE("Region statistics do not depend on the label order or the thread count", "[segment][merging][determinism]") {
    // The graph adds each row band's pixels straight into the regions it owns
    // and the crossing regions' through a per-band table: labels in random
    // order make nearly every region cross, which must give the same merges.
    auto permuted = [](const Image<uint32_t>& labels, uint32_t count) {
        std::vector<uint32_t> to(count + 1, 0);
        for (uint32_t k = 1; k <= count; ++k) to[k] = k;
        uint64_t state = 88172645463325252ull;
        for (uint32_t k = count; k > 1; --k) {  // Fisher-Yates with xorshift
            state ^= state << 13, state ^= state >> 7, state ^= state << 17;
            std::swap(to[k], to[1 + state % k]);
        }
        return relabel(labels, to);
    };
    SECTION("flat colours are recovered from shuffled seeds") {
        Image<float> img;
        Image<uint32_t> truth;
        four_regions(img, truth);
        WatershedOptions wo;
        wo.smoothing_sigma_px = 0.0;
        wo.h_minima = 0.0;
        const Oversegmentation over = watershed_oversegment(img, {}, wo);
        const Image<uint32_t> shuffled = permuted(over.labels, over.region_count);
        RegionMergingOptions mo;
        mo.scales = {20};
        mo.verify_invariants = true;
        const auto res = merge_regions(img, shuffled, over.region_count, mo);
        CHECK(res.levels[0].regions_after == 4);
        CHECK(same_partition(relabel(shuffled, res.levels[0].label_of_input), truth));
    }
    SECTION("shuffled seeds of a town: 1 thread and all threads agree") {
        ScratchDir dir("seg_shuffled");
        Image<float> img;
        const Oversegmentation over = fine_town_seeds(dir, img);
        const Image<uint32_t> shuffled = permuted(over.labels, over.region_count);
        RegionMergingOptions mo;
        mo.scales = {10, 30, 60};
        mo.verify_invariants = true;
        const auto all_threads = merge_regions(img, shuffled, over.region_count, mo);
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        const auto one_thread = merge_regions(img, shuffled, over.region_count, mo);
        for (std::size_t l = 0; l < mo.scales.size(); ++l) CHECK(all_threads.levels[l].label_of_input == one_thread.levels[l].label_of_input);
        REQUIRE(over.region_count > 1000);
        CHECK(all_threads.levels.back().regions_after < over.region_count / 10);
    }
    SECTION("seeds in raster order but for the last two labels, and a label out of range") {
        // The node numbering reads first pixels in one pass while labels come
        // in raster order of first appearance (the watershed's); here that
        // holds until the last two labels, and the numbering starts again
        // with the general search: same labels with 1 and all threads.
        ScratchDir dir("seg_nearly_ordered");
        Image<float> img;
        const Oversegmentation over = fine_town_seeds(dir, img);
        REQUIRE(over.region_count > 1000);
        std::vector<uint32_t> to(over.region_count + 1);
        for (uint32_t k = 0; k <= over.region_count; ++k) to[k] = k;
        std::swap(to[over.region_count], to[over.region_count - 1]);
        const Image<uint32_t> nearly = relabel(over.labels, to);
        RegionMergingOptions mo;
        mo.scales = {10, 30};
        mo.verify_invariants = true;
        const auto all_threads = merge_regions(img, nearly, over.region_count, mo);
        const auto ordered = merge_regions(img, over.labels, over.region_count, mo);
        {
            tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
            const auto one_thread = merge_regions(img, nearly, over.region_count, mo);
            const auto ordered_one = merge_regions(img, over.labels, over.region_count, mo);
            for (std::size_t l = 0; l < mo.scales.size(); ++l) {
                CHECK(all_threads.levels[l].label_of_input == one_thread.levels[l].label_of_input);
                CHECK(ordered.levels[l].label_of_input == ordered_one.levels[l].label_of_input);
            }
        }
        CHECK(all_threads.levels.back().regions_after < over.region_count / 10);
        // The next new label beyond the region count, in raster order: refused.
        Image<uint32_t> beyond = over.labels;
        beyond.band_data(0)[beyond.pixel_count() - 1] = over.region_count + 1;
        CHECK_THROWS_WITH(merge_regions(img, beyond, over.region_count, mo), Catch::Contains("exceeds the region count"));
    }
}

TEST_CASE("Region statistics: a block row's sums by runs equal the sums pixel by pixel (any value range, any band count)", "[segment][merging][determinism]") {
    // The graph sums 1, 3 or 4 bands of values below 2^24 fixed-point units
    // through prefix sums of each block row; other band counts and value
    // ranges pixel by pixel. Both must give the same statistics, so the same
    // merges (colour only: costs then scale exactly with the values).
    ScratchDir dir("seg_run_sums");
    Image<float> img;
    const Oversegmentation over = fine_town_seeds(dir, img);
    REQUIRE(over.region_count > 1000);
    RegionMergingOptions mo;
    mo.scales = {1e9};
    mo.min_regions = 300;
    mo.color_weight = 1.0;
    mo.verify_invariants = true;
    const auto reference = merge_regions(img, over.labels, over.region_count, mo);
    REQUIRE(reference.levels[0].regions_after == 300);
    SECTION("values scaled by 2^20: the fixed point falls below 1, the sums are taken pixel by pixel") {
        Image<float> big = img;
        for (float& v : big.data) v = std::ldexp(v, 20);
        const auto scaled = merge_regions(big, over.labels, over.region_count, mo);
        CHECK(scaled.levels[0].label_of_input == reference.levels[0].label_of_input);
    }
    SECTION("two bands (pixel by pixel) equal three with a zero band of weight 0 (by runs)") {
        Image<float> two(img.width, img.height, 2);
        std::copy(img.data.begin(), img.data.begin() + 2 * static_cast<std::ptrdiff_t>(img.pixel_count()), two.data.begin());
        Image<float> three = img;
        std::fill(three.data.begin() + 2 * static_cast<std::ptrdiff_t>(img.pixel_count()), three.data.end(), 0.0f);
        RegionMergingOptions with_zero = mo;
        with_zero.band_weights = {1, 1, 0};
        const auto by_pixel = merge_regions(two, over.labels, over.region_count, mo);
        const auto by_run = merge_regions(three, over.labels, over.region_count, with_zero);
        CHECK(by_pixel.levels[0].label_of_input == by_run.levels[0].label_of_input);
        CHECK(by_pixel.levels[0].regions_after == 300);
    }
}

TEST_CASE("Watershed with h 0 (seeds found by a parallel walk, no sort) equals the sequential flooding in level order", "[segment][determinism]") {
    RasterReader reader(shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif"));
    Image<float> real = reader.read<float>({1200, 1400, 400, 300}, {1, 2, 3});
    normalize_bands(real, {});
    Image<float> flat(37, 29, 3, 100.0f);  // one plateau: a single seed, walks as long as the image
    Image<float> ramp(300, 200, 1, 0.0f);  // falls to the right and down: walks across rows and blocks
    for (int y = 0; y < 200; ++y)
        for (int x = 0; x < 300; ++x) ramp.at(0, x, y) = static_cast<float>(255 - (x + y) % 256);
    Image<float> line(1, 50, 3, 0.0f), row(61, 1, 3, 0.0f);
    for (int i = 0; i < 50; ++i) line.at(0, 0, i) = static_cast<float>((i * 37) % 101);
    for (int i = 0; i < 61; ++i) row.at(1, i, 0) = static_cast<float>((i * 53) % 97);
    for (const Image<float>* img : {&real, &flat, &ramp, &line, &row}) {
        std::vector<uint8_t> holes(img->pixel_count(), 1);
        for (std::size_t i = 0; i < holes.size(); i += 5) holes[i] = 0;
        for (bool with_holes : {true, false}) {
            const std::vector<uint8_t> v = with_holes ? holes : std::vector<uint8_t>{};
            for (double smoothing : {0.0, 1.0}) {
                WatershedOptions wo;
                wo.h_minima = 0.0;
                wo.smoothing_sigma_px = smoothing;
                const Oversegmentation expected = test::reference_dynamics(*img, v, wo);  // h 0: no basin is absorbed
                const Oversegmentation all_threads = watershed_oversegment(*img, v, wo);
                Oversegmentation one_thread;
                {
                    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
                    one_thread = watershed_oversegment(*img, v, wo);
                }
                INFO("image " << img->width << " x " << img->height << (with_holes ? " with nodata" : "") << ", smoothing " << smoothing);
                CHECK(all_threads.region_count == expected.region_count);
                CHECK(all_threads.labels.data == expected.labels.data);
                CHECK(one_thread.labels.data == expected.labels.data);
            }
        }
    }
}

TEST_CASE("Band normalisation stretches between the exact 0.5 and 99.5 percentiles of its sample", "[segment]") {
    // Expected: test::reference_normalisation (nth_element over the same regular sample).
    Image<float> img(1500, 1400, 3, 0.0f);  // 2.1 M pixels: a sample of every other pixel
    uint32_t state = 12345;
    for (std::size_t i = 0; i < img.data.size(); ++i) {
        state = state * 1664525u + 1013904223u;
        const int b = static_cast<int>(i / img.pixel_count());
        // band 0: wide spread with negatives, band 1: few repeated integers, band 2: narrow float range
        img.data[i] = b == 0 ? static_cast<float>(static_cast<int32_t>(state) / 65536) * 0.37f
                    : b == 1 ? static_cast<float>(state % 7)
                             : 1000.0f + static_cast<float>(state % 100000) * 1e-4f;
    }
    std::vector<uint8_t> valid(img.pixel_count(), 1);
    for (std::size_t i = 0; i < valid.size(); i += 3) valid[i] = 0;
    for (const auto& v : {std::vector<uint8_t>{}, valid}) {
        Image<float> got = img;
        normalize_bands(got, v);
        const Image<float> want = test::reference_normalisation(img, v);
        CHECK(got.data == want.data);
    }
}
