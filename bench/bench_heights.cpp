// Heights benchmark: a synthetic city at 8 pts/m2 (default 2000 m x 2000 m,
// 32 M points). Prints LAS read speed, outlier removal and ground seconds,
// heights seconds and buildings per second, flat-roof accuracy and peak RSS.
//
//   build/bin/bench_heights [size_m] [lidar|photo]
#include "bench_main.hpp"
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "cloud/cloud_filters.hpp"
#include "cloud/las.hpp"
#include "heights/building_heights.hpp"
#include "io/vector.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {
using cityforge::bench::now;
}  // namespace

static int run_bench(int argc, char** argv) {
    SynthOptions so;
    so.size_m = argc > 1 ? cityforge::bench::parse_number(argv[1], "SIZE_M") : 2000.0;
    so.cloud_mode = argc > 2 ? cloud_mode_from_string(argv[2]) : CloudMode::lidar;
    const auto dir = std::filesystem::temp_directory_path() / "cityforge_bench_heights";
    double t = now();
    const SynthResult s = write_synthetic_town(dir.string(), so);
    std::printf("synth %.0f m (%s): %d buildings, %llu points in %.1f s\n", so.size_m, to_string(so.cloud_mode).c_str(), s.buildings,
                static_cast<unsigned long long>(s.points), now() - t);
    t = now();
    const PointCloud cloud = read_las(s.cloud_path);
    const double t_read = now() - t;
    std::printf("LAS read: %.2f s, %.1f M points/s (%.0f MB/s)\n", t_read, double(cloud.size()) / t_read / 1e6,
                double(std::filesystem::file_size(s.cloud_path)) / t_read / 1e6);
    t = now();
    const OutlierFilterResult clean = filter_outliers(cloud, OutlierFilterOptions{});
    std::printf("outlier removal: %.2f s (%zu statistical + %zu isolated)\n", now() - t, clean.removed_statistical, clean.removed_isolated);
    t = now();
    const GroundResult ground = classify_ground(cloud, clean.keep, GroundFilterOptions{});
    std::printf("ground (class 2): %.2f s\n", now() - t);
    GroundFilterOptions smrf;
    smrf.trust_classification = false;
    t = now();
    const GroundResult g2 = classify_ground(cloud, clean.keep, smrf);
    std::size_t agree = 0;
    for (std::size_t i = 0; i < cloud.size(); ++i) agree += ground.is_ground[i] == g2.is_ground[i];
    std::printf("ground (SMRF): %.2f s, agreement with class 2: %.2f %%\n", now() - t, 100.0 * double(agree) / double(cloud.size()));
    const PolygonLayer truth = read_polygon_layer(s.truth_path);
    std::vector<std::vector<Polygon>> parts;
    for (const auto& f : truth.features) parts.push_back(f.geometry);
    t = now();
    const auto heights = compute_building_heights(cloud, clean.keep, ground.is_ground, parts, HeightOptions{});
    const double t_h = now() - t;
    std::printf("heights: %zu buildings in %.2f s = %.0f buildings/s\n", heights.size(), t_h, double(heights.size()) / t_h);
    // Flat roofs: height_m vs the true eave height (field 3 = eave_height_m, field 2 = roof_type).
    double err = 0.0;
    int n = 0;
    for (std::size_t i = 0; i < heights.size(); ++i) {
        const auto& v = truth.features[i].values;
        if (std::get<std::string>(v[2]) != "flat" || !heights[i].height_m) continue;
        err += std::abs(*heights[i].height_m - std::get<double>(v[3]));
        ++n;
    }
    std::printf("flat roofs: MAE %.3f m over %d buildings\n", n ? err / n : 0.0, n);
    std::printf("peak RSS: %.0f MB\n", cityforge::peak_memory_mb());
    std::filesystem::remove_all(dir);
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_heights", "bench_heights [SIZE_M] [lidar|photo]", run_bench);
}
