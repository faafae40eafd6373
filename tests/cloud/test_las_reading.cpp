// Reading uncompressed LAS records: the parallel blocks (pread at each
// block's offset) against an independent decoding of the raw bytes, for any
// chunking and thread count, and a file cut short after it was opened.
#include <array>
#include <catch2/catch.hpp>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <tbb/global_control.h>
#include <vector>

#include "same_cloud.hpp"
#include "cloud/cloud_reader.hpp"
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

TEST_CASE("Window reads of an uncompressed LAS keep exactly the points of the half-open box, in file order - parts appended to one cloud", "[cloud][las][read][window]") {
    for (const char* name : {"autzen_oregon/autzen_trim.las", "delft_ahn3_bgt_west/ahn3_delft_west.las"}) {
        const std::string path = shared_data(name);
        INFO(name);
        const PointCloud all = read_las(path);
        REQUIRE(all.size() > 100000);
        const auto crop = [&](const std::array<double, 4>& b, PointCloud& into) {
            for (std::size_t i = 0; i < all.size(); ++i)
                if (all.x[i] >= b[0] && all.x[i] < b[2] && all.y[i] >= b[1] && all.y[i] < b[3]) into.append(all, i);
        };
        const LasHeader h = LasReader(path).header();
        // Boxes ending exactly on points (the half-open edge), a corner, one
        // missing the file, one holding all of it (the header's bounds inside).
        const double mx = 0.5 * (h.min[0] + h.max[0]), my = 0.5 * (h.min[1] + h.max[1]);
        const std::vector<std::array<double, 4>> boxes = {{h.min[0], h.min[1], all.x[all.size() / 2], all.y[all.size() / 3]},
                                                          {mx, my, h.max[0], h.max[1]},
                                                          {all.x[10], all.y[10], all.x[10] + 30, all.y[10] + 30},
                                                          {h.max[0] + 10, h.max[1] + 10, h.max[0] + 20, h.max[1] + 20},
                                                          {h.min[0] - 1, h.min[1] - 1, h.max[0] + 1, h.max[1] + 1}};
        PointCloud parts, expected_parts;
        for (const auto& b : boxes) {
            PointCloud expected;
            crop(b, expected);
            cityforge::test::check_same_cloud(read_point_cloud_in(path, b[0], b[1], b[2], b[3]), expected);
            append_point_cloud_in(path, b[0], b[1], b[2], b[3], parts);
            crop(b, expected_parts);
        }
        cityforge::test::check_same_cloud(parts, expected_parts);
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        PointCloud expected;
        crop(boxes[0], expected);
        cityforge::test::check_same_cloud(read_point_cloud_in(path, boxes[0][0], boxes[0][1], boxes[0][2], boxes[0][3]), expected);
    }
}

TEST_CASE("A window part that fails or carries other attributes leaves the cloud it was appended to as it was", "[cloud][read][window][errors]") {
    ScratchDir dir("window_part_fails");
    const std::string las = shared_data("autzen_oregon/autzen_trim.las");
    const PointCloud all = read_las(las);  // format 3: colour and GPS time
    const std::array<double, 4> box{all.x[10] - 50, all.y[10] - 50, all.x[10] + 50, all.y[10] + 50};
    PointCloud parts;
    append_point_cloud_in(las, box[0], box[1], box[2], box[3], parts);
    REQUIRE(parts.size() > 100);
    REQUIRE(parts.has_color());
    REQUIRE(parts.has_gps_time());
    const PointCloud before = parts;
    // A text file (no colour, no GPS time) after a part with both: refused,
    // not arrays of different lengths.
    const std::string xyz = dir / "plain.xyz";
    std::ofstream(xyz) << std::fixed << all.x[10] << " " << all.y[10] << " " << all.z[10] << "\n";
    try {
        append_point_cloud_in(xyz, box[0], box[1], box[2], box[3], parts);
        FAIL("a part without colour after parts with it was accepted");
    } catch (const cityforge::Error& e) {
        CHECK_THAT(e.what(), Catch::Contains("plain.xyz") && Catch::Contains("other attributes"));
    }
    cityforge::test::check_same_cloud(parts, before);
    // A file that fails after more than one chunk (2^20 points) was read into
    // the cloud: its points are taken off again, attributes too.
    const std::string bad = dir / "bad_tail.xyz";
    {
        std::ofstream out(bad);
        for (int i = 0; i < (1 << 20) + 5000; ++i) out << "1 2 3\n";
        out << "garbage here\n";
    }
    PointCloud plain;
    append_point_cloud_in(xyz, box[0], box[1], box[2], box[3], plain);
    REQUIRE(plain.size() == 1);
    const PointCloud plain_before = plain;
    CHECK_THROWS_WITH(append_point_cloud_in(bad, 0, 0, 10, 10, plain), Catch::Contains("bad_tail.xyz"));
    cityforge::test::check_same_cloud(plain, plain_before);
    CHECK_THROWS_WITH(append_point_cloud_in(bad, 0, 0, 10, 10, parts), Catch::Contains("bad_tail.xyz"));
    cityforge::test::check_same_cloud(parts, before);
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
        const PointCloud first = c;
        // Cut inside a record, after the open checked the size.
        std::filesystem::resize_file(p, offset_to_points + keep_points * rl + rl / 2);
        CHECK_THROWS_WITH(
            [&] {
                while (reader.read_chunk(c, 1u << 20) > 0) {
                }
            }(),
            Catch::Contains("shrinks.las") && Catch::Contains("truncated point records"));
        // The failed chunk is taken off again: the caller's cloud holds what
        // it held before that call, every attribute array of the same length.
        cityforge::test::check_same_cloud(c, first);
    }
    // The raw records take the same path.
    std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
    LasReader reader(p);
    std::filesystem::resize_file(p, offset_to_points + 10 * rl);
    std::vector<char> records;
    CHECK_THROWS_WITH(reader.read_records(records, 100), Catch::Contains("shrinks.las") && Catch::Contains("truncated point records"));
}

TEST_CASE("A LAS file replaced under its path after it was opened is read whole from the file that was opened - LAS and LAZ", "[cloud][las][read]") {
    // The header, VLRs and records come from one open descriptor: renaming
    // another file onto the path mixes nothing in.
    ScratchDir dir("las_replaced");
    for (const char* name : {"autzen_oregon/autzen_trim.las", "laz_corpus/autzen_trim.laz"}) {
        INFO(name);
        const std::string src = shared_data(name);
        const PointCloud expected = read_las(src);
        const std::string p = dir / (std::string("opened") + std::filesystem::path(name).extension().string());
        std::filesystem::copy_file(src, p, std::filesystem::copy_options::overwrite_existing);
        LasReader reader(p);
        const std::string other = dir / "other.las";
        std::filesystem::copy_file(shared_data("delft_ahn3_bgt_west/ahn3_delft_west.las"), other, std::filesystem::copy_options::overwrite_existing);
        std::filesystem::rename(other, p);
        PointCloud c;
        while (reader.read_chunk(c, 50000) > 0) {
        }
        cityforge::test::check_same_cloud(c, expected);
    }
}

TEST_CASE("LAS 1.4 format 7 with 3 extra bytes per record and an EVLR after the points: records, CRS from the EVLR, any chunking", "[cloud][las][read]") {
    // Built from our writer's file by hand: every record gets 3 extra bytes
    // (the record length says 39), and an extended VLR holding a WKT follows
    // the points (the header's EVLR offset and count point at it). 20,000
    // points: several of the reader's 256 kB blocks, and a block boundary
    // inside no record.
    ScratchDir dir("las14_evlr");
    PointCloud c;
    for (int i = 0; i < 20000; ++i) {
        c.x.push_back(500000.0 + 0.01 * i), c.y.push_back(4400000.0 + 0.37 * (i % 977)), c.z.push_back(10.0 + 0.001 * (i % 3001));
        c.intensity.push_back(static_cast<uint16_t>(i * 7)), c.classification.push_back(static_cast<uint8_t>(1 + i % 6));
        c.return_number.push_back(static_cast<uint8_t>(1 + i % 3)), c.number_of_returns.push_back(3);
        c.gps_time.push_back(1000.0 + i * 0.5);
        c.red.push_back(static_cast<uint16_t>(i)), c.green.push_back(static_cast<uint16_t>(2 * i)), c.blue.push_back(static_cast<uint16_t>(3 * i));
    }
    {
        LasWriter w(dir / "plain.las", {0.001, 0.001, 0.001}, {500000, 4400000, 0}, "");
        w.write(c);
        w.close();
    }
    const PointCloud expected = read_las(dir / "plain.las");
    REQUIRE(expected.size() == 20000);
    const std::string plain = slurp(dir / "plain.las");
    const std::size_t offset_to_points = at<uint32_t>(plain, 96), rl = at<uint16_t>(plain, 105);
    REQUIRE(static_cast<uint8_t>(plain[104]) == 7);
    REQUIRE(rl == 36);
    std::string b = plain.substr(0, offset_to_points);
    for (std::size_t i = 0; i < 20000; ++i) {
        b += plain.substr(offset_to_points + i * rl, rl);
        b += std::string{'\x11', '\x22', '\x33'};
    }
    const std::string wkt = "PROJCS[\"from the EVLR\"]";
    std::string evlr(60, '\0');
    std::memcpy(evlr.data() + 2, "LASF_Projection", 15);
    const uint16_t record_id = 2112;
    const uint64_t length = wkt.size() + 1;
    std::memcpy(evlr.data() + 18, &record_id, 2);
    std::memcpy(evlr.data() + 20, &length, 8);
    const uint64_t evlr_offset = b.size();
    const uint32_t evlr_count = 1;
    const uint16_t new_rl = 39;
    b += evlr + wkt + '\0';
    std::memcpy(b.data() + 105, &new_rl, 2);
    std::memcpy(b.data() + 235, &evlr_offset, 8);
    std::memcpy(b.data() + 243, &evlr_count, 4);
    const std::string p = dir / "extra_evlr.las";
    std::ofstream(p, std::ios::binary) << b;

    LasHeader h;
    cityforge::test::check_same_cloud(read_las(p, &h), expected);
    CHECK(h.point_record_length == 39);
    CHECK(h.crs.evlr_wkt == "PROJCS[\"from the EVLR\"]");
    for (std::size_t chunk : {std::size_t(6721), std::size_t(1) << 20, std::size_t(3)}) cityforge::test::check_same_cloud(read_in_chunks(p, chunk), expected);
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    cityforge::test::check_same_cloud(read_las(p), expected);
    // The raw records keep the extra bytes.
    LasReader reader(p);
    std::vector<char> records;
    REQUIRE(reader.read_records(records, 2) == 2);
    CHECK(records.size() == 78);
    CHECK(records[36] == '\x11');
    CHECK(records[77] == '\x33');
}

TEST_CASE("A chunk that fails to read leaves a cloud without GPS time or colour without them - points and attributes as before", "[cloud][las][read][errors]") {
    // The caller's cloud holds 5 points with neither GPS time nor colour; the
    // file (Autzen, format 3) has both. The failed chunk must not leave
    // zero-filled GPS and colour arrays behind.
    ScratchDir dir("las_fail_attrs");
    PointCloud c;
    for (int i = 0; i < 5; ++i) {
        c.x.push_back(i), c.y.push_back(2 * i), c.z.push_back(3 * i), c.intensity.push_back(static_cast<uint16_t>(i));
        c.classification.push_back(2), c.return_number.push_back(1), c.number_of_returns.push_back(1);
    }
    const PointCloud before = c;
    const std::string bytes = slurp(shared_data("autzen_oregon/autzen_trim.las"));
    const std::size_t offset_to_points = at<uint32_t>(bytes, 96), rl = at<uint16_t>(bytes, 105);
    const std::string p = dir / "cut.las";
    std::ofstream(p, std::ios::binary) << bytes;
    LasReader reader(p);
    std::filesystem::resize_file(p, offset_to_points + 1000 * rl);
    CHECK_THROWS_WITH(reader.read_chunk(c, 1u << 20), Catch::Contains("cut.las") && Catch::Contains("truncated point records"));
    CHECK_FALSE(c.has_gps_time());
    CHECK_FALSE(c.has_color());
    cityforge::test::check_same_cloud(c, before);
}

TEST_CASE("LAS paths that are no file: a directory, a dangling link, a path through a file - one-line errors naming them", "[cloud][las][read][errors]") {
    ScratchDir dir("las_no_file");
    std::filesystem::create_directories(dir / "folder.las");
    CHECK_THROWS_WITH(read_las(dir / "folder.las"), Catch::Contains("folder.las") && Catch::Contains("is a directory, not a point cloud file"));
    std::filesystem::create_symlink(dir / "gone.las", dir / "link.las");
    CHECK_THROWS_WITH(read_las(dir / "link.las"), Catch::Contains("link.las") && Catch::Contains("file not found"));
    std::ofstream(dir / "plain.las") << "x";
    CHECK_THROWS_WITH(read_las(dir / "plain.las" + "/inner.las"), Catch::Contains("inner.las") && Catch::Contains("file not found"));
    CHECK_THROWS_WITH(read_las(dir / "plain.las"), Catch::Contains("plain.las") && Catch::Contains("not a LAS file"));
}
