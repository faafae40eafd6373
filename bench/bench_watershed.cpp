// Watershed benchmark: the band normalisation and the watershed alone on a
// window of a real raster, repeated, on a given number of threads; prints
// wall and CPU seconds of each run, its minor page faults, the region count
// and a hash of the labels (to check that builds and thread counts give the same labels).
// Asserts nothing.
//
//   build/bin/bench_watershed --raster FILE [--window col,row,w,h]
//       [--h-minima H] [--smoothing S] [--threads N] [--repeat N]
// Defaults: the whole raster, h 4, smoothing 1 (what `segment` uses), all
// threads, 3 runs.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <sys/resource.h>
#include <tbb/global_control.h>

#include "bench_main.hpp"
#include "raster/raster.hpp"
#include "segment/watershed.hpp"

using namespace cityforge;

namespace {
using cityforge::bench::now;
using cityforge::bench::cpu_now;

// Minor page faults of the process so far (first touches of fresh memory:
// each clears a page, which shows in CPU time).
long minor_faults() {
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_minflt;
}
}  // namespace

namespace {
int run(int argc, char** argv) {
    std::string path;
    std::vector<int> window;
    WatershedOptions wo;
    int threads = 0, repeat = 3;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "bench_watershed: %s needs a value\n", a.c_str());
                std::exit(2);
            }
            return argv[++i];
        };
        auto number = [&]() { return bench::parse_number(next().c_str(), a.c_str()); };
        if (a == "--raster") path = next();
        else if (a == "--window") {
            std::stringstream ss(next());
            std::string item;
            while (std::getline(ss, item, ',')) window.push_back(static_cast<int>(bench::parse_number(item.c_str(), "--window")));
        } else if (a == "--h-minima") wo.h_minima = number();
        else if (a == "--smoothing") wo.smoothing_sigma_px = number();
        else if (a == "--threads") threads = static_cast<int>(number());
        else if (a == "--repeat") repeat = static_cast<int>(number());
        else {
            std::fprintf(stderr, "bench_watershed: unknown argument %s\n", a.c_str());
            return 2;
        }
    }
    if (path.empty()) {
        std::fprintf(stderr, "bench_watershed: --raster FILE is required\n");
        return 2;
    }
    std::unique_ptr<tbb::global_control> limit;
    if (threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
    RasterReader reader(path);
    const RasterInfo& info = reader.info();
    PixelWindow w{0, 0, info.width, info.height};
    if (window.size() == 4) {
        w.col = std::max(0, window[0]), w.row = std::max(0, window[1]);
        w.width = std::min(window[2], info.width - w.col), w.height = std::min(window[3], info.height - w.row);
    }
    std::vector<int> bands;
    for (int b = 1; b <= std::min(3, int(info.bands.size())); ++b) bands.push_back(b);
    const Image<float> raw = reader.read<float>(w, bands);
    std::printf("window %d,%d %dx%d (%.1f MP), h-minima %g, smoothing %g, threads %s\n", w.col, w.row, w.width, w.height,
                double(raw.pixel_count()) / 1e6, wo.h_minima, wo.smoothing_sigma_px, threads > 0 ? std::to_string(threads).c_str() : "all");
    for (int r = 0; r < repeat; ++r) {
        Image<float> img = raw;
        const long f0 = minor_faults();
        const double t0 = now(), c0 = cpu_now();
        normalize_bands(img, {});
        const double t1 = now(), c1 = cpu_now();
        const Oversegmentation over = watershed_oversegment(img, {}, wo);
        const double t2 = now(), c2 = cpu_now();
        const long f2 = minor_faults();
        uint64_t hash = 1469598103934665603ull;  // FNV-1a of the labels
        for (uint32_t v : over.labels.data) hash = (hash ^ v) * 1099511628211ull;
        std::printf("run %d: normalise %.3f s wall %.3f s CPU, watershed %.3f s wall %.3f s CPU, total %.3f s CPU, %ld page faults -> %u regions, hash %016llx\n",
                    r + 1, t1 - t0, c1 - c0, t2 - t1, c2 - c1, c2 - c0, f2 - f0, over.region_count, static_cast<unsigned long long>(hash));
    }
    return 0;
}
}  // namespace

int main(int argc, char** argv) {
    return bench::run_main(argc, argv, "bench_watershed",
                           "bench_watershed --raster FILE [--window col,row,w,h] [--h-minima H] [--smoothing S] [--threads N] [--repeat N]", run);
}
