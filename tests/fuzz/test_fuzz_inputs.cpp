// Mutation fuzzing (AFL-style, deterministic) of the input readers: LAS/LAZ,
// PLY and XYZ through CloudReader, and GeoJSON footprints through
// read_polygon_layer and the heights run. Each input must either be read or
// be refused with cityforge::Error; any other exception fails the test, a
// crash or a sanitizer report kills it (the input being tried is then left
// at the path printed first), a hang trips the watchdog, which copies the
// input next to it and aborts.
//
// Every input that ever crashed or hung is kept in tests/data/fuzz/regressions/
// and replayed first. Seeds: tests/data/fuzz/seeds/ (make_seeds.py) and the
// small LAZ files of tests/data/laz/ and ../shared/data/laz_corpus/.
// Longer runs: CITYFORGE_FUZZ_ITERATIONS=100000 CITYFORGE_FUZZ_SEED=7 build/bin/cityforge_tests "[fuzz]"
#include <catch2/catch.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cctype>
#include <cmath>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <random>
#include <thread>

#include "cloud/cloud_reader.hpp"
#include "cloud/cloud_filters.hpp"
#include "cloud/cloud_rasters.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "io/vector.hpp"
#include "pipeline/heights_run.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace cityforge;

namespace {

const std::string kFuzzData = test::source_dir() + "/tests/data/fuzz";

long env_long(const char* name, long fallback) {
    const char* v = std::getenv(name);
    return v && *v ? std::atol(v) : fallback;
}

std::vector<std::string> files_in(const fs::path& dir, const std::vector<std::string>& exts) {
    std::vector<std::string> out;
    if (!fs::is_directory(dir)) return out;
    for (const auto& e : fs::directory_iterator(dir)) {
        const std::string ext = e.path().extension().string();
        if (e.is_regular_file() && std::find(exts.begin(), exts.end(), ext) != exts.end()) out.push_back(e.path().string());
    }
    std::sort(out.begin(), out.end());
    return out;
}

// AFL-like havoc on bytes, plus token swaps for text formats (numbers become
// nan, inf, 1e308, huge integers; lines are dropped or repeated).
class Mutator {
public:
    explicit Mutator(uint64_t seed) : rng_(seed) {}
    std::string mutate(std::string b, bool text) {
        const int rounds = 1 + static_cast<int>(pick(6));
        for (int r = 0; r < rounds; ++r) {
            if (text && pick(2) == 0) text_op(b);
            else byte_op(b);
        }
        return b;
    }

private:
    uint64_t pick(uint64_t n) { return n == 0 ? 0 : rng_() % n; }
    template <class T>
    void put(std::string& b, T v) {
        if (b.size() < sizeof v) return;
        const std::size_t at = pick(b.size() - sizeof v + 1);
        std::memcpy(b.data() + at, &v, sizeof v);
    }
    void byte_op(std::string& b) {
        if (b.empty()) {
            b.push_back(static_cast<char>(rng_()));
            return;
        }
        static const uint64_t u64[] = {0, 1, 0xFFFFFFFFull, 0x80000000ull, 1ull << 62, ~0ull - 59, ~0ull, 0x7FFFFFFFFFFFFFFFull, 65535, 375};
        static const double f64[] = {1e300, -1e300, 1e308, NAN, INFINITY, -INFINITY, 0.0, -0.0, 1e-300, 5e-324};
        static const uint8_t u8[] = {0, 1, 0x7F, 0x80, 0xFF, 6, 7, 10, 0x87};
        switch (pick(10)) {
            case 0: b[pick(b.size())] ^= static_cast<char>(1u << pick(8)); break;
            case 1: b[pick(b.size())] = static_cast<char>(rng_()); break;
            case 2: b[pick(b.size())] = static_cast<char>(u8[pick(std::size(u8))]); break;
            case 3: put<uint16_t>(b, static_cast<uint16_t>(u64[pick(std::size(u64))])); break;
            case 4: put<uint32_t>(b, static_cast<uint32_t>(u64[pick(std::size(u64))])); break;
            case 5: put<uint64_t>(b, u64[pick(std::size(u64))]); break;
            case 6: put<double>(b, f64[pick(std::size(f64))]); break;
            case 7: b.resize(pick(b.size() + 1)); break;  // truncate
            case 8: {  // duplicate a block
                const std::size_t at = pick(b.size()), len = 1 + pick(std::min<std::size_t>(256, b.size() - at));
                b.insert(pick(b.size() + 1), b.substr(at, len));
                break;
            }
            default: {  // delete a block
                const std::size_t at = pick(b.size()), len = 1 + pick(std::min<std::size_t>(64, b.size() - at));
                b.erase(at, len);
            }
        }
    }
    void text_op(std::string& b) {
        static const char* tokens[] = {"nan", "inf", "-inf", "1e308", "-1e308", "1e300", "0", "-0", "99999999999999999999",
                                       "4294967296", "", "-1", "1e-320", "0x10", "NaN", "18446744073709551615", "\"", "[", "{", ","};
        if (b.empty()) return;
        const std::size_t at = pick(b.size());
        switch (pick(4)) {
            case 0: {  // replace the number (or word) at a random place
                std::size_t s = at, e = at;
                auto word = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '+' || c == '_'; };
                while (s > 0 && word(b[s - 1])) --s;
                while (e < b.size() && word(b[e])) ++e;
                b.replace(s, e - s, tokens[pick(std::size(tokens))]);
                break;
            }
            case 1: {  // drop a line
                const std::size_t s = b.rfind('\n', at), e = b.find('\n', at);
                b.erase(s == std::string::npos ? 0 : s, e == std::string::npos ? std::string::npos : e - (s == std::string::npos ? 0 : s));
                break;
            }
            case 2: {  // repeat a line
                const std::size_t s = b.rfind('\n', at), e = b.find('\n', at);
                if (s != std::string::npos && e != std::string::npos) b.insert(e, b.substr(s, e - s));
                break;
            }
            default: b.insert(at, tokens[pick(std::size(tokens))]);
        }
    }
    std::mt19937_64 rng_;
};

// A hang guard: if one input takes longer than `limit`, the input is copied
// to a file beside it (kept by the scratch folder's parent) and the process aborts.
class Watchdog {
public:
    explicit Watchdog(std::chrono::seconds limit) : limit_(limit), thread_([this] { watch(); }) {}
    ~Watchdog() {
        {
            std::lock_guard<std::mutex> l(m_);
            stop_ = true;
        }
        cv_.notify_all();
        thread_.join();
    }
    void start(const std::string& input) {
        std::lock_guard<std::mutex> l(m_);
        input_ = input;
        since_ = std::chrono::steady_clock::now();
        busy_ = true;
    }
    void done() {
        std::lock_guard<std::mutex> l(m_);
        busy_ = false;
    }

private:
    void watch() {
        std::unique_lock<std::mutex> l(m_);
        while (!stop_) {
            cv_.wait_for(l, std::chrono::seconds(1));
            if (busy_ && std::chrono::steady_clock::now() - since_ > limit_) {
                const std::string kept = fs::temp_directory_path() / ("cityforge_fuzz_hang_" + fs::path(input_).filename().string());
                std::error_code ec;
                fs::copy_file(input_, kept, fs::copy_options::overwrite_existing, ec);
                std::fprintf(stderr, "fuzz: %s hangs (> %lld s); kept as %s\n", input_.c_str(), static_cast<long long>(limit_.count()), kept.c_str());
                std::abort();
            }
        }
    }
    std::chrono::seconds limit_;
    std::mutex m_;
    std::condition_variable cv_;
    std::string input_;
    std::chrono::steady_clock::time_point since_;
    bool busy_ = false, stop_ = false;
    std::thread thread_;
};

struct Target {
    std::string name;
    std::string ext;  ///< the extension the input file gets (readers look at it)
    bool text;
    std::vector<std::string> seeds;
    std::function<void(const std::string&)> run;  ///< reads the file; may throw Error only
};

// Reads the cloud, then lays the rasters' grid over it (the grid caps are part
// of the reader's contract). A small cloud (a few thousand points) then goes
// through the outlier filter and the SMRF ground filter, under the watchdog:
// degenerate shapes (every point on one row, duplicates, a far point) once
// hung the outlier filter's neighbour search.
void read_cloud(const std::string& path) {
    const PointCloud c = read_point_cloud(path);
    grid_over_cloud(c, 2.0);
    if (c.size() > 5000) return;
    const OutlierFilterResult kept = filter_outliers(c, OutlierFilterOptions{});
    GroundFilterOptions g;
    g.trust_classification = false;  // always the SMRF grid
    // The ground grid's caps are tested by the CLI tests; a mutated digit that
    // spreads 40 points over 5 km would only make the fuzzing slow.
    double minx = INFINITY, miny = INFINITY, maxx = -INFINITY, maxy = -INFINITY;
    for (std::size_t i = 0; i < c.size(); ++i)
        minx = std::min(minx, c.x[i]), maxx = std::max(maxx, c.x[i]), miny = std::min(miny, c.y[i]), maxy = std::max(maxy, c.y[i]);
    if ((maxx - minx + 2 * g.cell) * (maxy - miny + 2 * g.cell) > 4e6 * g.cell * g.cell) return;
    classify_ground(c, kept.keep, g);
}

struct Outcome {
    std::size_t read = 0, refused = 0;
};

// Runs one input; returns false (and reports) on anything but success or Error.
bool try_input(const Target& t, const std::string& path, Watchdog& dog, Outcome& o) {
    dog.start(path);
    bool ok = true;
    try {
        t.run(path);
        ++o.read;
    } catch (const Error&) {
        ++o.refused;
    } catch (const std::exception& e) {
        ok = false;
        const std::string kept = fs::temp_directory_path() / ("cityforge_fuzz_failed_" + t.name + t.ext);
        std::error_code ec;
        fs::copy_file(path, kept, fs::copy_options::overwrite_existing, ec);
        FAIL_CHECK(t.name << ": " << path << " (kept as " << kept << ") threw a non-Error exception: " << e.what());
    }
    dog.done();
    return ok;
}

std::vector<Target> targets(const test::ScratchDir& dir) {
    const std::string seeds = kFuzzData + "/seeds";
    auto with_shared = [](std::vector<std::string> v, const std::vector<std::string>& names) {
        for (const std::string& n : names)
            if (fs::exists(n)) v.push_back(n);
        return v;
    };
    // The footprint path: GeoJSON -> polygons -> heights over a small clean cloud -> a GeoJSON written.
    const std::string cloud = seeds + "/f7_wkt_evlr.las", out = dir / "fuzz_heights.geojson";
    auto footprints = [cloud, out](const std::string& path) {
        const PolygonLayer layer = read_polygon_layer(path);
        if (layer.features.size() > 64) return;  // a mutation that repeats features: reading them was the test
        HeightsRunOptions o;
        o.cloud_crs = "EPSG:32650";
        std::error_code ec;
        fs::remove(out, ec);
        run_heights(path, cloud, out, o);
    };
    return {
        {"las", ".las", false,
         with_shared(files_in(seeds, {".las"}), {test::shared_data("laz_corpus/point-time-1.4.las.laz"),
                                                 test::shared_data("laz_corpus/autzen_clip_native.copc.laz"),
                                                 test::shared_data("laz_corpus/test_pdalfail_0643_6319_LA93_IGN69.laz"),
                                                 test::source_dir() + "/tests/data/laz/wavepacket/pf5-1.3.laz",
                                                 test::source_dir() + "/tests/data/laz/wavepacket/pf10-1.4-eb3.laz"}),
         read_cloud},
        {"ply", ".ply", true, files_in(seeds, {".ply"}), read_cloud},
        {"xyz", ".xyz", true, files_in(seeds, {".xyz"}), read_cloud},
        {"geojson", ".geojson", true, files_in(seeds, {".geojson"}), footprints},
    };
}

}  // namespace

TEST_CASE("fuzz regressions: every input that once crashed or hung a reader is read or refused with an Error", "[fuzz][faults]") {
    test::ScratchDir dir("fuzz_regressions");
    const log::Level level = log::level();
    log::set_level(log::Level::quiet);
    Watchdog dog(std::chrono::seconds(60));
    std::size_t replayed = 0;
    for (const Target& t : targets(dir)) {
        Outcome o;
        for (const std::string& f : files_in(kFuzzData + "/regressions/" + t.name, {t.ext, ".laz"})) {
            INFO(f);
            CHECK(try_input(t, f, dog, o));
            ++replayed;
        }
    }
    log::set_level(level);
    CHECK(replayed >= 10);  // the folder exists and holds the known cases
}

TEST_CASE("fuzz: mutated LAS/LAZ, PLY, XYZ and GeoJSON inputs are read or refused with an Error, never a crash or hang", "[fuzz][faults]") {
    test::ScratchDir dir("fuzz");
    const long iterations = env_long("CITYFORGE_FUZZ_ITERATIONS", 600);
    const auto seed = static_cast<uint64_t>(env_long("CITYFORGE_FUZZ_SEED", 15));
    const log::Level level = log::level();
    log::set_level(log::Level::quiet);
    Watchdog dog(std::chrono::seconds(60));
    for (const Target& t : targets(dir)) {
        REQUIRE(!t.seeds.empty());
        std::vector<std::string> seeds;
        for (const std::string& s : t.seeds) seeds.push_back(test::slurp(s));
        Mutator m(seed * 1000003u + std::hash<std::string>{}(t.name));
        const std::string input = dir / ("input" + t.ext);
        std::fprintf(stderr, "fuzz %s: %ld inputs from %zu seeds; after a crash the input is %s\n", t.name.c_str(), iterations, seeds.size(),
                     input.c_str());
        Outcome o;
        for (const std::string& s : t.seeds) {  // every seed reads: mutations start from valid files
            INFO("seed " << s);
            REQUIRE_NOTHROW(t.run(s));
        }
        bool ok = true;
        for (long i = 0; i < iterations && ok; ++i) {
            {
                std::ofstream f(input, std::ios::binary | std::ios::trunc);
                const std::string b = m.mutate(seeds[static_cast<std::size_t>(i) % seeds.size()], t.text);
                f.write(b.data(), static_cast<std::streamsize>(b.size()));
            }
            ok = try_input(t, input, dog, o);
        }
        std::fprintf(stderr, "fuzz %s: %zu read, %zu refused\n", t.name.c_str(), o.read, o.refused);
        CHECK(o.refused > 0);  // the mutations do reach the checks
    }
    log::set_level(level);
}
