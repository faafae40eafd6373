#include <catch2/catch.hpp>
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
}

TEST_CASE("A writer that is not closed leaves no file", "[cloud][las][errors]") {
    ScratchDir dir("las_unclosed");
    {
        LasWriter w(dir / "a.las", {0.01, 0.01, 0.01}, {0, 0, 0}, "");
        w.write(small_cloud());
    }
    CHECK(dir.file_count() == 0);
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
