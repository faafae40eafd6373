// Fuzz driver of the LAZ chunk decoder.
//   libFuzzer:  clang++ -fsanitize=fuzzer,address -DCITYFORGE_LIBFUZZER ... bench/fuzz_laz.cpp (+ cloud, core sources)
//   standalone: build/bin/fuzz_laz [ITERATIONS] [SEED]   (mutates real chunks of the corpus)
// Input layout: byte 0 picks the item set, bytes 1-2 the point count, the rest
// is the chunk. The decoder must return or throw cityforge::Error; anything
// else (crash, sanitizer report, other exception, hang) is a bug.
#include "bench_main.hpp"
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "cloud/las.hpp"
#include "cloud/laz_decoder.hpp"
#include "core/error.hpp"

namespace {
using cityforge::LazInfo;
LazInfo make(uint16_t compressor, std::vector<cityforge::LazItem> items) {
    LazInfo i;
    i.compressor = compressor;
    i.chunk_size = 50000;
    i.items = std::move(items);
    return i;
}
const std::vector<LazInfo>& configs() {
    static const std::vector<LazInfo> c = {
        make(2, {{6, 20, 2}}),
        make(2, {{6, 20, 2}, {7, 8, 2}, {8, 6, 2}}),
        make(2, {{6, 20, 2}, {7, 8, 2}, {8, 6, 2}, {0, 5, 2}}),
        make(3, {{10, 30, 3}}),
        make(3, {{10, 30, 3}, {11, 6, 3}}),
        make(3, {{10, 30, 3}, {12, 8, 3}, {14, 3, 3}}),
        make(3, {{10, 30, 4}, {11, 6, 4}, {14, 4, 4}}),
    };
    return c;
}
int record_length(const LazInfo& info) {
    int n = 0;
    for (const auto& it : info.items) n += it.size;
    return n;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
    if (size < 3) return 0;
    const LazInfo& info = configs()[data[0] % configs().size()];
    const uint64_t count = 1 + (data[1] | (data[2] << 8));
    const int rl = record_length(info);
    std::vector<char> out(static_cast<std::size_t>(count) * rl);
    try {
        cityforge::decode_laz_chunk(info, rl, data + 3, size - 3, count, out.data(), "fuzz", 0);
    } catch (const cityforge::Error&) {
    }
    return 0;
}

#ifndef CITYFORGE_LIBFUZZER
// Seeds: the first chunk of real files with a matching item set.
static int run_bench(int argc, char** argv) {
    const long iterations = argc > 1 ? static_cast<long>(cityforge::bench::parse_number(argv[1], "ITERATIONS")) : 20000;
    std::mt19937 rng(argc > 2 ? static_cast<unsigned>(cityforge::bench::parse_number(argv[2], "SEED")) : 18u);
    const std::pair<const char*, int> seeds_src[] = {{"point10.las.laz", 0}, {"point-color-time.las.laz", 1}, {"lone-star.copc.laz", 3},
                                                     {"Semis_2022_0906_6665_LA93_IGN69_ok.laz", 4}, {"crop_duplicate.laz", -1}};
    std::vector<std::vector<uint8_t>> seeds;
    for (const auto& [name, cfg] : seeds_src) {
        const std::string path = std::string(CITYFORGE_SHARED_DATA) + "/laz_corpus/" + name;
        try {
            cityforge::LasReader reader(path);
            const auto& chunks = reader.laz_source()->chunks();
            if (chunks.empty() || cfg < 0) continue;
            std::FILE* f = std::fopen(path.c_str(), "rb");
            std::vector<uint8_t> chunk(static_cast<std::size_t>(chunks[0].bytes) + 3);
            std::fseek(f, static_cast<long>(chunks[0].offset), SEEK_SET);
            const std::size_t got = std::fread(chunk.data() + 3, 1, chunk.size() - 3, f);
            std::fclose(f);
            chunk.resize(got + 3);
            const auto n = static_cast<uint32_t>(std::min<uint64_t>(chunks[0].point_count, 65536) - 1);
            chunk[0] = static_cast<uint8_t>(cfg), chunk[1] = static_cast<uint8_t>(n & 0xFF), chunk[2] = static_cast<uint8_t>(n >> 8);
            seeds.push_back(std::move(chunk));
        } catch (const cityforge::Error& e) {
            std::fprintf(stderr, "skipping seed: %s\n", e.what());
        }
    }
    if (seeds.empty()) return 1;
    for (long i = 0; i < iterations; ++i) {
        std::vector<uint8_t> b = seeds[rng() % seeds.size()];
        const int flips = 1 + static_cast<int>(rng() % 16);
        for (int f = 0; f < flips; ++f) b[3 + rng() % (b.size() - 3)] = static_cast<uint8_t>(rng());
        if (rng() % 4 == 0) b.resize(3 + rng() % (b.size() - 3));
        if (rng() % 8 == 0) b[0] = static_cast<uint8_t>(rng());
        LLVMFuzzerTestOneInput(b.data(), b.size());
    }
    std::printf("fuzz_laz: %ld inputs, no crash\n", iterations);
    return 0;
}
#endif

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "fuzz_laz", "fuzz_laz [ITERATIONS] [SEED]", run_bench);
}
