// Cloud stage benchmark: reading a LAS file, canonical point order,
// statistical + isolated outlier removal and SMRF ground filtering, in points
// per second (wall and CPU), on a given file or on a synthetic town. Prints
// figures and a digest (FNV-1a) of the kept and ground flags, so that two
// builds can be checked to give the same result; asserts nothing.
//
//   build/bin/bench_cloud FILE.las            (any LAS/LAZ the reader takes)
//   build/bin/bench_cloud --synth SIZE_M [DENSITY]   (default 8 pts/m²)
//   build/bin/bench_cloud --read FILE.las [REPEATS]  (reading only, whole and streamed, REPEATS times)
//   build/bin/bench_cloud --digest FILE.las  (read_las once; a digest of every array of the cloud)
#include "bench_main.hpp"
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <string>
#include <vector>
#include <sys/resource.h>

#include "cloud/cloud_filters.hpp"
#include "cloud/surface_support.hpp"
#include "cloud/las.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {
using cityforge::bench::now;
using cityforge::bench::cpu_now;
// System CPU seconds and minor page faults of the process so far.
struct SysUsage {
    double sys_s = 0;
    long faults = 0;
};
SysUsage sys_now() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return {double(u.ru_stime.tv_sec) + 1e-6 * double(u.ru_stime.tv_usec), u.ru_minflt};
}
SysUsage sys_start;
// One line per step: wall and CPU seconds (user + system), points per second
// of both, and of the CPU the system's share and the page faults (fresh
// memory costs here).
void report(const char* what, std::size_t n, double wall, double cpu) {
    const SysUsage s = sys_now();
    std::printf("%-22s %12zu points %8.3f s wall %8.3f s CPU %8.2f M points/s wall %8.2f M points/CPU s  (sys %.2f s, %.2f M page faults)\n", what, n,
                wall, cpu, double(n) / wall / 1e6, double(n) / cpu / 1e6, s.sys_s - sys_start.sys_s, double(s.faults - sys_start.faults) / 1e6);
}
uint64_t digest(const std::vector<uint8_t>& v) {
    uint64_t h = 1469598103934665603ull;
    for (uint8_t b : v) h = (h ^ b) * 1099511628211ull;
    return h;
}
// FNV-1a over the 8-byte words of an array's bytes (then its tail bytes),
// seeded with its size: equal digests of two reads = the same bytes.
template <class T>
uint64_t array_digest(const std::vector<T>& v) {
    const auto* p = reinterpret_cast<const unsigned char*>(v.data());
    const std::size_t bytes = v.size() * sizeof(T);
    uint64_t h = 1469598103934665603ull ^ bytes;
    std::size_t i = 0;
    for (; i + 8 <= bytes; i += 8) {
        uint64_t w;
        std::memcpy(&w, p + i, 8);
        h = (h ^ w) * 1099511628211ull;
    }
    for (; i < bytes; ++i) h = (h ^ p[i]) * 1099511628211ull;
    return h;
}
}  // namespace

static int run_bench(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: bench_cloud FILE.las | --synth SIZE_M [DENSITY] | --read FILE.las [REPEATS] | --digest FILE.las\n");
        return 2;
    }
    std::string path = argv[1];
    if (path == "--digest") {  // the cloud's bytes, to compare two builds' readers
        if (argc < 3) throw Error("--digest", "needs a LAS file");
        const PointCloud c = read_las(argv[2]);
        const std::pair<const char*, uint64_t> arrays[] = {
            {"x", array_digest(c.x)}, {"y", array_digest(c.y)}, {"z", array_digest(c.z)}, {"intensity", array_digest(c.intensity)},
            {"classification", array_digest(c.classification)}, {"return_number", array_digest(c.return_number)},
            {"number_of_returns", array_digest(c.number_of_returns)}, {"gps_time", array_digest(c.gps_time)},
            {"red", array_digest(c.red)}, {"green", array_digest(c.green)}, {"blue", array_digest(c.blue)}};
        uint64_t all = 1469598103934665603ull;
        for (const auto& [name, d] : arrays) std::printf("  %-18s %016llx\n", name, static_cast<unsigned long long>(d)), all = (all ^ d) * 1099511628211ull;
        std::printf("cloud digest %016llx (%zu points)\n", static_cast<unsigned long long>(all), c.size());
        return 0;
    }
    if (path == "--read") {  // reading alone, repeated (page cache warm after the first)
        if (argc < 3) throw Error("--read", "needs a LAS file");
        const int repeats = argc > 3 ? int(cityforge::bench::parse_number(argv[3], "REPEATS")) : 1;
        for (int r = 0; r < repeats; ++r) {
            double load = 0;
            if (FILE* f = std::fopen("/proc/loadavg", "r")) {
                if (std::fscanf(f, "%lf", &load) != 1) load = 0;
                std::fclose(f);
            }
            double t = now(), c = cpu_now();
            sys_start = sys_now();
            {
                const PointCloud cloud = read_las(argv[2]);
                report("read_las", cloud.size(), now() - t, cpu_now() - c);
            }
            // Streamed: chunks of 1 M points into one reused cloud, as the
            // run's passes over the cloud read it (no fresh memory per point).
            t = now(), c = cpu_now(), sys_start = sys_now();
            LasReader reader(argv[2]);
            PointCloud chunk;
            std::size_t n = 0;
            while (true) {
                chunk.clear();
                const std::size_t got = reader.read_chunk(chunk, 1u << 20);
                if (got == 0) break;
                n += got;
            }
            report("read_chunk (streamed)", n, now() - t, cpu_now() - c);
            std::printf("  load %.2f\n", load);
        }
        return 0;
    }
    std::filesystem::path dir;
    if (path == "--synth") {
        SynthOptions so;
        so.size_m = argc > 2 ? cityforge::bench::parse_number(argv[2], "SIZE_M") : 500;
        so.cloud_density_m2 = argc > 3 ? cityforge::bench::parse_number(argv[3], "DENSITY") : 8;
        dir = std::filesystem::temp_directory_path() / ("cityforge_bench_cloud_" + std::to_string(int(so.size_m)));
        write_synthetic_town(dir.string(), so);
        path = (dir / "cloud.las").string();
    }
    double t = now(), c = cpu_now();
    sys_start = sys_now();
    PointCloud cloud = read_las(path);
    report("read_las", cloud.size(), now() - t, cpu_now() - c);
    t = now(), c = cpu_now(), sys_start = sys_now();
    canonical_order(cloud);  // as every command does before the filters
    report("canonical_order", cloud.size(), now() - t, cpu_now() - c);
    t = now(), c = cpu_now(), sys_start = sys_now();
    const OutlierFilterResult out = filter_outliers(cloud, OutlierFilterOptions{});
    report("filter_outliers", cloud.size(), now() - t, cpu_now() - c);
    std::printf("  removed %zu statistical, %zu isolated (limit %.6f), keep digest %016llx\n", out.removed_statistical, out.removed_isolated,
                out.limit, static_cast<unsigned long long>(digest(out.keep)));
    // Sparse surfaces back in, as every command does after the filter (prepared_cloud.cpp).
    std::vector<uint8_t> keep = out.keep;
    t = now(), c = cpu_now(), sys_start = sys_now();
    const std::size_t restored = restore_surface_points(cloud, keep, SurfaceSupportOptions{});
    report("restore_surface_points", cloud.size(), now() - t, cpu_now() - c);
    std::printf("  restored %zu, keep digest %016llx\n", restored, static_cast<unsigned long long>(digest(keep)));
    GroundFilterOptions go;
    go.trust_classification = false;
    t = now(), c = cpu_now(), sys_start = sys_now();
    const GroundResult g = classify_ground(cloud, keep, go);
    report("classify_ground (SMRF)", cloud.size(), now() - t, cpu_now() - c);
    std::printf("  %zu ground points, ground digest %016llx\n", g.ground_points, static_cast<unsigned long long>(digest(g.is_ground)));
    if (!dir.empty()) std::filesystem::remove_all(dir);
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_cloud", "bench_cloud FILE.las | --synth SIZE_M [DENSITY] | --read FILE.las [REPEATS] | --digest FILE.las", run_bench);
}
