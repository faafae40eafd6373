// LAZ decoding speed over a corpus folder, checked against its oracle.
//   bench_laz [CORPUS_DIR] [--repeat N] [--points]
// CORPUS_DIR defaults to ../shared/data/laz_corpus. Prints, per file, points,
// decode time and whether the sha256 of the decoded records equals
// oracle.json's; then the total in M points/s (all chunks of a file decoded
// in parallel with TBB; set the thread count with TBB's usual arena, e.g.
// `taskset -c 0,1`). Decode CPU seconds exclude the SHA-256, which is
// timed and printed apart. --points also times the PointCloud path (LasReader::
// read_chunk, which skips the layers a PointCloud does not hold).
// --kernel also times the chunk decoder alone on one thread (chunks read into
// memory first, decoded one after the other into one buffer as the reader
// decodes them, layer tasks and all, in a one-thread arena; thread CPU time,
// best of --repeat): the per-core figure, free of I/O, copies and scheduling.
// --threads N caps TBB's worker count (default: all cores).
#include "bench_main.hpp"
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <ctime>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cloud/las.hpp"
#include "core/resource_usage.hpp"
#include "core/error.hpp"
#include "core/sha256.hpp"

namespace {
// Single-thread decode of every chunk of a LAZ file: best thread-CPU seconds
// of `repeat` passes; `hash` gets the sha256 of the decoded records.
double kernel_seconds(const std::string& path, int repeat, std::string& hash) {
    cityforge::LasReader reader(path);
    cityforge::LazPointSource* laz = reader.laz_source();
    if (!laz || !laz->has_chunk_table()) return -1.0;
    const auto& h = reader.header();
    const std::size_t rl = static_cast<std::size_t>(h.point_record_length);
    std::ifstream in(path, std::ios::binary);
    std::vector<std::vector<uint8_t>> raw;
    for (const auto& c : laz->chunks()) {
        raw.emplace_back(static_cast<std::size_t>(c.bytes));
        in.seekg(static_cast<std::streamoff>(c.offset));
        in.read(reinterpret_cast<char*>(raw.back().data()), static_cast<std::streamsize>(c.bytes));
    }
    std::vector<char> out(static_cast<std::size_t>(h.point_count) * rl);
    double best = 1e30;
    // The reader's decode of each chunk (layered chunks split into layer
    // tasks as LazPointSource does), in an arena of one thread so that every
    // task runs on this thread and its CPU time counts.
    tbb::task_arena one(1);
    one.execute([&] {
        for (int r = 0; r < repeat; ++r) {
            const double t0 = cityforge::thread_cpu_seconds();
            for (std::size_t i = 0; i < raw.size(); ++i) {
                const auto& c = laz->chunks()[i];
                cityforge::decode_laz_chunk(*h.laz, h.point_record_length, raw[i].data(), raw[i].size(), c.point_count,
                                            out.data() + c.first_point * rl, path, i, false, laz->split_layers(c));
            }
            best = std::min(best, cityforge::thread_cpu_seconds() - t0);
        }
    });
    cityforge::Sha256 sha;
    sha.update(out.data(), out.size());
    hash = sha.hex();
    return best;
}
}  // namespace

static int run_bench(int argc, char** argv) {
    namespace fs = std::filesystem;
    std::string dir = CITYFORGE_SHARED_DATA "/laz_corpus";
    int repeat = 3;
    bool points_path = false, kernel = false;
    int threads = 0;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--points") points_path = true;
        else if (a == "--kernel") kernel = true;
        else if (a == "--threads" && i + 1 < argc) threads = std::max(1, static_cast<int>(cityforge::bench::parse_number(argv[++i], "--threads")));
        else if (a == "--repeat" && i + 1 < argc) repeat = std::max(1, static_cast<int>(cityforge::bench::parse_number(argv[++i], "--repeat")));
        else dir = a;
    }
    std::unique_ptr<tbb::global_control> cap;
    if (threads > 0) cap = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
    nlohmann::json oracle;
    if (std::ifstream f(dir + "/oracle.json"); f) oracle = nlohmann::json::parse(f);
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir))
        if (e.path().extension() == ".laz") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    double total_s = 0.0, total_points_s = 0.0, total_cpu = 0.0, total_sha_cpu = 0.0, total_kernel = 0.0;
    uint64_t total_points = 0, kernel_points = 0;
    int mismatches = 0;
    std::printf("%-55s %10s %9s %8s %9s  %s\n", "file", "points", "wall ms", "Mpts/s", "Mpts/CPUs", "oracle");
    for (const fs::path& p : files) {
        const std::string name = p.filename().string();
        try {
            double best = 1e30, cpu = 0.0, sha_cpu = 0.0;
            std::string hash;
            uint64_t points = 0;
            // The records go straight into one buffer sized once (as a
            // caller that reuses its buffer): the figure is the decoder's,
            // not zero-filling, page faults or copies of the harness.
            std::vector<char> all;
            {
                const cityforge::LasReader probe(p.string());
                all.resize(static_cast<std::size_t>(probe.header().point_count) * probe.header().point_record_length);
            }
            for (int r = 0; r < repeat; ++r) {
                // Decode only; hashed afterwards so that SHA-256 is not part of
                // the decode figure.
                const double cpu0 = cityforge::process_cpu_seconds();
                const auto t0 = std::chrono::steady_clock::now();
                cityforge::LasReader reader(p.string());
                const std::size_t rl = static_cast<std::size_t>(reader.header().point_record_length);
                points = 0;
                while (std::size_t n = reader.read_records(all.data() + points * rl,
                                                           std::min<std::size_t>(1u << 20, all.size() / rl - points))) {
                    points += n;
                }
                if (reader.points_remaining() != 0) throw cityforge::Error(p.string(), "more points than the header announces");
                const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
                const double cpu1 = cityforge::process_cpu_seconds();
                cpu += cpu1 - cpu0;
                best = std::min(best, s);
                cityforge::Sha256 sha;
                sha.update(all.data(), static_cast<std::size_t>(points) * rl);
                hash = sha.hex();
                sha_cpu += cityforge::process_cpu_seconds() - cpu1;
            }
            cpu /= repeat;
            sha_cpu /= repeat;
            total_cpu += cpu;
            total_sha_cpu += sha_cpu;
            double best_points = 0.0;
            if (points_path) {
                best_points = 1e30;
                for (int r = 0; r < repeat; ++r) {
                    const auto t0 = std::chrono::steady_clock::now();
                    cityforge::LasReader reader(p.string());
                    cityforge::PointCloud cloud;
                    while (true) {
                        cloud.clear();
                        if (reader.read_chunk(cloud, 1u << 20) == 0) break;
                    }
                    best_points = std::min(best_points, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
                }
            }
            total_points_s += best_points;
            std::string status = "no oracle";
            const nlohmann::json entries = oracle.is_array() ? oracle
                                           : oracle.is_object() ? oracle.value("files", nlohmann::json::array())
                                                                : nlohmann::json::array();
            for (const auto& entry : entries) {
                if (entry.value("file", "") != name) continue;
                if (!entry.value("decoded", true) || !entry.contains("points_sha256")) break;
                const bool ok = entry["points_sha256"].get<std::string>() == hash;
                status = ok ? "match" : "MISMATCH";
                if (!ok) ++mismatches;
            }
            std::string kernel_note;
            if (kernel && points > 0) {
                std::string khash;
                const double ks = kernel_seconds(p.string(), repeat, khash);
                if (ks > 0) {
                    total_kernel += ks;
                    kernel_points += points;
                    char buf[96];
                    std::snprintf(buf, sizeof buf, "  kernel %.2f Mpts/CPUs%s", static_cast<double>(points) / ks / 1e6,
                                  khash == hash ? "" : " (KERNEL HASH DIFFERS)");
                    kernel_note = buf;
                    if (khash != hash) ++mismatches;
                }
            }
            std::printf("%-55s %10llu %9.2f %8.2f %9.2f  %s%s\n", name.c_str(), static_cast<unsigned long long>(points), best * 1e3,
                        best > 0 ? static_cast<double>(points) / best / 1e6 : 0.0,
                        cpu > 0 ? static_cast<double>(points) / cpu / 1e6 : 0.0, status.c_str(), kernel_note.c_str());
            total_s += best;
            total_points += points;
        } catch (const cityforge::Error& e) {
            std::printf("%-55s refused: %s\n", name.c_str(), e.what());
        }
    }
    std::printf("TOTAL %llu points in %.3f s wall: %.2f M points/s (best of %d; wall time depends on the machine's load)\n",
                static_cast<unsigned long long>(total_points), total_s,
                total_s > 0 ? static_cast<double>(total_points) / total_s / 1e6 : 0.0, repeat);
    std::printf("DECODE CPU (user+system, all threads, SHA-256 excluded): %.3f s per pass = %.2f M points per CPU-second\n", total_cpu,
                total_cpu > 0 ? static_cast<double>(total_points) / total_cpu / 1e6 : 0.0);
    std::printf("DECODE+SHA-256 CPU: %.3f s per pass = %.2f M points per CPU-second (SHA-256 alone %.3f s)\n",
                total_cpu + total_sha_cpu,
                total_cpu + total_sha_cpu > 0 ? static_cast<double>(total_points) / (total_cpu + total_sha_cpu) / 1e6 : 0.0,
                total_sha_cpu);
    if (kernel)
        std::printf("KERNEL (one thread, chunks in memory, best of %d): %llu points in %.3f CPU-s = %.2f M points per CPU-second\n", repeat,
                    static_cast<unsigned long long>(kernel_points), total_kernel,
                    total_kernel > 0 ? static_cast<double>(kernel_points) / total_kernel / 1e6 : 0.0);
    if (points_path)
        std::printf("TOTAL PointCloud path: %.3f s: %.2f M points/s\n", total_points_s,
                    total_points_s > 0 ? static_cast<double>(total_points) / total_points_s / 1e6 : 0.0);
    return mismatches == 0 ? 0 : 1;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_laz", "bench_laz [CORPUS_DIR] [--repeat N] [--points] [--kernel] [--threads N]", run_bench);
}
