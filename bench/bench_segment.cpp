// Segmentation benchmark: the reference study's Table 4 on our own synthetic
// towns. For each scene size: watershed time and region count, then for each
// queue strategy and scale the initial queue length, merges and seconds, and
// the relative segmentation accuracy (RAS: share of pixels whose final label
// agrees with rag's) of nng and mutual. Prints a table; asserts nothing.
//
//   build/bin/bench_segment [size_m ...]     (default: 1300 4000)
//
// Real raster mode: a window of any GDAL raster at its native resolution,
// watershed (options below), then each strategy through the scales; merges/s
// per scale; checks that all strategies give the same labels (prints it).
//
//   build/bin/bench_segment --raster FILE [--window col,row,w,h] [--h-minima H]
//       [--smoothing S] [--scales a,b,...] [--strategies rag,nng,mutual]
//       [--min-regions N] [--seeds-out seeds.tif] [--seeds-in seeds.tif]
//       [--labels-out final.tif] [--json out.json]
// The window is clipped to the raster. --seeds-in skips the watershed and
// merges the given label raster (1..N, 0 = nodata); --seeds-out writes ours.
#include "bench_main.hpp"
#include <chrono>
#include <ctime>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "raster/raster.hpp"
#include "segment/region_merging.hpp"
#include "segment/watershed.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {
using cityforge::bench::now;
using cityforge::bench::cpu_now;  // less sensitive to the load of a shared machine than wall time

std::vector<double> parse_list(const std::string& s) {
    std::vector<double> v;
    std::stringstream ss(s);
    std::string item;
    while (std::getline(ss, item, ',')) v.push_back(cityforge::bench::parse_number(item.c_str(), "list item"));
    return v;
}

// Renumbers labels 1..N in raster order of first appearance (0 stays 0).
uint32_t compact_labels(Image<uint32_t>& lab) {
    std::vector<uint32_t> map;
    uint32_t next = 0;
    for (uint32_t& v : lab.data) {
        if (!v) continue;
        if (v >= map.size()) map.resize(std::size_t(v) + 1, 0);
        if (!map[v]) map[v] = ++next;
        v = map[v];
    }
    return next;
}

int raster_mode(int argc, char** argv) {
    std::string path, seeds_out, seeds_in, labels_out, json_out;
    std::vector<double> window, scales{10, 20, 30, 40, 50, 60};
    std::vector<QueueStrategy> strategies{QueueStrategy::rag, QueueStrategy::nng, QueueStrategy::mutual};
    WatershedOptions wo;
    uint32_t min_regions = 0;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) throw Error(a, "needs a value");
            return argv[++i];
        };
        if (a == "--raster") path = next();
        else if (a == "--window") window = parse_list(next());
        else if (a == "--h-minima") wo.h_minima = cityforge::bench::parse_number(next().c_str(), "--h-minima");
        else if (a == "--smoothing") wo.smoothing_sigma_px = cityforge::bench::parse_number(next().c_str(), "--smoothing");
        else if (a == "--scales") scales = parse_list(next());
        else if (a == "--min-regions") min_regions = static_cast<uint32_t>(cityforge::bench::parse_number(next().c_str(), "--min-regions"));
        else if (a == "--seeds-out") seeds_out = next();
        else if (a == "--seeds-in") seeds_in = next();
        else if (a == "--labels-out") labels_out = next();
        else if (a == "--json") json_out = next();
        else if (a == "--strategies") {
            strategies.clear();
            std::stringstream ss(next());
            std::string item;
            while (std::getline(ss, item, ',')) strategies.push_back(queue_strategy_from_string(item));
        } else {
            throw Error(a, "unknown argument (see --help)");
        }
    }
    RasterReader reader(path);
    const RasterInfo& info = reader.info();
    PixelWindow w{0, 0, info.width, info.height};
    if (window.size() == 4) {
        w.col = std::max(0, int(window[0])), w.row = std::max(0, int(window[1]));
        w.width = std::min(int(window[2]), info.width - w.col), w.height = std::min(int(window[3]), info.height - w.row);
    }
    std::vector<int> bands;
    for (int b = 1; b <= std::min(3, int(info.bands.size())); ++b) bands.push_back(b);
    Image<float> img = reader.read<float>(w, bands);
    const double t_norm0 = now(), c_norm0 = cpu_now();
    normalize_bands(img, {});
    const double t_norm = now() - t_norm0, c_norm = cpu_now() - c_norm0;  // reported with the watershed
    nlohmann::json report;
    report["raster"] = path;
    report["window"] = {w.col, w.row, w.width, w.height};
    std::printf("raster %s window %d,%d %dx%d (%.1f MP), %d band(s)\n", path.c_str(), w.col, w.row, w.width, w.height,
                double(img.pixel_count()) / 1e6, img.bands);
    Oversegmentation over;
    if (!seeds_in.empty()) {
        over.labels = RasterReader(seeds_in).read_all<uint32_t>();
        if (over.labels.width != img.width || over.labels.height != img.height) {
            std::fprintf(stderr, "bench_segment: %s is not %dx%d\n", seeds_in.c_str(), img.width, img.height);
            return 2;
        }
        over.region_count = compact_labels(over.labels);
        std::printf("seeds from %s: %u regions\n", seeds_in.c_str(), over.region_count);
    } else {
        const double t = now(), c = cpu_now();
        over = watershed_oversegment(img, {}, wo);
        const double t_ws = now() - t, c_ws = cpu_now() - c;
        std::printf("watershed (h-minima %g, smoothing %g px): %u regions in %.3f s wall, %.3f s CPU (%.1f Mpx/s)\n", wo.h_minima,
                    wo.smoothing_sigma_px, over.region_count, t_ws, c_ws, double(img.pixel_count()) / t_ws / 1e6);
        std::printf("normalising the bands (0.5-99.5 %% stretch) before it: %.3f s wall, %.3f s CPU\n", t_norm, c_norm);
        report["watershed"] = {{"regions", over.region_count}, {"seconds", t_ws}, {"cpu_seconds", c_ws},
                               {"normalize_seconds", t_norm}, {"normalize_cpu_seconds", c_norm}};
    }
    if (!seeds_out.empty()) {
        GeoTiffWriteOptions wopt;
        wopt.nodata = 0;
        write_geotiff(seeds_out, over.labels, info.transform.window(w.col, w.row), info.crs.wkt, wopt);
    }
    std::vector<uint32_t> reference;
    std::string reference_name;
    for (QueueStrategy s : strategies) {
        RegionMergingOptions mo;
        mo.scales = scales;
        mo.strategy = s;
        mo.min_regions = min_regions;
        const double t = now(), c = cpu_now();
        const auto res = merge_regions(img, over.labels, over.region_count, mo);
        const double total = now() - t, cpu = cpu_now() - c;
        std::printf("%-8s %-7s %10s %10s %10s %10s %12s %10s %10s\n", "strategy", "scale", "regions", "merges", "wall_s", "cpu_s",
                    "merges/cpu_s", "max_degree", "pushes");
        uint64_t merges = 0;
        double merging = 0.0, merging_cpu = 0.0;
        for (const auto& l : res.levels) {
            std::printf("%-8s %-7g %10u %10llu %10.3f %10.3f %12.0f %10u %10llu\n", to_string(s).c_str(), l.scale, l.regions_after,
                        static_cast<unsigned long long>(l.merges), l.seconds, l.cpu_seconds,
                        double(l.merges) / std::max(l.cpu_seconds, 1e-9), l.max_degree,
                        static_cast<unsigned long long>(l.queue_pushes));
            merges += l.merges, merging += l.seconds, merging_cpu += l.cpu_seconds;
        }
        const auto& last = res.levels.back().label_of_input;
        std::string same = "reference";
        if (reference.empty()) reference = last, reference_name = to_string(s);
        else same = last == reference ? "identical to " + reference_name : "DIFFERENT from " + reference_name;
        uint64_t hash = 1469598103934665603ull;  // FNV-1a of the final labels, to compare builds
        for (uint32_t v : last) hash = (hash ^ v) * 1099511628211ull;
        std::printf("%-8s total %.3f s wall, %.3f s CPU (graph %.3f s wall, %.3f s CPU; merging %.3f s wall, %.3f s CPU, %.0f merges/CPU s) -> "
                    "%u regions; labels %s, hash %016llx; %llu adjacent pairs at the start\n",
                    to_string(s).c_str(), total, cpu, res.graph_seconds, res.graph_cpu_seconds, merging, merging_cpu, double(merges) / std::max(merging_cpu, 1e-9),
                    res.levels.back().regions_after, same.c_str(), static_cast<unsigned long long>(hash),
                    static_cast<unsigned long long>(res.adjacent_pairs));
        report["merging"][to_string(s)] = {{"seconds", total}, {"cpu_seconds", cpu}, {"graph_seconds", res.graph_seconds}, {"graph_cpu_seconds", res.graph_cpu_seconds}, {"merging_seconds", merging}, {"merging_cpu_seconds", merging_cpu},
                                           {"merges", merges}, {"regions", res.levels.back().regions_after}, {"labels", same}};
        if (!labels_out.empty() && s == strategies.back()) {
            GeoTiffWriteOptions wopt;
            wopt.nodata = 0;
            write_geotiff(labels_out, relabel(over.labels, last), info.transform.window(w.col, w.row), info.crs.wkt, wopt);
        }
    }
    std::printf("peak RSS: %.1f MB\n", cityforge::peak_memory_mb());
    if (!json_out.empty()) std::ofstream(json_out) << report.dump(2) << "\n";
    return 0;
}
}  // namespace

static int run_bench(int argc, char** argv) {
    for (int i = 1; i < argc; ++i)
        if (std::string(argv[i]) == "--raster") return raster_mode(argc, argv);
    std::vector<double> sizes;
    for (int i = 1; i < argc; ++i) sizes.push_back(cityforge::bench::parse_number(argv[i], "size_m"));
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
        std::printf("peak RSS so far: %.1f MB (%.1f bytes/pixel of the largest scene)\n", cityforge::peak_memory_mb(),
                    cityforge::peak_memory_mb() * 1048576.0 / double(img.pixel_count()));
        std::filesystem::remove_all(dir);
    }
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_segment",
                                      "bench_segment [SIZE_M ...] | --raster FILE [--window col,row,w,h] [--h-minima H] [--smoothing S] "
                                      "[--scales a,b,...] [--strategies rag,nng,mutual] [--min-regions N] [--seeds-out F] [--seeds-in F] "
                                      "[--labels-out F] [--json F]",
                                      run_bench);
}
