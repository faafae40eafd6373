#include <catch2/catch.hpp>
#include <cstring>
#include <fstream>

#include "cloud/cloud_reader.hpp"
#include "core/error.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

TEST_CASE("PLY ASCII and binary clouds read with colour and classification", "[cloud][ply]") {
    ScratchDir dir("ply");
    {
        std::ofstream f(dir / "a.ply");
        f << "ply\nformat ascii 1.0\ncomment test\nelement vertex 3\nproperty double x\nproperty double y\nproperty float z\n"
             "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar classification\n"
             "property float nx\nproperty float ny\nproperty float nz\nend_header\n"
             "100.5 200.25 3.5 255 0 10 6 0 0 1\n101 201 4 0 255 0 2 0 0 1\n102 202 5 1 2 3 5 0 0 1\n";
    }
    const PointCloud a = read_point_cloud(dir / "a.ply");
    REQUIRE(a.size() == 3);
    CHECK(a.x[0] == 100.5);
    CHECK(a.y[0] == 200.25);
    CHECK(a.z[2] == 5.0);
    CHECK(a.red[0] == 65535);
    CHECK(a.classification[0] == 6);
    CHECK(a.classification[1] == 2);
    {
        std::ofstream f(dir / "b.ply", std::ios::binary);
        f << "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
             "property ushort red\nproperty ushort green\nproperty ushort blue\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
        const float xyz[2][3] = {{1.5f, 2.5f, 3.5f}, {4.0f, 5.0f, 6.0f}};
        const uint16_t rgb[2][3] = {{1000, 2000, 3000}, {4, 5, 6}};
        for (int i = 0; i < 2; ++i) {
            f.write(reinterpret_cast<const char*>(xyz[i]), 12);
            f.write(reinterpret_cast<const char*>(rgb[i]), 6);
        }
    }
    CloudReader br(dir / "b.ply");
    CHECK(br.format() == CloudFormat::ply);
    CHECK(br.announced_points() == 2);
    PointCloud b;
    br.read_chunk(b, 100);
    REQUIRE(b.size() == 2);
    CHECK(b.z[1] == 6.0);
    CHECK(b.red[0] == 1000);  // 16-bit colour kept as is
    {
        std::ofstream f(dir / "short.ply", std::ios::binary);
        f << "ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        f << std::string(100, '\0');
    }
    CHECK_THROWS_WITH(read_point_cloud(dir / "short.ply"), Catch::Contains("short.ply") && Catch::Contains("truncated"));
    {
        std::ofstream f(dir / "noz.ply");
        f << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
    }
    CHECK_THROWS_WITH(read_point_cloud(dir / "noz.ply"), Catch::Contains("noz.ply") && Catch::Contains("lacks x, y or z"));
}

TEST_CASE("XYZ and CSV text clouds - with and without a header", "[cloud][xyz]") {
    ScratchDir dir("xyz");
    { std::ofstream(dir / "a.xyz") << "1 2 3\n4 5 6\n\n7 8 9\n"; }
    const PointCloud a = read_point_cloud(dir / "a.xyz");
    REQUIRE(a.size() == 3);
    CHECK(a.z[2] == 9.0);
    { std::ofstream(dir / "b.csv") << "X,Y,Z,Classification,R,G,B\n10.5,20,30,6,255,128,0\n11,21,31,2,0,0,0\n"; }
    const PointCloud b = read_point_cloud(dir / "b.csv");
    REQUIRE(b.size() == 2);
    CHECK(b.x[0] == 10.5);
    CHECK(b.classification[0] == 6);
    CHECK(b.green[0] == 128 * 257);
    { std::ofstream(dir / "bad.xyz") << "1 2 3\n4 5\n"; }
    CHECK_THROWS_WITH(read_point_cloud(dir / "bad.xyz"), Catch::Contains("bad.xyz") && Catch::Contains("line 2"));
    { std::ofstream(dir / "empty.xyz") << "x y z\n"; }
    CHECK_THROWS_WITH(read_point_cloud(dir / "empty.xyz"), Catch::Contains("empty.xyz: point cloud is empty"));
    { std::ofstream(dir / "cloud.bin") << "??"; }
    CHECK_THROWS_WITH(read_point_cloud(dir / "cloud.bin"), Catch::Contains("cloud.bin") && Catch::Contains("unknown point cloud format"));
}

TEST_CASE("LAS through the common reader keeps its CRS WKT", "[cloud]") {
    CloudReader r(shared_data("autzen_oregon/autzen_trim.las"));
    CHECK(r.format() == CloudFormat::las);
    CHECK(r.announced_points() == 110000);
    CHECK(r.crs_records().wkt.find("Lambert") != std::string::npos);
}
