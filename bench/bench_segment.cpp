// Segmentation benchmark: the reference study's Table 4 on our own synthetic
// towns. For each scene size: watershed time and region count, then for each
// queue strategy and scale the initial queue length, merges and seconds, and
// the relative segmentation accuracy (RAS: share of pixels whose final label
// agrees with rag's) of nng and mutual. Prints a table; asserts nothing.
//
//   build/bin/bench_segment [size_m ...]     (default: 1300 4000)
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <sys/resource.h>
#include <vector>

#include "raster/raster.hpp"
#include "segment/region_merging.hpp"
#include "segment/watershed.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {
double now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
long peak_rss_kb() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return u.ru_maxrss;
}
}  // namespace

int main(int argc, char** argv) {
    std::vector<double> sizes;
    for (int i = 1; i < argc; ++i) sizes.push_back(std::atof(argv[i]));
    if (sizes.empty()) sizes = {1300, 4000};
    const std::vector<double> scales{500, 1000, 1500, 2000, 2500, 3000};
    const std::vector<double> fine_scales{10, 20, 30, 40, 50, 60};
    for (double size : sizes) {
        const auto dir = std::filesystem::temp_directory_path() / ("cityforge_bench_" + std::to_string(int(size)));
        SynthOptions so;
        so.size_m = size;
        so.cloud_density_m2 = 0;
        write_synthetic_town(dir.string(), so);
        Image<float> img = RasterReader((dir / "ortho.tif").string()).read_all<float>();
        normalize_bands(img, {});
        double t = now();
        const Oversegmentation over = watershed_oversegment(img, {}, WatershedOptions{});
        const double t_ws = now() - t;
        std::printf("\nscene %.0f m: %d x %d px, watershed %u regions in %.3f s (%.1f Mpx/s)\n", size, img.width, img.height,
                    over.region_count, t_ws, double(img.pixel_count()) / t_ws / 1e6);
        for (const auto* sc : {&scales, &fine_scales}) {
            std::printf("%-8s %-7s %12s %10s %10s %10s\n", "strategy", "scale", "init_queue", "regions", "merges", "seconds");
            std::vector<uint32_t> rag_final;
            for (auto s : {QueueStrategy::rag, QueueStrategy::nng, QueueStrategy::mutual}) {
                RegionMergingOptions mo;
                mo.scales = *sc;
                mo.strategy = s;
                t = now();
                const auto res = merge_regions(img, over.labels, over.region_count, mo);
                const double total = now() - t;
                for (const auto& l : res.levels)
                    std::printf("%-8s %-7g %12llu %10u %10llu %10.3f\n", to_string(s).c_str(), l.scale,
                                static_cast<unsigned long long>(l.initial_queue_length), l.regions_after,
                                static_cast<unsigned long long>(l.merges), l.seconds);
                const auto& last = res.levels.back().label_of_input;
                double ras = 1.0;
                if (s == QueueStrategy::rag) rag_final = last;
                else {
                    std::size_t agree = 0;
                    for (uint32_t v : over.labels.data) agree += last[v] == rag_final[v];
                    ras = double(agree) / double(over.labels.data.size());
                }
                double merging = 0.0;
                for (const auto& l : res.levels) merging += l.seconds;
                std::printf("%-8s total %.3f s over %zu scales (graph %.3f s, merging %.3f s), RAS vs rag %.4f\n",
                            to_string(s).c_str(), total, sc->size(), res.graph_seconds, merging, ras);
            }
        }
        std::printf("peak RSS so far: %.1f MB (%.1f bytes/pixel of the largest scene)\n", double(peak_rss_kb()) / 1024.0,
                    double(peak_rss_kb()) * 1024.0 / double(img.pixel_count()));
        std::filesystem::remove_all(dir);
    }
    return 0;
}
