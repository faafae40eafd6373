#include <catch2/catch.hpp>

#include <bit>

#include <tbb/global_control.h>

#include "cloud/cloud_filters.hpp"
#include "cloud/kd_tree.hpp"
#include "cloud/las.hpp"
#include "core/grid_fill.hpp"
#include "core/morphology.hpp"
#include "core/random.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

namespace {
// The outlier filter as it was with one k-d tree over the whole cloud: the
// oracle for the grid search (same neighbours, same distances, same flags).
std::vector<uint8_t> kd_tree_outlier_keep(const PointCloud& c, const OutlierFilterOptions& o) {
    const std::size_t n = c.size();
    std::vector<uint8_t> keep(n, 1);
    for (std::size_t i = 0; i < n; ++i)
        if (c.classification[i] == las_class::low_noise || c.classification[i] == las_class::high_noise) keep[i] = 0;
    double ox = INFINITY, oy = INFINITY, oz = INFINITY;
    for (std::size_t i = 0; i < n; ++i) ox = std::min(ox, c.x[i]), oy = std::min(oy, c.y[i]), oz = std::min(oz, c.z[i]);
    const LocalPoints local = local_points(c, ox, oy, oz);
    PointTree tree(3, local, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    tree.buildIndex();
    const std::size_t k = static_cast<std::size_t>(std::max(o.k_neighbours, o.isolated_min_neighbours)) + 1;
    const auto m = static_cast<std::size_t>(o.isolated_min_neighbours);
    std::vector<double> mean(n, 0.0);
    std::vector<uint8_t> isolated(n, 0);
    std::vector<uint32_t> idx(k);
    std::vector<float> d2(k);
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t found = tree.knnSearch(&local.xyz[3 * i], k, idx.data(), d2.data());
        const std::size_t used = std::min(found, static_cast<std::size_t>(o.k_neighbours) + 1);
        double s = 0.0;
        for (std::size_t j = 1; j < used; ++j) {
            const std::size_t a = idx[j];
            const double dx = c.x[a] - c.x[i], dy = c.y[a] - c.y[i], dz = c.z[a] - c.z[i];
            s += std::sqrt(dx * dx + dy * dy + dz * dz);
        }
        mean[i] = used > 1 ? s / double(used - 1) : 0.0;
        isolated[i] = found <= m || d2[m] > o.isolated_radius * o.isolated_radius;
    }
    // Gross outliers (over kGrossOutlierFactor x the median) stay out of mu and sigma.
    std::vector<float> sorted(mean.begin(), mean.end());
    std::sort(sorted.begin(), sorted.end());
    const double gross = sorted[n / 2] > 0 ? kGrossOutlierFactor * double(sorted[n / 2]) : INFINITY;
    double sum = 0.0, sum2 = 0.0, used = 0.0;
    for (double d : mean)
        if (d <= gross) sum += d, sum2 += d * d, used += 1;
    const double mu = sum / used, sigma = std::sqrt(std::max(0.0, sum2 / used - mu * mu));
    const double limit = mu + o.std_multiplier * sigma;
    for (std::size_t i = 0; i < n; ++i)
        if (keep[i] && (mean[i] > limit || isolated[i])) keep[i] = 0;
    return keep;
}
}  // namespace

TEST_CASE("Statistical outlier removal drops far points and keeps a clean surface", "[cloud][filters]") {
    PointCloud c;
    Rng rng(5);
    for (int i = 0; i < 4000; ++i) {
        c.x.push_back(rng.uniform(0, 20)), c.y.push_back(rng.uniform(0, 20)), c.z.push_back(10 + 0.02 * rng.normal());
        c.classification.push_back(1), c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
    }
    const double outliers[3][3] = {{5, 5, 40}, {12, 3, -20}, {18, 18, 25}};
    for (const auto& p : outliers) {
        c.x.push_back(p[0]), c.y.push_back(p[1]), c.z.push_back(p[2]);
        c.classification.push_back(1), c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
    }
    const OutlierFilterResult r = filter_outliers(c, OutlierFilterOptions{});
    for (std::size_t i = 4000; i < 4003; ++i) CHECK_FALSE(r.keep[i]);
    CHECK(r.removed_statistical + r.removed_isolated < 60);  // the surface itself survives (<1.5 %)
}

TEST_CASE("outlier_limit: the median of the float-rounded distances (radix selection) and mean + m sigma without the gross outliers, for any thread count", "[cloud][filters]") {
    // The oracle: a float copy sorted, as the filter did with nth_element.
    const auto oracle = [](const std::vector<double>& v, double m) {
        std::vector<float> sorted(v.begin(), v.end());
        std::sort(sorted.begin(), sorted.end());
        const double median = sorted[v.size() / 2];
        const double gross = median > 0 ? kGrossOutlierFactor * median : INFINITY;
        double sum = 0.0, sum2 = 0.0, used = 0.0;
        for (double d : v)
            if (d <= gross) sum += d, sum2 += d * d, used += 1;
        const double mu = sum / used;
        return mu + m * std::sqrt(std::max(0.0, sum2 / used - mu * mu));
    };
    Rng rng(17);
    for (const std::size_t n : {std::size_t(1), std::size_t(2), std::size_t(3), std::size_t(1000), std::size_t(1001), std::size_t(300000)}) {
        INFO("n " << n);
        // Distances over six orders of magnitude, many equal after rounding
        // to float, a few gross outliers; then values of both signs and zeros
        // (the selection is defined for any non-NaN value).
        std::vector<double> d(n), signed_d(n);
        for (std::size_t i = 0; i < n; ++i) {
            d[i] = std::pow(10.0, rng.uniform(-3.0, 3.0));
            if (i % 7 == 0) d[i] = 0.25 + 1e-12 * double(i % 5);  // equal as floats
            if (i % 997 == 5) d[i] = 1e6;
            signed_d[i] = i % 3 == 0 ? -d[i] : i % 11 == 0 ? 0.0 : i % 13 == 0 ? -0.0 : d[i];
        }
        for (const std::vector<double>* v : {&d, &signed_d}) {
            const double want = oracle(*v, 3.0);
            CHECK(outlier_limit(*v, 3.0) == want);
            tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
            CHECK(outlier_limit(*v, 3.0) == want);
        }
    }
    CHECK(outlier_limit(std::vector<double>{}, 3.0) == 0.0);
    // The median itself against the sorted float copy: one rank or one ulp
    // off would show here (both radix passes: values sharing their high 16
    // bits and differing in the low ones).
    for (const std::size_t n : {std::size_t(1), std::size_t(2), std::size_t(5), std::size_t(1000), std::size_t(1001), std::size_t(200000)}) {
        for (int kind = 0; kind < 3; ++kind) {
            INFO("n " << n << ", kind " << kind);
            std::vector<double> v(n);
            for (std::size_t i = 0; i < n; ++i)
                v[i] = kind == 0   ? std::pow(10.0, rng.uniform(-3.0, 3.0))
                       : kind == 1 ? std::bit_cast<float>(std::bit_cast<uint32_t>(1.5f) + static_cast<uint32_t>(rng.integer(0, 4000)))  // 1.5 + a few ulps
                                   : rng.uniform(-5.0, 5.0) * (i % 17 == 0 ? 0.0 : 1.0);
            std::vector<float> sorted(v.begin(), v.end());
            std::sort(sorted.begin(), sorted.end());
            CHECK(median_as_float(v) == sorted[n / 2]);
            tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
            CHECK(median_as_float(v) == sorted[n / 2]);
        }
    }
}

TEST_CASE("SMRF ground agrees with the synthetic scene's exact ground class", "[cloud][ground]") {
    ScratchDir dir("smrf");
    make_town(dir, 200, 4, 4);
    const PointCloud c = read_las(dir / "cloud.las");
    GroundFilterOptions go;
    go.trust_classification = false;
    const GroundResult g = classify_ground(c, {}, go);
    CHECK_FALSE(g.from_classification);
    std::size_t agree = 0, truth_ground = 0, found_ground = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
        const bool t = c.classification[i] == las_class::ground;
        truth_ground += t;
        found_ground += g.is_ground[i];
        agree += t == static_cast<bool>(g.is_ground[i]);
    }
    INFO("truth ground " << truth_ground << ", SMRF ground " << found_ground);
    CHECK(double(agree) / double(c.size()) > 0.95);
    GroundFilterOptions trust;
    CHECK(classify_ground(c, {}, trust).from_classification);
    tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
    CHECK(classify_ground(c, {}, go).is_ground == g.is_ground);
}

TEST_CASE("SMRF on two sites far apart (a grid each, grouped in parallel) flags the points as each site alone does, for any thread count", "[cloud][ground]") {
    // Two 150 m sites. 6 km east and 3 km north of each other: one 1 m grid
    // over both would hold 1.8e7 cells (tried whole, then split by the blocks
    // read off its minimum-z pass); 12 km east: 3.6e7 cells (split at once,
    // a byte a block); 600 km east and north: 3.6e11 cells (split through the
    // sorted list of occupied blocks). Each path flags what each site alone does.
    const auto site = [](PointCloud& c, double x0, double y0, uint64_t seed) {
        Rng rng(seed);
        for (int q = 0; q < 150 * 150; ++q) {
            const double x = x0 + (q % 150) + rng.uniform(0.0, 1.0), y = y0 + (q / 150) + rng.uniform(0.0, 1.0);
            const bool roof = std::abs(x - x0 - 75) < 12 && std::abs(y - y0 - 75) < 9;
            c.x.push_back(x), c.y.push_back(y), c.z.push_back(20.0 + 0.02 * (x - x0) + (roof ? 7.0 : 0.0) + rng.uniform(-0.05, 0.05));
            c.intensity.push_back(0), c.classification.push_back(1), c.return_number.push_back(1), c.number_of_returns.push_back(1);
        }
    };
    GroundFilterOptions go;
    go.trust_classification = false;
    PointCloud a;
    site(a, 400000.0, 5000000.0, 1);
    const GroundResult ga = classify_ground(a, {}, go);
    for (const auto& [dx, dy] : {std::pair{6000.0, 3000.0}, std::pair{12000.0, 0.0}, std::pair{600000.0, 600000.0}}) {
        INFO("second site " << dx << " m east, " << dy << " m north");
        PointCloud b, both;
        site(b, 400000.0 + dx, 5000000.0 + dy, 2);
        site(both, 400000.0, 5000000.0, 1), site(both, 400000.0 + dx, 5000000.0 + dy, 2);
        const GroundResult gb = classify_ground(b, {}, go), g = classify_ground(both, {}, go);
        std::vector<uint8_t> want = ga.is_ground;
        want.insert(want.end(), gb.is_ground.begin(), gb.is_ground.end());
        CHECK(g.is_ground == want);
        CHECK(g.ground_points == ga.ground_points + gb.ground_points);
        std::size_t roof_ground = 0;  // the roofs are not ground
        for (std::size_t i = 0; i < both.size(); ++i) {
            const double x0 = i < a.size() ? 400000.0 : 400000.0 + dx;
            roof_ground += g.is_ground[i] && both.z[i] - 20.0 - 0.02 * (both.x[i] - x0) > 3.0;
        }
        CHECK(roof_ground == 0);
        CHECK(g.ground_points > both.size() / 2);
        tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
        CHECK(classify_ground(both, {}, go).is_ground == g.is_ground);
    }
}

TEST_CASE("Outlier filter on grid neighbourhoods flags exactly the points of a whole-cloud k-d tree, for any thread count", "[cloud][filters]") {
    // Real AHN3 lidar (Delft, 675 k points) and IGN Lidar HD; plus far
    // isolated points above and below, which make the grid search reach out.
    for (const char* rel : {"delft_ahn3_bgt_west/ahn3_delft_west.las", "ign_lidarhd_bdtopo_west/lidarhd_870200_6617083_west.las"}) {
        INFO(rel);
        PointCloud c = read_las(shared_data(rel));
        REQUIRE(c.size() > 10000);
        // Noise classes (neither file has any): points in the surface, and
        // copies far above and below, which the search also finds isolated.
        for (std::size_t at : {c.size() / 5, c.size() / 7}) c.classification[at] = las_class::low_noise;
        c.classification[c.size() / 11] = las_class::high_noise;
        for (const auto& [dz, cls] : {std::pair{250.0, las_class::high_noise}, std::pair{-90.0, las_class::low_noise}}) {
            PointCloud one;
            one.reserve(1, c.has_color(), c.has_gps_time());
            one.append(c, c.size() / 4);
            one.z[0] += dz, one.classification[0] = cls;
            c.append(one, 0);
        }
        for (const double dz : {80.0, -60.0, 300.0}) {
            PointCloud one;
            one.reserve(1, c.has_color(), c.has_gps_time());
            one.append(c, c.size() / 3);
            one.z[0] += dz;
            c.append(one, 0);
        }
        // The defaults (k = 8 + the point: the compile-time path) and, on the
        // smaller cloud, other counts (any k).
        const bool small = c.size() < 300000;
        for (const auto& [k_neighbours, isolated_min] : {std::pair{8, 2}, std::pair{5, 7}}) {
            if (k_neighbours != 8 && !small) continue;
            INFO("k " << k_neighbours << ", isolated min " << isolated_min);
            OutlierFilterOptions o;
            o.k_neighbours = k_neighbours, o.isolated_min_neighbours = isolated_min;
            const std::vector<uint8_t> oracle = kd_tree_outlier_keep(c, o);
            const OutlierFilterResult r = filter_outliers(c, o);
            std::size_t differ = 0, removed = 0, not_flag = 0;
            for (std::size_t i = 0; i < c.size(); ++i) differ += r.keep[i] != oracle[i], removed += !r.keep[i], not_flag += r.keep[i] > 1;
            CHECK(differ == 0);
            CHECK(not_flag == 0);  // keep is 0 or 1, whatever the search marked on the way
            CHECK(r.removed_statistical >= 5);  // the noise classes count as statistical removals
            CHECK(removed >= 3);
            for (std::size_t i = c.size() - 3; i < c.size(); ++i) CHECK_FALSE(r.keep[i]);
            tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
            CHECK(filter_outliers(c, o).keep == r.keep);
        }
        // In canonical order (as every command filters): the grid's cells are
        // then counted and filled by blocks of columns in parallel.
        canonical_order(c);
        const OutlierFilterOptions o;
        const std::vector<uint8_t> oracle = kd_tree_outlier_keep(c, o);
        const OutlierFilterResult r = filter_outliers(c, o);
        CHECK(r.keep == oracle);
        tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
        CHECK(filter_outliers(c, o).keep == r.keep);
    }
}

TEST_CASE("Outlier filter on a diagonal corridor and on a cloud with a stray point kilometres away: the k-d tree's flags, cells for the ground covered", "[cloud][filters]") {
    // A 45° strip (2 km x 30 m: its bounding box is 50 times the ground it
    // covers), two east-west corridors 3 km apart (each column spans both:
    // the grid is laid out by rows instead), and a square with one stray point 20 km away. The grid
    // sizes its cells from the ground the points cover (BandedGrid); the flags
    // must be those of the whole-cloud k-d tree, for any thread count.
    const auto strip = [](double length, double width, double angle_deg, uint64_t seed) {
        PointCloud c;
        Rng rng(seed);
        const double a = angle_deg * M_PI / 180.0;
        const auto n = static_cast<std::size_t>(length * width * 2.0);  // 2 pts/m²
        for (std::size_t i = 0; i < n; ++i) {
            const double u = rng.uniform(0, length), v = rng.uniform(-width / 2, width / 2);
            c.x.push_back(500000 + u * std::cos(a) - v * std::sin(a)), c.y.push_back(5000000 + u * std::sin(a) + v * std::cos(a));
            c.z.push_back(40 + 0.01 * u + (std::fmod(u, 40.0) < 15 && std::abs(v) < 8 ? 7.0 : 0.0) + 0.05 * rng.normal());
            c.classification.push_back(1), c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
        }
        return c;
    };
    PointCloud diagonal = strip(2000, 30, 45, 11);
    PointCloud corridors = strip(1500, 30, 0, 12);
    corridors.append(strip(1500, 30, 0, 13), 0);
    for (std::size_t i = corridors.size() / 2; i < corridors.size(); ++i) corridors.y[i] += 3000;
    PointCloud stray = strip(150, 150, 0, 14);
    stray.x[0] += 20000, stray.y[0] += 15000, stray.z[0] = 45;
    for (PointCloud* c : {&diagonal, &corridors, &stray}) {
        // A few points far above and below the surface (the ring search reaches out).
        for (std::size_t i = 100; i < c->size(); i += c->size() / 4) c->z[i] += 90.0;
        OutlierFilterOptions o;
        const std::vector<uint8_t> oracle = kd_tree_outlier_keep(*c, o);
        const OutlierFilterResult r = filter_outliers(*c, o);
        std::size_t differ = 0, removed = 0;
        for (std::size_t i = 0; i < c->size(); ++i) differ += r.keep[i] != oracle[i], removed += !r.keep[i];
        INFO(c->size() << " points, " << removed << " removed");
        CHECK(differ == 0);
        CHECK(removed >= 3);
        tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
        CHECK(filter_outliers(*c, o).keep == r.keep);
    }
    CHECK_FALSE(filter_outliers(stray, OutlierFilterOptions{}).keep[0]);  // the stray point itself is an outlier
}

namespace {
// morphology_square as it was: for every cell the (2r+1)-wide window scanned
// cell by cell, rows then columns (the oracle for the running extrema).
template <typename T>
std::vector<T> naive_morphology(const std::vector<T>& in, int w, int h, int r, bool erode, std::optional<T> outside) {
    auto pick = [erode](T a, T b) { return erode ? std::min(a, b) : std::max(a, b); };
    std::vector<T> tmp(in.size()), out(in.size());
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            T v = in[static_cast<std::size_t>(y) * w + x];
            for (int d = -r; d <= r; ++d) {
                if (x + d < 0 || x + d >= w) {
                    if (outside) v = pick(v, *outside);
                    continue;
                }
                v = pick(v, in[static_cast<std::size_t>(y) * w + x + d]);
            }
            tmp[static_cast<std::size_t>(y) * w + x] = v;
        }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            T v = tmp[static_cast<std::size_t>(y) * w + x];
            for (int d = -r; d <= r; ++d) {
                if (y + d < 0 || y + d >= h) {
                    if (outside) v = pick(v, *outside);
                    continue;
                }
                v = pick(v, tmp[static_cast<std::size_t>(y + d) * w + x]);
            }
            out[static_cast<std::size_t>(y) * w + x] = v;
        }
    return out;
}
// Equal cell by cell, NaN equal to NaN.
bool same_cells(const std::vector<double>& a, const std::vector<double>& b) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i)
        if (!(a[i] == b[i] || (std::isnan(a[i]) && std::isnan(b[i])))) return false;
    return true;
}
}  // namespace

TEST_CASE("Square morphology (running extrema) equals the cell-by-cell window scan, NaN cells and grid edges included", "[cloud][ground][morphology]") {
    Rng rng(7);
    std::vector<double> reused_out, reused_scratch;
    // 530: three column strips; 256 x 17: one whole strip, rows in two groups of 8 and one of 1.
    for (const auto& [w, h] : {std::pair{1, 1}, std::pair{1, 9}, std::pair{13, 1}, std::pair{37, 23}, std::pair{130, 71}, std::pair{530, 9}, std::pair{256, 17}}) {
        std::vector<double> grid(static_cast<std::size_t>(w) * h);
        std::vector<uint8_t> mask(grid.size());
        for (std::size_t i = 0; i < grid.size(); ++i) {
            grid[i] = std::floor(rng.uniform(-20.0, 20.0)) * 0.5;  // ties on purpose
            if (rng.uniform(0.0, 1.0) < 0.1) grid[i] = NAN;
            mask[i] = rng.uniform(0.0, 1.0) < 0.6 ? 1 : 0;
        }
        for (const int r : {0, 1, 2, 3, 7, 18, 80})
            for (const bool erode : {true, false}) {
                INFO("w " << w << " h " << h << " r " << r << " erode " << erode);
                CHECK(same_cells(morphology_square(grid, w, h, r, erode), naive_morphology<double>(grid, w, h, r, erode, std::nullopt)));
                morphology_square(grid, w, h, r, erode, reused_out, reused_scratch);  // buffers of earlier calls (other sizes)
                CHECK(same_cells(reused_out, naive_morphology<double>(grid, w, h, r, erode, std::nullopt)));
                CHECK(same_cells(morphology_square(grid, w, h, r, erode, std::optional<double>(3.0)),
                                 naive_morphology<double>(grid, w, h, r, erode, 3.0)));
                CHECK(morphology_square(mask, w, h, r, erode) == naive_morphology<uint8_t>(mask, w, h, r, erode, std::nullopt));
                CHECK(morphology_square<uint8_t>(mask, w, h, r, erode, uint8_t(0)) == naive_morphology<uint8_t>(mask, w, h, r, erode, uint8_t(0)));
                // Caller-owned buffers holding stale values, on one thread.
                std::vector<double> out(grid.size(), 1e300), scratch(grid.size(), -1e300);
                tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
                morphology_square<double>(grid.data(), w, h, r, erode, out.data(), scratch.data());
                CHECK(same_cells(out, naive_morphology<double>(grid, w, h, r, erode, std::nullopt)));
            }
    }
}

namespace {
// fill_gaps as it was: the 8 directional sweeps over the whole grid, one
// after the other (the oracle for the sweeps by strips of rows).
void naive_fill_gaps(std::vector<double>& g, int w, int h, int limit) {
    const std::size_t cells = static_cast<std::size_t>(w) * h;
    auto sweep = [&](int lim, std::vector<double>& num, std::vector<double>& den) {
        const int dirs[8][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}, {1, 1}, {-1, -1}, {1, -1}, {-1, 1}};
        std::vector<double> last_v(cells);
        std::vector<int> last_d(cells);
        for (const auto& d : dirs) {
            const int dx = d[0], dy = d[1];
            const double step = (dx && dy) ? std::sqrt(2.0) : 1.0;
            for (int y = dy >= 0 ? 0 : h - 1; y != (dy >= 0 ? h : -1); y += dy >= 0 ? 1 : -1)
                for (int x = dx >= 0 ? 0 : w - 1; x != (dx >= 0 ? w : -1); x += dx >= 0 ? 1 : -1) {
                    const std::size_t k = static_cast<std::size_t>(y) * w + x;
                    if (!std::isnan(g[k])) {
                        last_v[k] = g[k], last_d[k] = 0;
                        continue;
                    }
                    const int px = x - dx, py = y - dy;
                    if (px < 0 || py < 0 || px >= w || py >= h) {
                        last_d[k] = -1;
                        continue;
                    }
                    const std::size_t pk = static_cast<std::size_t>(py) * w + px;
                    if (last_d[pk] < 0 || (lim > 0 && last_d[pk] + 1 > lim)) {
                        last_d[k] = -1;
                        continue;
                    }
                    last_d[k] = last_d[pk] + 1, last_v[k] = last_v[pk];
                    const double dist = last_d[k] * step, wgt = 1.0 / (dist * dist);
                    num[k] += wgt * last_v[k], den[k] += wgt;
                }
        }
    };
    double sum = 0.0;
    std::size_t valid = 0;
    for (double v : g)
        if (!std::isnan(v)) sum += v, ++valid;
    if (valid == 0 || valid == cells) return;
    std::vector<double> num(cells, 0.0), den(cells, 0.0), num_all(cells, 0.0), den_all(cells, 0.0);
    sweep(limit, num, den);
    sweep(0, num_all, den_all);
    for (std::size_t k = 0; k < cells; ++k)
        if (std::isnan(g[k]) && !(den[k] > 0)) num[k] = num_all[k], den[k] = den_all[k];
    for (std::size_t k = 0; k < cells; ++k)
        if (std::isnan(g[k])) g[k] = den[k] > 0 ? num[k] / den[k] : sum / double(valid);
}
}  // namespace

TEST_CASE("Gap fill by strips of rows equals the sweeps over the whole grid, for any thread count", "[cloud][ground][fill]") {
    Rng rng(11);
    // 700 rows: several strips of 256 rows (and of 4 x the reach) with their lead-in rows.
    for (const auto& [w, h] : {std::pair{1, 1}, std::pair{3, 700}, std::pair{90, 700}, std::pair{301, 1100}}) {
        std::vector<double> grid(static_cast<std::size_t>(w) * h);
        for (std::size_t i = 0; i < grid.size(); ++i) grid[i] = rng.uniform(0.0, 1.0) < 0.3 ? rng.uniform(-5.0, 5.0) : NAN;
        for (int y = 100; y < std::min(h, 480); ++y)  // a large gap: rays beyond every reach
            for (int x = 0; x < w; ++x) grid[static_cast<std::size_t>(y) * w + x] = NAN;
        for (const int limit : {0, 2, 40, 90}) {
            INFO("w " << w << " h " << h << " limit " << limit);
            std::vector<double> expected = grid, filled = grid, one_thread = grid;
            naive_fill_gaps(expected, w, h, limit);
            fill_gaps(filled, w, h, limit);
            CHECK(same_cells(filled, expected));
            // Only the cells of a mask filled (the others, e.g. beyond a survey, stay
            // empty): the filled ones get the values of the fill without a mask.
            std::vector<uint8_t> only(grid.size());
            for (std::size_t i = 0; i < only.size(); ++i) only[i] = (i / 7 + i / static_cast<std::size_t>(w)) % 3 != 0;
            std::vector<double> masked = grid;
            fill_gaps(masked, w, h, limit, &only);
            bool masked_ok = true;
            for (std::size_t i = 0; i < grid.size(); ++i) {
                const bool filled_cell = !std::isnan(grid[i]) || only[i];
                masked_ok = masked_ok && (filled_cell ? (masked[i] == expected[i] || (std::isnan(masked[i]) && std::isnan(expected[i]))) : std::isnan(masked[i]));
            }
            CHECK(masked_ok);
            // Caller-owned workspace holding stale values.
            std::vector<double> in_place = grid, num(grid.size(), 7.0), den(grid.size(), -3.0);
            fill_gaps(in_place.data(), w, h, limit, nullptr, [&] { return std::pair<double*, double*>{num.data(), den.data()}; });
            CHECK(same_cells(in_place, expected));
            tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
            fill_gaps(one_thread, w, h, limit);
            CHECK(same_cells(one_thread, expected));
        }
    }
}

namespace {
// canonical_order of `c` against std::sort of the key each point gives
// (key(cloud, i)), with the default threads and with one, and again on its
// own output (already in order: unchanged).
template <class KeyOf>
void check_canonical_order(const PointCloud& c, KeyOf key) {
    auto keys = [&](const PointCloud& p) {
        std::vector<decltype(key(p, 0))> k;
        for (std::size_t i = 0; i < p.size(); ++i) k.push_back(key(p, i));
        return k;
    };
    auto expected = keys(c);
    std::sort(expected.begin(), expected.end());
    PointCloud sorted = c;
    canonical_order(sorted);
    CHECK(keys(sorted) == expected);
    tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
    PointCloud sorted_one = c;
    canonical_order(sorted_one);
    CHECK(keys(sorted_one) == expected);
    canonical_order(sorted_one);
    CHECK(keys(sorted_one) == expected);
}
}  // namespace

TEST_CASE("canonical_order sorts by the whole key, by chunks and buckets in parallel, for any thread count", "[cloud][filters]") {
    // 300 k points (several chunks of the parallel counting sort), x and y on
    // a coarse grid (many ties broken by z and the other attributes), GPS time
    // and colour present.
    Rng rng(3);
    PointCloud c;
    const std::size_t n = 300000;
    for (std::size_t i = 0; i < n; ++i) {
        c.x.push_back(std::floor(rng.uniform(0, 300)) * 0.5), c.y.push_back(std::floor(rng.uniform(0, 40)) * 0.25);
        c.z.push_back(std::floor(rng.uniform(0, 4))), c.gps_time.push_back(std::floor(rng.uniform(0, 3)));
        c.intensity.push_back(static_cast<uint16_t>(rng.uniform(0, 3))), c.classification.push_back(static_cast<uint8_t>(rng.uniform(0, 3)));
        c.return_number.push_back(1), c.number_of_returns.push_back(1);
        c.red.push_back(static_cast<uint16_t>(rng.uniform(0, 2))), c.green.push_back(0), c.blue.push_back(0);
    }
    check_canonical_order(c, [](const PointCloud& p, std::size_t i) {
        return std::tuple{p.x[i], p.y[i], p.z[i], p.gps_time[i], p.intensity[i], p.classification[i], p.red[i]};
    });
}

TEST_CASE("canonical_order: coordinates of any magnitude and sign, zeros of both signs, one bucket holding most points", "[cloud][filters]") {
    // Buckets whose x and y span too many bits for the packed 128-bit key
    // (1e-300 next to 1e300, or x across 0) take the comparison sort, the
    // others (negative x too) the packed key; -0 and +0 are equal; 70 % of
    // the points on one x: the bucket split is uneven (the scratch grows by
    // the overhang). Equal (x, y) are broken by z and intensity.
    for (const auto& [share_on_one_x, share_special] : {std::pair{0.0, 0.1}, std::pair{0.7, 0.1}, std::pair{0.0, 0.0}}) {
        Rng rng(11);
        PointCloud c;
        const std::size_t n = 60000;
        const double specials[] = {-1e300, -1.0, -0.0, 0.0, 1e-300, 1.0, 1e300, 123456.789};
        for (std::size_t i = 0; i < n; ++i) {
            const double u = rng.uniform(0, 1);
            const double x = u < share_on_one_x ? 5.0
                             : rng.uniform(0, 1) < share_special ? specials[static_cast<std::size_t>(rng.uniform(0, 8)) % 8]
                                                                 : std::floor(rng.uniform(-500, 500)) * 0.01;
            const double y = rng.uniform(0, 1) < share_special ? specials[static_cast<std::size_t>(rng.uniform(0, 8)) % 8]
                                                               : 1000 + std::floor(rng.uniform(0, 50)) * 0.5;
            c.x.push_back(x), c.y.push_back(y), c.z.push_back(std::floor(rng.uniform(0, 3)));
            c.intensity.push_back(static_cast<uint16_t>(rng.uniform(0, 3))), c.classification.push_back(2);
            c.return_number.push_back(1), c.number_of_returns.push_back(1);
        }
        check_canonical_order(c, [](const PointCloud& p, std::size_t i) { return std::tuple{p.x[i], p.y[i], p.z[i], p.intensity[i]}; });
    }
}
