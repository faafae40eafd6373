#include <catch2/catch.hpp>
#include <iomanip>
#include <cmath>
#include <cstring>
#include <fstream>

#include "cloud/las.hpp"
#include "core/error.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;
using cityforge::test::slurp;

namespace {
PointCloud small_cloud() {
    PointCloud c;
    for (int i = 0; i < 1000; ++i) {
        c.x.push_back(500000.0 + i * 0.137);
        c.y.push_back(4400000.0 + i * 0.071);
        c.z.push_back(30.0 + (i % 17) * 0.5);
        c.intensity.push_back(static_cast<uint16_t>(i));
        c.classification.push_back(static_cast<uint8_t>(i % 3 == 0 ? 2 : 6));
        c.return_number.push_back(1);
        c.number_of_returns.push_back(static_cast<uint8_t>(1 + i % 2));
        c.gps_time.push_back(i * 0.5);
        c.red.push_back(static_cast<uint16_t>(i * 3)), c.green.push_back(7), c.blue.push_back(65535);
    }
    return c;
}
void patch(const std::string& path, std::size_t offset, const void* data, std::size_t n) {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>(offset));
    f.write(static_cast<const char*>(data), static_cast<std::streamsize>(n));
}
}  // namespace

TEST_CASE("LAS 1.4 format 7 round trip keeps coordinates - attributes and CRS", "[cloud][las]") {
    ScratchDir dir("las_rt");
    const PointCloud c = small_cloud();
    {
        LasWriter w(dir / "a.las", {0.001, 0.001, 0.001}, {500000, 4400000, 0}, "PROJCS[\"dummy\"]");
        w.write(c);
        w.close();
    }
    LasHeader h;
    const PointCloud r = read_las(dir / "a.las", &h);
    CHECK(h.version_minor == 4);
    CHECK(h.point_format == 7);
    CHECK(h.point_count == 1000);
    CHECK(h.crs.wkt == "PROJCS[\"dummy\"]");
    REQUIRE(r.size() == 1000);
    for (std::size_t i = 0; i < r.size(); ++i) {
        REQUIRE(r.x[i] == Approx(c.x[i]).margin(0.0005));
        REQUIRE(r.z[i] == Approx(c.z[i]).margin(0.0005));
        REQUIRE(r.classification[i] == c.classification[i]);
        REQUIRE(r.number_of_returns[i] == c.number_of_returns[i]);
        REQUIRE(r.red[i] == c.red[i]);
        REQUIRE(r.gps_time[i] == c.gps_time[i]);
    }
    CHECK(h.min[0] == Approx(500000.0));
    CHECK(h.max[2] == Approx(38.0));
    // Format 7 with a WKT CRS keeps no legacy compatibility: the legacy
    // counts (point count at byte 107, counts by return at 111..130) must be
    // zero (LAS 1.4 R15); the 64-bit count at 247 holds the points.
    const std::string bytes = slurp(dir / "a.las");
    REQUIRE(bytes.size() > 255);
    uint32_t legacy[6];
    std::memcpy(legacy, bytes.data() + 107, sizeof legacy);
    for (uint32_t v : legacy) CHECK(v == 0);
    uint64_t count = 0;
    std::memcpy(&count, bytes.data() + 247, 8);
    CHECK(count == 1000);
    // The WKT bit of the global encoding is set for format 7, with a CRS or
    // without (LAS 1.4 R15: formats 6-10 with the bit clear are an error).
    CHECK((static_cast<uint8_t>(bytes[6]) & 0x10) != 0);
    {
        LasWriter w(dir / "none.las", {0.001, 0.001, 0.001}, {500000, 4400000, 0}, "");
        w.write(c);
        w.close();
    }
    const std::string none = slurp(dir / "none.las");
    REQUIRE(none.size() > 6);
    CHECK((static_cast<uint8_t>(none[6]) & 0x10) != 0);
    LasHeader hn;
    CHECK(read_las(dir / "none.las", &hn).size() == 1000);
    CHECK(hn.crs.wkt.empty());
}

TEST_CASE("A writer that is not closed leaves no file", "[cloud][las][errors]") {
    ScratchDir dir("las_unclosed");
    {
        LasWriter w(dir / "a.las", {0.01, 0.01, 0.01}, {0, 0, 0}, "");
        w.write(small_cloud());
    }
    CHECK(dir.file_count() == 0);
}

TEST_CASE("Raw records with return number 0 are written but counted in no return bin", "[cloud][las][errors]") {
    ScratchDir dir("las_return0");
    std::vector<char> records(2 * 36, 0);
    records[14] = 0x10;           // return 0 of 1 (invalid in LAS 1.4)
    records[36 + 14] = 0x11;      // return 1 of 1
    records[36 + 0] = 100;        // x = 100 units
    {
        LasWriter w(dir / "r.las", {0.01, 0.01, 0.01}, {0, 0, 0}, "");
        w.write_records(records.data(), 2);
        w.close();
    }
    std::ifstream in(dir / "r.las", std::ios::binary);
    std::array<uint64_t, 15> by_return{};
    in.seekg(255);
    in.read(reinterpret_cast<char*>(by_return.data()), sizeof(by_return));
    REQUIRE(in);
    CHECK(by_return[0] == 1);
    for (int r = 1; r < 15; ++r) CHECK(by_return[r] == 0);
    LasHeader h;
    const PointCloud c = read_las(dir / "r.las", &h);
    CHECK(c.size() == 2);
    CHECK(h.max[0] == Approx(1.0));
}

TEST_CASE("Real LAS 1.2 files: Autzen (format 3 - RGB - CRS) and AHN3 Delft (format 1 - no CRS)", "[cloud][las][real]") {
    LasHeader h;
    const PointCloud autzen = read_las(shared_data("autzen_oregon/autzen_trim.las"), &h);
    CHECK(h.point_format == 3);
    CHECK(autzen.size() == 110000);
    CHECK(autzen.has_color());
    CHECK_FALSE(h.crs.wkt.empty());
    std::size_t ground = 0, unclassified = 0;
    for (uint8_t c : autzen.classification) ground += c == 2, unclassified += c == 1;
    CHECK(ground == 26107);
    CHECK(unclassified == 83893);
    CHECK(h.min[2] == Approx(406.26).margin(0.01));

    // autzen_thin_srs keeps its WKT in libLAS's "liblas" 2112 record.
    LasReader thin(shared_data("autzen_oregon/autzen_thin_srs.las"));
    CHECK(thin.header().crs.liblas_wkt.find("NAD_1983_HARN_Lambert_Conformal_Conic") != std::string::npos);

    LasReader delft(shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"));
    CHECK(delft.header().point_count == 675339);
    CHECK(delft.header().crs.empty());
    PointCloud chunk;
    std::size_t total = 0;
    while (std::size_t n = delft.read_chunk(chunk, 100000)) {
        total += n;
        chunk.clear();
    }
    CHECK(total == 675339);
}

TEST_CASE("Corrupt LAS input gets a clear error naming the file", "[cloud][las][errors]") {
    ScratchDir dir("las_bad");
    const std::string good = shared_data("autzen_oregon/autzen_thin_srs.las");
    const std::string bytes = slurp(good);
    auto copy = [&](const std::string& name) {
        std::ofstream(dir / name, std::ios::binary) << bytes;
        return dir / name;
    };
    {
        const std::string p = copy("count.las");
        const uint32_t huge = 50000000;
        patch(p, 107, &huge, 4);
        CHECK_THROWS_WITH(read_las(p), Catch::Contains("count.las") && Catch::Contains("truncated"));
    }
    {
        const std::string p = copy("laz.las");
        const uint8_t fmt = 3 | 0x80;
        patch(p, 104, &fmt, 1);
        CHECK_THROWS_WITH(read_las(p), Catch::Contains("laz.las") && Catch::Contains("no LASzip VLR"));
    }
    {
        const std::string p = copy("format.las");
        const uint8_t fmt = 11;
        patch(p, 104, &fmt, 1);
        CHECK_THROWS_WITH(read_las(p), Catch::Contains("format.las") && Catch::Contains("unknown LAS point format 11"));
    }
    {
        const std::string p = copy("scale.las");
        const double zero = 0.0;
        patch(p, 131, &zero, 8);
        CHECK_THROWS_WITH(read_las(p), Catch::Contains("scale.las") && Catch::Contains("scale"));
    }
    {
        const std::string p = dir / "short.las";
        std::ofstream(p, std::ios::binary) << bytes.substr(0, 100);
        CHECK_THROWS_WITH(read_las(p), Catch::Contains("short.las") && Catch::Contains("truncated LAS header"));
    }
    {
        const std::string p = dir / "cut.las";
        std::ofstream(p, std::ios::binary) << bytes.substr(0, bytes.size() - 1000);
        CHECK_THROWS_WITH(read_las(p), Catch::Contains("cut.las") && Catch::Contains("truncated"));
    }
    CHECK_THROWS_WITH(read_las(dir / "none.las"), Catch::Contains("none.las: file not found"));
}

TEST_CASE("LAS text fields: up to the first NUL, padding dropped, an empty record read without touching its pointer", "[cloud][las][errors]") {
    CHECK(las_text(nullptr, 0).empty());  // a zero-length WKT record (UBSan: strnlen on a null pointer before)
    const std::vector<char> empty;
    CHECK(las_text(empty.data(), empty.size()).empty());
    const char user[16] = {'c', 'o', 'p', 'c', '\0', 'x', 'y', 'z', 0, 0, 0, 0, 0, 0, 0, 0};
    CHECK(las_text(user, sizeof user) == "copc");
    const char padded[8] = {'P', 'D', 'A', 'L', ' ', ' ', ' ', ' '};  // no NUL at all: the length bounds the read
    CHECK(las_text(padded, sizeof padded) == "PDAL");
}

TEST_CASE("Splitting a LAS file into overlapping windows gives the bytes of reading it and writing each window's points", "[cloud][las][split]") {
    ScratchDir dir("las_split");
    // Autzen: point format 3 (records re-encoded as format 7); a copy whose
    // header bounds leave out some points (read_chunk's screen drops them).
    const std::string autzen = shared_data("autzen_oregon/autzen_trim.las");
    const std::string cut = dir / "cut.las";
    {
        std::ofstream(cut, std::ios::binary) << slurp(autzen);
        LasReader r(cut);
        const double max_x = (r.header().min[0] + r.header().max[0]) / 2;
        patch(cut, 179, &max_x, 8);
    }
    // Delft: point format 1 (no colour); a synthetic format-7 file.
    const std::string synthetic = dir / "synthetic.las";
    {
        LasWriter w(synthetic, {0.001, 0.001, 0.001}, {500000, 4400000, 0}, "PROJCS[\"dummy\"]");
        w.write(small_cloud());
        w.close();
    }
    for (const std::string& src : {autzen, cut, shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), synthetic}) {
        LasHeader h;
        const PointCloud all = read_las(src, &h);
        const double x0 = h.min[0], y0 = h.min[1], dx = h.max[0] - h.min[0], dy = h.max[1] - h.min[1];
        // A 3 x 2 grid of overlapping windows, one past the data, one
        // covering everything, an empty one, one with a NaN edge, one with
        // an edge on a point.
        std::vector<std::array<double, 4>> windows;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 2; ++j)
                windows.push_back({x0 + dx * (i / 3.0 - 0.05), y0 + dy * (j / 2.0 - 0.1), x0 + dx * ((i + 1) / 3.0 + 0.05), y0 + dy * ((j + 1) / 2.0 + 0.1)});
        windows.push_back({x0 + 2 * dx, y0, x0 + 3 * dx, y0 + dy});
        windows.push_back({x0 - 1, y0 - 1, x0 + dx + 1, y0 + dy + 1});
        windows.push_back({x0 + dx / 2, y0, x0 + dx / 2, y0 + dy});
        windows.push_back({std::nan(""), y0, x0 + dx, y0 + dy});
        windows.push_back({all.x[all.size() / 2], all.y[all.size() / 3], all.x[all.size() / 4] + dx / 10, y0 + dy});
        std::vector<std::string> ours, expected;
        for (std::size_t w = 0; w < windows.size(); ++w) {
            ours.push_back(dir / ("ours_" + std::to_string(w) + ".las"));
            expected.push_back(dir / ("expected_" + std::to_string(w) + ".las"));
            // The reference: every point read, tested against the window, written.
            PointCloud in;
            for (std::size_t i = 0; i < all.size(); ++i)
                if (all.x[i] >= windows[w][0] && all.x[i] < windows[w][2] && all.y[i] >= windows[w][1] && all.y[i] < windows[w][3]) in.append(all, i);
            LasWriter wr(expected.back(), h.scale, h.offset, "WKT");
            wr.write(in);
            wr.close();
        }
        for (std::size_t chunk : {std::size_t(1) << 21, std::size_t(70001), std::size_t(1000)}) {
            const std::vector<uint64_t> counts = split_las_into_windows(src, windows, ours, "WKT", chunk);
            REQUIRE(counts.size() == windows.size());
            uint64_t sum = 0;
            for (std::size_t w = 0; w < windows.size(); ++w) {
                INFO(src << " window " << w << " chunk " << chunk);
                CHECK(slurp(ours[w]) == slurp(expected[w]));
                CHECK(read_las(ours[w]).size() == counts[w]);
                sum += counts[w];
            }
            CHECK(sum > all.size());  // the windows overlap
            if (chunk == (std::size_t(1) << 21)) {
                // And against a reference that shares none of our LAS code
                // (Python's struct module reading the source and each output).
                const std::string windows_json = dir / "windows.json";
                {
                    std::ofstream f(windows_json);
                    f << std::setprecision(17) << "[";
                    for (std::size_t w = 0; w < windows.size(); ++w) {
                        f << (w ? ",[" : "[");
                        for (int k = 0; k < 4; ++k) {
                            if (std::isnan(windows[w][k])) f << (k ? ",NaN" : "NaN");
                            else f << (k ? "," : "") << windows[w][k];
                        }
                        f << "]";
                    }
                    f << "]";
                }
                std::string cmd = "python3 " + test::source_dir() + "/tests/cloud/las_window_oracle.py " + src + " " + windows_json;
                for (const std::string& o : ours) cmd += " " + o;
                const auto oracle = test::run_command(cmd);
                INFO(src << ": " << oracle.out << oracle.err);
                CHECK(oracle.exit_code == 0);
            }
            CHECK(counts[7] == all.size());
            CHECK(counts[6] == 0);
            CHECK(counts[8] == 0);
            CHECK(counts[9] == 0);
        }
    }
    CHECK_THROWS_WITH(split_las_into_windows(autzen, {{0, 0, 1, 1}}, {}, ""), Catch::Contains("1 windows but 0 output files"));
}
