// Corrupt and hostile point clouds through the built CLI (issue #15): every
// case gets a one-line error naming the file and a non-zero exit, or (for
// points that cannot be right: NaN/Inf coordinates, records outside the
// header's bounds) a warning naming the file and the count, with results
// identical to those of the clean file. Never a hang, a crash or a silent
// change. The corrupt files are made here from a small synthetic town.
#include <catch2/catch.hpp>
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>

#include "cloud/las.hpp"
#include "cloud/le_bytes.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using test::ScratchDir;

namespace {

std::string read_bytes(const std::string& path) { return test::slurp(path); }
void write_bytes(const std::string& path, const std::string& b) { std::ofstream(path, std::ios::binary) << b; }

template <class T>
void patch(std::string& b, std::size_t at, T v) {
    std::memcpy(b.data() + at, &v, sizeof v);
}

// A hang guard, not a timing: a reader that loops forever fails the test
// (exit 124) instead of holding CI until its limit.
test::CommandResult cli_guarded(const std::string& args) { return test::run_command("timeout 120 " + test::cli() + " " + args); }

// The GeoJSON of a heights run, read back.
std::string heights_of(const SynthResult& s, const std::string& cloud, const std::string& out, std::string* err = nullptr) {
    const auto r = cli_guarded("heights --footprints " + s.truth_path + " --cloud " + cloud + " --out " + out);
    INFO(r.err);
    REQUIRE(r.exit_code == 0);
    if (err) *err = r.err;
    return test::slurp(out);
}

// One line on stderr (the CLI's promise for an error), naming `file`.
void check_one_line_error(const test::CommandResult& r, const std::string& file, const std::string& problem) {
    INFO(r.err);
    CHECK(r.exit_code == 1);
    CHECK(r.err.find(file) != std::string::npos);
    CHECK(r.err.find(problem) != std::string::npos);
    CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
}

// The town's cloud as XYZ text (x y z intensity), every point.
void write_xyz(const std::string& las, const std::string& path, const std::string& extra_lines_at_middle = {}) {
    const PointCloud c = read_las(las);
    std::ofstream out(path);
    out.precision(17);
    for (std::size_t i = 0; i < c.size(); ++i) {
        if (i == c.size() / 2) out << extra_lines_at_middle;
        out << c.x[i] << ' ' << c.y[i] << ' ' << c.z[i] << ' ' << c.intensity[i] << '\n';
    }
}

// Binary little-endian PLY of the town's cloud, x/y/z as `type` ("float" or
// "double"); `values_as_double` writes doubles whatever the header says.
// The first `skip` points are left out, x of the first `nan_points` is NaN.
void write_ply(const std::string& las, const std::string& path, const std::string& type, bool values_as_double,
               std::size_t nan_points = 0, std::size_t skip = 0) {
    const PointCloud c = read_las(las);
    std::ofstream out(path, std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\nelement vertex " << c.size() - skip << "\nproperty " << type << " x\nproperty " << type
        << " y\nproperty " << type << " z\nend_header\n";
    for (std::size_t i = skip; i < c.size(); ++i) {
        double v[3] = {c.x[i], c.y[i], c.z[i]};
        if (i < nan_points) v[0] = std::numeric_limits<double>::quiet_NaN();
        for (double d : v) {
            if (values_as_double || type == "double") {
                out.write(reinterpret_cast<const char*>(&d), 8);
            } else {
                const auto f = static_cast<float>(d);
                out.write(reinterpret_cast<const char*>(&f), 4);
            }
        }
    }
}

}  // namespace

TEST_CASE("corrupt LAS headers: EVLR length wrap, scale 1e300, a point count of 2^62 - one-line errors, no hang", "[faults][corrupt][cli]") {
    ScratchDir dir("corrupt_las_header");
    const SynthResult s = test::make_town(dir, 60, 3, 2.0);
    const std::string good = read_bytes(s.cloud_path);
    REQUIRE(good.size() > 375);
    REQUIRE(good[25] == 4);  // LAS 1.4: EVLR fields present

    SECTION("an EVLR whose length wraps the read position (2^64 - 60), with 0xFFFFFFFF EVLRs") {
        std::string b = good;
        const uint64_t at = b.size();
        std::string evlr(60, '\0');
        std::memcpy(evlr.data() + 2, "LASF_Projection", 15);
        patch<uint16_t>(evlr, 18, 2112);
        patch<uint64_t>(evlr, 20, std::numeric_limits<uint64_t>::max() - 59);
        b += evlr;
        patch<uint64_t>(b, 235, at);
        patch<uint32_t>(b, 243, 0xFFFFFFFFu);
        const std::string bad = dir / "evlr_wrap.las";
        write_bytes(bad, b);
        for (const std::string& cmd : {"info " + bad, "heights --footprints " + s.truth_path + " --cloud " + bad + " --out " + (dir / "h.geojson")}) {
            INFO(cmd);
            check_one_line_error(cli_guarded(cmd), bad, "extended variable length record 0");
        }
        CHECK_FALSE(std::filesystem::exists(dir / "h.geojson"));
    }
    SECTION("a coordinate scale of 1e300 (all-null heights before) and an offset of 1e300") {
        std::string b = good;
        patch<double>(b, 131, 1e300);
        write_bytes(dir / "scale.las", b);
        check_one_line_error(cli_guarded("info " + (dir / "scale.las")), dir / "scale.las", "coordinate scale factor 1e+300");
        check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "scale.las") + " --out " + (dir / "h.geojson")),
                             dir / "scale.las", "outside [1e-12, 1e4]");
        b = good;
        patch<double>(b, 163, 1e300);  // z offset
        write_bytes(dir / "offset.las", b);
        check_one_line_error(cli_guarded("info " + (dir / "offset.las")), dir / "offset.las", "coordinate offset 1e+300");
    }
    SECTION("a point count of 2^62: count x record length wraps 2^64 (info reported 4611686018427387904 points)") {
        std::string b = good;
        patch<uint64_t>(b, 247, uint64_t(1) << 62);
        write_bytes(dir / "count.las", b);
        check_one_line_error(cli_guarded("info " + (dir / "count.las")), dir / "count.las", "header says 4611686018427387904 points but the file holds only");
        // 2^64 / 36 + 1 points of 36 bytes wrap to a few bytes.
        b = good;
        patch<uint64_t>(b, 247, std::numeric_limits<uint64_t>::max() / 36 + 1);
        write_bytes(dir / "count2.las", b);
        check_one_line_error(cli_guarded("info " + (dir / "count2.las")), dir / "count2.las", "(truncated or corrupt)");
    }
}

TEST_CASE("LAS records outside the header's bounds are dropped with a warning, results unchanged - all outside is refused", "[faults][corrupt][cli]") {
    ScratchDir dir("corrupt_las_bounds");
    const SynthResult s = test::make_town(dir, 120, 3, 4.0);
    std::string b = read_bytes(s.cloud_path);
    LasHeader h;
    const PointCloud all = read_las(s.cloud_path, &h);
    REQUIRE(h.point_count > 6000);
    // Garbage records (what a VLR that shifts the records gives): 7 points
    // tens of kilometres away, one below the ground by 3 km.
    std::vector<uint64_t> bad;
    for (uint64_t k = 0; k < 7; ++k) {
        bad.push_back(100 + 797 * k);
        patch<int32_t>(b, h.offset_to_points + bad.back() * h.point_record_length + (k % 3) * 4, int32_t(2'000'000'000 - 12345 * int32_t(k)));
    }
    bad.push_back(6000);
    patch<int32_t>(b, h.offset_to_points + bad.back() * h.point_record_length + 8, int32_t(-300'000'000));
    write_bytes(dir / "garbage.las", b);
    // The same cloud without those 8 points, written cleanly.
    {
        PointCloud kept;
        for (std::size_t i = 0; i < all.size(); ++i)
            if (std::find(bad.begin(), bad.end(), i) == bad.end()) kept.append(all, i);
        LasWriter w(dir / "without.las", h.scale, h.offset, h.crs.wkt);
        w.write(kept);
        w.close();
    }
    const std::string clean = heights_of(s, dir / "without.las", dir / "clean.geojson");
    std::string err;
    const std::string dirty = heights_of(s, dir / "garbage.las", dir / "dirty.geojson", &err);
    INFO(err);
    CHECK(err.find(dir / "garbage.las") != std::string::npos);
    CHECK(err.find("8 of " + std::to_string(h.point_count) + " points lie outside the header's bounds and were dropped") != std::string::npos);
    CHECK(dirty == clean);
    // Header bounds that hold no point: the header or the records are corrupt.
    b = read_bytes(s.cloud_path);
    patch<double>(b, 179, h.max[0] + 1e6);
    patch<double>(b, 187, h.max[0] + 5e5);
    write_bytes(dir / "elsewhere.las", b);
    check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "elsewhere.las") + " --out " + (dir / "e.geojson")),
                         dir / "elsewhere.las", "all " + std::to_string(h.point_count) + " of " + std::to_string(h.point_count) +
                                                    " points lie outside the header's bounds (corrupt header or point records)");
    CHECK_FALSE(std::filesystem::exists(dir / "e.geojson"));
}

TEST_CASE("NaN and Inf coordinates in XYZ and PLY are dropped with a warning naming the file and count, results unchanged", "[faults][corrupt][cli]") {
    ScratchDir dir("corrupt_nan");
    const SynthResult s = test::make_town(dir, 120, 3, 4.0);
    const std::string crs = " --cloud-crs EPSG:32650";
    write_xyz(s.cloud_path, dir / "clean.xyz");
    write_xyz(s.cloud_path, dir / "nan.xyz", "nan nan nan 0\n500010 inf 5 0\n-inf 0 0 0\n");
    const auto clean = cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "clean.xyz") + crs + " --out " + (dir / "c.geojson"));
    const auto nan = cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "nan.xyz") + crs + " --out " + (dir / "n.geojson"));
    INFO(clean.err << nan.err);
    REQUIRE(clean.exit_code == 0);
    REQUIRE(nan.exit_code == 0);
    CHECK(nan.err.find(dir / "nan.xyz") != std::string::npos);
    CHECK(nan.err.find("3 of ") != std::string::npos);
    CHECK(nan.err.find("points have a NaN or infinite coordinate and were dropped") != std::string::npos);
    CHECK(test::slurp(dir / "n.geojson") == test::slurp(dir / "c.geojson"));
    // Binary PLY: NaN x in the first 5 vertices, against the PLY without them.
    write_ply(s.cloud_path, dir / "clean.ply", "double", true, 0, 5);
    write_ply(s.cloud_path, dir / "nan.ply", "double", true, 5);
    const auto pc = cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "clean.ply") + crs + " --out " + (dir / "pc.geojson"));
    const auto pn = cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "nan.ply") + crs + " --out " + (dir / "pn.geojson"));
    INFO(pc.err << pn.err);
    REQUIRE(pc.exit_code == 0);
    REQUIRE(pn.exit_code == 0);
    CHECK(pn.err.find(dir / "nan.ply") != std::string::npos);
    CHECK(pn.err.find("5 of ") != std::string::npos);
    CHECK(test::slurp(dir / "pn.geojson") == test::slurp(dir / "pc.geojson"));
    // Nothing but NaN: refused.
    std::ofstream(dir / "allnan.xyz") << "nan nan nan\nnan 1 2\n";
    check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "allnan.xyz") + crs + " --out " + (dir / "a.geojson")),
                         dir / "allnan.xyz", "all 2 of 2 points have a NaN or infinite coordinate");
}

TEST_CASE("clouds that cannot be read: a directory, a PLY declaring float holding doubles, a truncated PLY", "[faults][corrupt][cli]") {
    ScratchDir dir("corrupt_misc");
    const SynthResult s = test::make_town(dir, 60, 3, 2.0);
    const std::string crs = " --cloud-crs EPSG:32650";
    std::filesystem::create_directories(dir / "x.las");
    check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "x.las") + " --out " + (dir / "h.geojson")),
                         dir / "x.las", "is a directory, not a point cloud file");
    check_one_line_error(cli_guarded("info " + (dir / "x.las")), dir / "x.las", "is a directory, not a raster, point cloud or vector dataset");
    // Declared float, holding doubles: twice the bytes the header announces
    // ("cannot create std::vector larger than max_size()" before).
    write_ply(s.cloud_path, dir / "float_doubles.ply", "float", true);
    check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "float_doubles.ply") + crs + " --out " + (dir / "h.geojson")),
                         dir / "float_doubles.ply", "the declared property types do not match the data");
    // Declared double, holding floats: half the bytes.
    write_ply(s.cloud_path, dir / "double_floats.ply", "float", false);
    std::string b = read_bytes(dir / "double_floats.ply");
    const auto p = b.find("property float");
    REQUIRE(p != std::string::npos);
    for (std::size_t at = b.find("float"); at != std::string::npos && at < b.find("end_header"); at = b.find("float", at)) b.replace(at, 5, "double");
    write_bytes(dir / "double_floats.ply", b);
    check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "double_floats.ply") + crs + " --out " + (dir / "h.geojson")),
                         dir / "double_floats.ply", "(truncated, or property types that do not match the data)");
    CHECK_FALSE(std::filesystem::exists(dir / "h.geojson"));
}

TEST_CASE("grids over scattered or huge coordinates are refused naming the file, before any large allocation", "[faults][corrupt][cli]") {
    ScratchDir dir("corrupt_grids");
    const SynthResult s = test::make_town(dir, 60, 3, 2.0);
    const std::string crs = " --cloud-crs EPSG:32650";
    // A cluster of 30 points 40,000 km away (finite, no header bounds to
    // screen them, too many to be isolated outliers): the ground filter once
    // built a grid of 4e8 cells for minutes.
    std::string far;
    for (int k = 0; k < 30; ++k) far += std::to_string(4e7 + 0.1 * k) + " " + std::to_string(4e7 + 0.07 * (k % 5)) + " 10 0\n";
    write_xyz(s.cloud_path, dir / "far.xyz", far);
    check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "far.xyz") + crs + " --out " + (dir / "h.geojson")),
                         dir / "far.xyz", "grid too large");
    // A sparse but real cloud is not refused: PDAL's 1.2-with-color.las, 1,065 points over about 1 x 1.4 km, at 0.5 m.
    const auto sparse = cli_guarded("cloud rasterize --quiet --cloud " + test::shared_data("laz_corpus/reference_las/1.2-with-color.las") +
                                    " --cloud-crs EPSG:2994 --gsd 0.5 --out " + (dir / "sparse"));
    INFO(sparse.err);
    CHECK(sparse.exit_code == 0);
    CHECK(std::filesystem::exists(dir / "sparse/dsm.tif"));
    // 1e308: the extent itself overflows.
    write_xyz(s.cloud_path, dir / "huge.xyz", "1e308 1e308 0 0\n-1e308 -1e308 0 0\n");
    check_one_line_error(cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "huge.xyz") + crs + " --out " + (dir / "h.geojson")),
                         dir / "huge.xyz", "is not finite");
    CHECK_FALSE(std::filesystem::exists(dir / "h.geojson"));
}

TEST_CASE("degenerate and sparse clouds: every point on one row finishes, two sites 6 km apart work", "[faults][corrupt][cli]") {
    ScratchDir dir("corrupt_sparse");
    const SynthResult s = test::make_town(dir, 120, 3, 4.0);
    const std::string crs = " --cloud-crs EPSG:32650";
    // 400 points sharing one y (garbage records of a corrupt VLR): the outlier
    // filter's neighbour search once ran for ever. Any answer but a hang will do:
    // results, or a one-line error naming the file.
    {
        std::ofstream out(dir / "one_row.xyz");
        out.precision(17);
        for (int k = 0; k < 400; ++k) out << 500000.0 + 0.73 * k << " 4400000 10\n";
    }
    for (const std::string& cmd : {"heights --footprints " + s.truth_path + " --cloud " + (dir / "one_row.xyz") + crs + " --out " + (dir / "row.geojson"),
                                   "cloud rasterize --quiet --cloud " + (dir / "one_row.xyz") + crs + " --gsd 1 --out " + (dir / "row_rasters")}) {
        INFO(cmd);
        const auto r = cli_guarded(cmd);
        INFO(r.err);
        CHECK(r.exit_code != 124);  // timeout 120: a hang
        CHECK((r.exit_code == 0 || r.exit_code == 1));
        if (r.exit_code == 1) {
            CHECK(r.err.find(dir / "one_row.xyz") != std::string::npos);
            CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
        }
    }
    // The town twice, the copy 6 km east and 6 km north: a real sparse cloud
    // (3.6e7 cells of 1 m over its extent) that a cap by point density refused.
    {
        const PointCloud c = read_las(s.cloud_path);
        std::ofstream out(dir / "two_sites.xyz");
        out.precision(17);
        for (double shift : {0.0, 6000.0})
            for (std::size_t i = 0; i < c.size(); ++i) out << c.x[i] + shift << ' ' << c.y[i] + shift << ' ' << c.z[i] << ' ' << c.intensity[i] << '\n';
    }
    const auto h = cli_guarded("heights --footprints " + s.truth_path + " --cloud " + (dir / "two_sites.xyz") + crs + " --out " + (dir / "two.geojson"));
    INFO(h.err);
    CHECK(h.exit_code == 0);
    CHECK(std::filesystem::exists(dir / "two.geojson"));
    const auto r = cli_guarded("cloud rasterize --quiet --cloud " + (dir / "two_sites.xyz") + crs + " --gsd 4 --out " + (dir / "two_rasters"));
    INFO(r.err);
    CHECK(r.exit_code == 0);
    CHECK(std::filesystem::exists(dir / "two_rasters/dsm.tif"));
}

namespace {
// truth.geojson with every coordinate multiplied (1e294: about 1e300), or its
// first footprint replaced by a square of `side` metres.
std::string scaled_footprints(const ScratchDir& dir, const SynthResult& s, const std::string& name, double factor, double huge_side = 0) {
    const std::string out = dir / name;
    const std::string py = "import json\n"
                           "g = json.load(open('" + s.truth_path + "'))\n"
                           "f, side = " + std::to_string(factor) + ", " + std::to_string(huge_side) + "\n"
                           "for k, ft in enumerate(g['features']):\n"
                           "    if side and k == 0:\n"
                           "        x, y = ft['geometry']['coordinates'][0][0]\n"
                           "        ft['geometry'] = {'type': 'Polygon', 'coordinates': [[[x, y], [x + side, y], [x + side, y + side], [x, y + side], [x, y]]]}\n"
                           "    elif not side:\n"
                           "        ft['geometry']['coordinates'] = [[[c[0] * f, c[1] * f] for c in r] for r in ft['geometry']['coordinates']]\n"
                           "json.dump(g, open('" + out + "', 'w'))\n";
    std::ofstream(dir / (name + ".py")) << py;
    REQUIRE(test::run_command("python3 " + (dir / (name + ".py"))).exit_code == 0);
    return out;
}
}  // namespace

TEST_CASE("clear messages naming the file: 1e300 footprints, a 1e9 m footprint, a 65,000 px ortho, a lon/lat grid", "[faults][corrupt][cli]") {
    ScratchDir dir("fault_messages");
    const SynthResult s = test::make_town(dir, 60, 3, 2.0);
    // 1e300 coordinates: refused where they are read (a crash in heights, "bad numeric conversion" in the audit before).
    const std::string e300 = scaled_footprints(dir, s, "e300.geojson", 1e294);
    for (const std::string& cmd : {"heights --footprints " + e300 + " --cloud " + s.cloud_path + " --out " + (dir / "h.geojson"),
                                   "audit footprints --pred " + e300 + " --ref " + s.truth_path + " --out " + (dir / "audit"),
                                   "audit footprints --pred " + s.truth_path + " --ref " + e300 + " --out " + (dir / "audit")}) {
        INFO(cmd);
        check_one_line_error(cli_guarded(cmd), e300 + " feature ", "beyond +-1e9 CRS units: corrupt coordinates?");
    }
    // A footprint 9e8 m wide: that building gets a row saying so, the others their heights.
    const std::string huge = scaled_footprints(dir, s, "huge.geojson", 1.0, 9e8);
    const auto h = cli_guarded("heights --footprints " + huge + " --cloud " + s.cloud_path + " --out " + (dir / "huge_h.geojson"));
    INFO(h.err);
    REQUIRE(h.exit_code == 0);
    const std::string rows = test::slurp(dir / "huge_h.geojson");
    CHECK(rows.find("\"height_quality\": \"footprint_too_large\"") != std::string::npos);
    CHECK(rows.find("\"height_quality\": \"good\"") != std::string::npos);
    // A 65,000 x 65,000 ortho (sparse, 0.5 MB on disk): refused before the read, naming it, exit 3.
    const std::string big = dir / "big.tif";
    REQUIRE(test::run_command("gdal_create -of GTiff -outsize 65000 65000 -bands 3 -ot Byte -a_srs EPSG:32650 -a_ullr 500000 4432500 532500 4400000 "
                              "-co TILED=YES -co SPARSE_OK=TRUE " + big).exit_code == 0);
    const auto oom = test::run_command("bash -c '" + test::address_space_limit(4000000) + "timeout 120 " + test::cli() + " footprints --ortho " + big + " --out " +
                                       (dir / "f.geojson") + "'");
    INFO(oom.err);
    CHECK(oom.exit_code == 3);
    CHECK(oom.err.find(big + ": out of memory: 65000 x 65000 pixels") != std::string::npos);
    CHECK(std::count(oom.err.begin(), oom.err.end(), '\n') == 1);
    CHECK_FALSE(std::filesystem::exists(dir / "f.geojson"));
    // A grid raster in lon/lat ("outlier_limit_m: must be >= 0" once): read on its working grid (UTM), said in a warning.
    REQUIRE(test::run_command("gdalwarp -q -t_srs EPSG:4326 " + s.ortho_path + " " + (dir / "lonlat.tif")).exit_code == 0);
    const auto ll = cli_guarded("cloud rasterize --cloud " + s.cloud_path + " --grid " + (dir / "lonlat.tif") + " --out " + (dir / "ras"));
    INFO(ll.err);
    CHECK(ll.exit_code == 0);
    CHECK(ll.err.find("working grid in EPSG:326") != std::string::npos);
    CHECK(test::run_command("gdalsrsinfo -o epsg " + (dir / "ras/dsm.tif")).out.find("EPSG:326") != std::string::npos);
    // A grid the cloud does not reach: an error naming both, no rasters (not empty ones).
    REQUIRE(test::run_command("gdal_translate -q -a_ullr 900000 5000000 901000 4999000 " + s.ortho_path + " " + (dir / "far.tif")).exit_code == 0);
    check_one_line_error(cli_guarded("cloud rasterize --cloud " + s.cloud_path + " --grid " + (dir / "far.tif") + " --out " + (dir / "ras_far")),
                         s.cloud_path, "does not overlap");
    CHECK_FALSE(std::filesystem::exists(dir / "ras_far/dsm.tif"));
}

TEST_CASE("SMRF on two sites 4.2 km apart in a 1.4 GB address space: split into a grid per site, not out of memory", "[faults][corrupt][cli]") {
    // The whole 4,400 x 4,400-cell grid needs ~794 MB, over half of 1.4 GB;
    // the sites are two groups, each a small grid. The grid is tried whole
    // first only when memory allows it (once, that try refused the cloud).
    ScratchDir dir("two_sites_small_memory");
    {
        std::ofstream out(dir / "two.xyz");
        uint64_t state = 1;
        auto uniform = [&state] {  // a small LCG: the same points everywhere
            state = state * 6364136223846793005ULL + 1442695040888963407ULL;
            return static_cast<double>(state >> 11) / 9007199254740992.0;
        };
        char line[96];
        for (const double o : {0.0, 4200.0})
            for (int i = 0; i < 80000; ++i) {
                const double x = 500000.0 + o + 200.0 * uniform(), y = 4400000.0 + o + 200.0 * uniform();
                const bool roof = x - 500000.0 - o > 50 && x - 500000.0 - o < 100 && y - 4400000.0 - o > 50 && y - 4400000.0 - o < 100;
                std::snprintf(line, sizeof line, "%.3f %.3f %.3f\n", x, y, 10.0 + (roof ? 8.0 : 0.0) + 0.05 * uniform());
                out << line;
            }
    }
    const auto r = test::run_command("bash -c '" + test::address_space_limit(1400000) + test::cli() + " cloud rasterize --quiet --cloud " + (dir / "two.xyz") +
                                     " --cloud-crs EPSG:32650 --gsd 4 --out " + (dir / "r") + "'");
    INFO(r.err);
    CHECK(r.exit_code == 0);
    CHECK(std::filesystem::exists(dir / "r/dtm.tif"));
}
