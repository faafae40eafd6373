// Reading uncompressed LAS records: the parallel blocks (pread at each
// block's offset) against an independent decoding of the raw bytes, for any
// chunking and thread count, and a file cut short after it was opened.
#include <catch2/catch.hpp>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <tbb/global_control.h>

#include "same_cloud.hpp"
#include "cloud/las.hpp"
#include "core/error.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;
using cityforge::test::slurp;

namespace {
template <class T>
T at(const std::string& bytes, std::size_t offset) {
    T v;
    std::memcpy(&v, bytes.data() + offset, sizeof v);
    return v;
}

// The cloud decoded from the file's bytes by the LAS 1.2 layout alone
// (formats 1 and 3: GPS time at 20, RGB at 28), not by the reader.
PointCloud decode_by_hand(const std::string& bytes) {
    const auto offset_to_points = at<uint32_t>(bytes, 96);
    const int format = static_cast<uint8_t>(bytes[104]);
    const std::size_t rl = at<uint16_t>(bytes, 105);
    const std::size_t n = at<uint32_t>(bytes, 107);
    double scale[3], offset[3];
    for (int k = 0; k < 3; ++k) scale[k] = at<double>(bytes, 131 + 8 * k), offset[k] = at<double>(bytes, 155 + 8 * k);
    PointCloud c;
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t p = offset_to_points + i * rl;
        c.x.push_back(at<int32_t>(bytes, p) * scale[0] + offset[0]);
        c.y.push_back(at<int32_t>(bytes, p + 4) * scale[1] + offset[1]);
        c.z.push_back(at<int32_t>(bytes, p + 8) * scale[2] + offset[2]);
        c.intensity.push_back(at<uint16_t>(bytes, p + 12));
        const auto bits = static_cast<uint8_t>(bytes[p + 14]);
        c.return_number.push_back(bits & 0x07), c.number_of_returns.push_back((bits >> 3) & 0x07);
        c.classification.push_back(static_cast<uint8_t>(bytes[p + 15]) & 0x1F);
        c.gps_time.push_back(at<double>(bytes, p + 20));
        if (format == 3) c.red.push_back(at<uint16_t>(bytes, p + 28)), c.green.push_back(at<uint16_t>(bytes, p + 30)), c.blue.push_back(at<uint16_t>(bytes, p + 32));
    }
    return c;
}

PointCloud read_in_chunks(const std::string& path, std::size_t chunk) {
    LasReader reader(path);
    PointCloud c;
    while (reader.read_chunk(c, chunk) > 0) {
    }
    return c;
}
}  // namespace

TEST_CASE("LAS records decoded in parallel blocks equal the bytes decoded by hand - any chunking and thread count", "[cloud][las][read]") {
    // Autzen: format 3, 34-byte records, 110,000 points (several blocks of
    // the reader's 256 kB); Delft: format 1, 675,339 points.
    for (const char* name : {"autzen_oregon/autzen_trim.las", "delft_ahn3_bgt_west/ahn3_delft_west.las"}) {
        const std::string path = shared_data(name);
        INFO(name);
        const PointCloud expected = decode_by_hand(slurp(path));
        REQUIRE(expected.size() > 100000);
        cityforge::test::check_same_cloud(read_las(path), expected);
        for (std::size_t chunk : {std::size_t(1) << 20, std::size_t(7777), std::size_t(100001)}) cityforge::test::check_same_cloud(read_in_chunks(path, chunk), expected);
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        cityforge::test::check_same_cloud(read_las(path), expected);
    }
}

TEST_CASE("A LAS file cut short after it was opened gives the one-line truncated error naming it", "[cloud][las][read][errors]") {
    ScratchDir dir("las_cut_late");
    const std::string bytes = slurp(shared_data("autzen_oregon/autzen_trim.las"));
    const std::size_t offset_to_points = at<uint32_t>(bytes, 96), rl = at<uint16_t>(bytes, 105);
    const std::string p = dir / "shrinks.las";
    for (const std::size_t keep_points : {std::size_t(0), std::size_t(5000), std::size_t(60000)}) {
        INFO(keep_points);
        std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
        LasReader reader(p);
        PointCloud c;
        REQUIRE(reader.read_chunk(c, 1000) == 1000);
        // Cut inside a record, after the open checked the size.
        std::filesystem::resize_file(p, offset_to_points + keep_points * rl + rl / 2);
        CHECK_THROWS_WITH(
            [&] {
                while (reader.read_chunk(c, 1u << 20) > 0) {
                }
            }(),
            Catch::Contains("shrinks.las") && Catch::Contains("truncated point records"));
    }
    // The raw records take the same path.
    std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
    LasReader reader(p);
    std::filesystem::resize_file(p, offset_to_points + 10 * rl);
    std::vector<char> records;
    CHECK_THROWS_WITH(reader.read_records(records, 100), Catch::Contains("shrinks.las") && Catch::Contains("truncated point records"));
}
