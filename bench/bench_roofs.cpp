// LOD2 benchmark: every building of a synthetic city (default 4000 m,
// ~9,700 buildings) gets roof points sampled from its exact roof (8 pts/m²,
// 3 cm noise, as airborne LiDAR) and is reconstructed; prints buildings per
// second (both cores), roof-type accuracy, RMSE to the exact roofs' points,
// valid solids and the peak memory. The cloud stages before it (reading,
// cleaning, ground) are measured by bench_heights.
//
//   build/bin/bench_roofs [size_m] [density_per_m2]
#include "bench_main.hpp"
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <tbb/parallel_for.h>

#include "roof/lod2_builder.hpp"
#include "synth/scene.hpp"

using namespace cityforge;

static int run_bench(int argc, char** argv) {
    synth::SceneLayout layout;
    layout.size_m = argc > 1 ? cityforge::bench::parse_number(argv[1], "SIZE_M") : 4000.0;
    const double density = argc > 2 ? cityforge::bench::parse_number(argv[2], "DENSITY") : 8.0;
    layout.seed = 1;
    const synth::Scene scene = synth::generate_scene(layout);
    const std::size_t n = scene.buildings.size();
    std::vector<std::vector<Polygon>> footprints(n);
    std::vector<std::vector<std::array<double, 3>>> points(n);
    std::size_t total_points = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const synth::SceneBuilding& b = scene.buildings[i];
        Polygon p = b.footprint();
        orient_polygon(p);
        footprints[i] = {p};
        points[i] = synth::sample_roof_points(b, density, 0.03, 5);
        total_points += points[i].size();
    }
    std::vector<Lod2Result> results(n);
    const auto t0 = std::chrono::steady_clock::now();
    tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
        const synth::SceneBuilding& b = scene.buildings[i];
        results[i] = reconstruct_lod2(footprints[i], points[i], b.ground_z, b.ground_z + b.eave_height_m);
    });
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::size_t correct = 0, valid = 0, fallback = 0;
    double rmse = 0;
    std::map<std::string, std::pair<int, int>> per_type;
    for (std::size_t i = 0; i < n; ++i) {
        const std::string truth = synth::to_string(scene.buildings[i].roof);
        auto& t = per_type[truth];
        ++t.second;
        if (results[i].roof_type == truth) ++correct, ++t.first;
        bool ok = true;
        for (const Solid& s : results[i].solids) ok = ok && validate_solid(s).empty();
        valid += ok;
        fallback += results[i].fallback;
        rmse += results[i].rmse_m;
    }
    std::printf("%.0f m city: %zu buildings, %zu roof points (%.1f per m2)\n", layout.size_m, n, total_points, density);
    std::printf("LOD2 reconstruction %.2f s = %.0f buildings/s; valid solids %zu / %zu; flat fallbacks %zu\n", seconds, double(n) / seconds,
                valid, n, fallback);
    std::printf("roof type accuracy %.1f %% (", 100.0 * double(correct) / double(n));
    for (const auto& [k, v] : per_type) std::printf(" %s %d/%d", k.c_str(), v.first, v.second);
    std::printf(" ); mean RMSE points to model %.3f m; peak memory %.0f MB\n", rmse / double(n), cityforge::peak_memory_mb());
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_roofs", "bench_roofs [SIZE_M] [DENSITY]", run_bench);
}
