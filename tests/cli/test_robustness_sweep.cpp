// Robustness sweep on data we did not make (December 2026): what broke, each
// case as it was found. Real files from ../shared/data, altered as named.
#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cloud/cloud_filters.hpp"
#include "cloud/las.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::run_cli;
using cityforge::test::run_command;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;
using cityforge::test::slurp;
using nlohmann::json;

namespace {

struct FarPoint {
    double x, y, z;  ///< file CRS units
};

// A copy of a LAS 1.0-1.3 file (legacy point count) with `extra` points
// appended: the first record's attributes, these coordinates; the header's
// count and bounds updated.
void write_with_points(const std::string& src, const std::string& dst, const std::vector<FarPoint>& extra) {
    std::string las = slurp(src);
    REQUIRE(las.size() > 227);
    uint32_t offset, n;
    uint16_t rec;
    double scale[3], origin[3], bounds[6];  // max x, min x, max y, min y, max z, min z
    std::memcpy(&offset, las.data() + 96, 4);
    std::memcpy(&rec, las.data() + 105, 2);
    std::memcpy(&n, las.data() + 107, 4);
    std::memcpy(scale, las.data() + 131, 24);
    std::memcpy(origin, las.data() + 155, 24);
    std::memcpy(bounds, las.data() + 179, 48);
    REQUIRE(las.size() >= offset + std::size_t(n) * rec);
    las.resize(offset + std::size_t(n) * rec);
    const std::string first = las.substr(offset, rec);
    for (const FarPoint& p : extra) {
        std::string r = first;
        const double v[3] = {p.x, p.y, p.z};
        for (int a = 0; a < 3; ++a) {
            const auto q = static_cast<int32_t>(std::llround((v[a] - origin[a]) / scale[a]));
            std::memcpy(r.data() + 4 * a, &q, 4);
            bounds[2 * a] = std::max(bounds[2 * a], v[a]), bounds[2 * a + 1] = std::min(bounds[2 * a + 1], v[a]);
        }
        las += r;
    }
    const uint32_t count = n + static_cast<uint32_t>(extra.size());
    std::memcpy(las.data() + 107, &count, 4);
    std::memcpy(las.data() + 179, bounds, 48);
    std::ofstream(dst, std::ios::binary) << las;
}

// PDAL's Autzen trim (EPSG:2994-like WKT, international feet: x 636002-637179, y 848935-849498, z 406-521).
const std::vector<FarPoint> kAutzenFar = {{646500, 859200, 450}, {626500, 839200, 450}, {656500, 849200, 430}};  // 3 km away
const std::vector<FarPoint> kAutzenLow = {{636500, 849200, -5577}, {636600, 849250, -5577}, {636700, 849300, -5600}};  // z -1700 m

}  // namespace

TEST_CASE("A few gross outliers do not set the outlier filter's limit (Autzen, 3 points 1.7 km below)", "[cloud][filters][sweep]") {
    ScratchDir dir("sweep_filter");
    const std::string src = shared_data("autzen_oregon/autzen_trim.las");
    write_with_points(src, dir / "low.las", kAutzenLow);
    const PointCloud clean = read_las(src), low = read_las(dir / "low.las");
    REQUIRE(low.size() == clean.size() + 3);
    const OutlierFilterResult a = filter_outliers(clean, OutlierFilterOptions{}), b = filter_outliers(low, OutlierFilterOptions{});
    // Before: mean + 3 sigma over every point, 2.0 m -> 22.6 m (in feet 6.7 -> 74).
    CHECK(b.limit == a.limit);
    for (std::size_t i = clean.size(); i < low.size(); ++i) CHECK_FALSE(b.keep[i]);
    CHECK(std::equal(a.keep.begin(), a.keep.end(), b.keep.begin()));
}

TEST_CASE("run copes with far outliers: points km away and a z of -1700 m give the clean cloud's buildings", "[run][sweep][cli]") {
    ScratchDir dir("sweep_far");
    // 1300 x 2600 px of the Autzen ortho (1 ft): the cloud fills its southern
    // third, so the grid's centre is 800 m from any point.
    const std::string ortho = dir / "ortho.tif";
    REQUIRE(run_command("gdal_translate -q -projwin 635950 851500 637250 848900 " + shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif") +
                        " " + ortho).exit_code == 0);
    const std::string src = shared_data("autzen_oregon/autzen_trim.las");
    std::vector<FarPoint> both = kAutzenFar;
    both.insert(both.end(), kAutzenLow.begin(), kAutzenLow.end());
    write_with_points(src, dir / "far.las", both);
    const auto run = [&](const std::string& cloud, const std::string& out) {
        return run_cli("run --quiet --ortho " + ortho + " --cloud " + cloud + " --formats geojson --lod 0,1 --out " + (dir / out));
    };
    const auto clean = run(src, "clean");
    INFO(clean.err);
    REQUIRE(clean.exit_code == 0);
    // Before: exit 1, "no point left after cleaning in the 400 m around ..."
    // (the far points stretch the cloud's box over the whole grid, whose centre
    // is empty); the low points alone raised the outlier limit 11 times (on
    // a 1280 x 650 px crop of the same ortho: 16 buildings instead of 17).
    const auto far = run(dir / "far.las", "far");
    INFO(far.err);
    REQUIRE(far.exit_code == 0);
    CHECK(slurp(dir / "far/buildings.geojson") == slurp(dir / "clean/buildings.geojson"));
    const json report = json::parse(slurp(dir / "far/run_report.json"));
    CHECK(report["counts"]["buildings"].get<int>() > 10);
}

TEST_CASE("Empty and cut files are named as such: a 0-byte LAS, a LAS cut in its header, a cut GeoJSON, a city model", "[cli][errors][sweep]") {
    ScratchDir dir("sweep_cut");
    std::ofstream(dir / "empty.las").flush();
    std::ofstream(dir / "empty.tif").flush();
    std::filesystem::create_directories(dir / "folder");
    const std::string las = slurp(shared_data("autzen_oregon/autzen_trim.las"));
    std::ofstream(dir / "head.las", std::ios::binary) << las.substr(0, 200);
    const std::string geojson = slurp(shared_data("ign_lidarhd_bdtopo_west/bdtopo_buildings_west.geojson"));
    std::ofstream(dir / "cut.geojson") << geojson.substr(0, geojson.size() / 2);
    std::ofstream(dir / "model.city.json") << R"({"type": "CityJSON", "version": "2.0", "transform": {"scale": [1, 1, 1], "translate": [0, 0, 0]}, "CityObjects": {}, "vertices": []})";
    const std::string fp = shared_data("ign_lidarhd_bdtopo_west/bdtopo_buildings_west.geojson");
    struct Case {
        std::string args, file, problem;
    };
    // Before: "not a LAS file (no LASF signature)" for the first three,
    // "not a raster, LAS point cloud or vector file" for the next four and
    // "not a vector dataset OGR can read" for the last three.
    const std::vector<Case> cases = {
        {"heights --footprints " + fp + " --cloud " + (dir / "empty.las") + " --out " + (dir / "h.gpkg"), dir / "empty.las", "empty file (0 bytes)"},
        {"info " + (dir / "head.las"), dir / "head.las", "truncated LAS header: the file ends after 200 bytes"},
        {"cloud rasterize --cloud " + (dir / "head.las") + " --gsd 1 --out " + (dir / "r"), dir / "head.las", "truncated LAS header"},
        {"info " + (dir / "empty.tif"), dir / "empty.tif", "empty file (0 bytes)"},
        {"info " + (dir / "empty.las"), dir / "empty.las", "empty file (0 bytes)"},
        {"info " + (dir / "cut.geojson"), dir / "cut.geojson", "GeoJSON"},
        {"info " + (dir / "model.city.json"), dir / "model.city.json", "a city model"},
        {"export --in " + (dir / "model.city.json") + " --out " + (dir / "e"), dir / "model.city.json", "a city model (CityJSON / glTF), not a vector layer"},
        {"heights --footprints " + (dir / "empty.tif") + " --cloud " + shared_data("autzen_oregon/autzen_trim.las") + " --out " + (dir / "h.gpkg"),
         dir / "empty.tif", "empty file (0 bytes)"},
        {"run --footprints " + (dir / "folder") + " --cloud " + shared_data("autzen_oregon/autzen_trim.las") + " --out " + (dir / "run"),
         dir / "folder", "is a directory, not a vector dataset"},
    };
    for (const Case& c : cases) {
        const auto r = run_cli(c.args);
        INFO(c.args << "\n" << r.err);
        CHECK(r.exit_code == 1);
        CHECK(r.err.rfind("cityforge: error: " + c.file + ": ", 0) == 0);
        CHECK(r.err.find(c.problem) != std::string::npos);
        CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
    }
    CHECK_FALSE(std::filesystem::exists(dir / "h.gpkg"));
    CHECK_FALSE(std::filesystem::exists(dir / "r"));
    CHECK_FALSE(std::filesystem::exists(dir / "e"));
    CHECK_FALSE(std::filesystem::exists(dir / "run"));
}

TEST_CASE("export of footprints without heights to every format is refused naming the input, before any file is written", "[cli][export][sweep]") {
    ScratchDir dir("sweep_export");
    // OpenStreetMap footprints of Kampala (EPSG:3857), no height fields.
    const std::string in = shared_data("oam_kampala_rgba/kampala_z19_east_buildings.geojson");
    const auto r = run_cli("export --in " + in + " --out " + (dir / "m"));
    INFO(r.err);
    // Before: exit 1 naming m/buildings.glb, with six city model files left in m/.
    CHECK(r.exit_code == 1);
    CHECK(r.err.find("cityforge: error: " + in + ": no building has a height") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "m"));
    // Without the mesh formats the footprints (LOD0) are written.
    const auto lod0 = run_cli("export --quiet --in " + in + " --formats geojson,cityjson --out " + (dir / "m0"));
    INFO(lod0.err);
    CHECK(lod0.exit_code == 0);
    CHECK(std::filesystem::exists(dir / "m0/buildings.city.json"));
}

TEST_CASE("run does not replace a folder's outputs without --overwrite - with it, a run of other options starts afresh", "[cli][run][sweep]") {
    ScratchDir dir("sweep_run_folder");
    const std::string ign = shared_data("ign_lidarhd_bdtopo_west/");
    const std::string inputs = " --ortho " + ign + "rgb_from_points_0p5m_west.tif --cloud " + ign + "lidarhd_870200_6617083_west.las --formats geojson";
    // A folder holding another command's city models (export of Delft footprints).
    const std::string delft = shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson");
    REQUIRE(run_cli("export --quiet --in " + delft + " --formats geojson,cityjson --lod 0 --out " + (dir / "m")).exit_code == 0);
    const std::string before = slurp(dir / "m/buildings.geojson");
    // Before: exit 0, the 135 Delft buildings silently replaced by the run's.
    const auto refused = run_cli("run --quiet" + inputs + " --out " + (dir / "m"));
    CHECK(refused.exit_code == 1);
    CHECK(refused.err.find("cityforge: error: " + (dir / "m") + ": output folder exists and is not empty") != std::string::npos);
    CHECK(refused.err.find("--overwrite") != std::string::npos);
    CHECK(slurp(dir / "m/buildings.geojson") == before);
    const auto replaced = run_cli("--overwrite run --quiet" + inputs + " --out " + (dir / "m"));
    INFO(replaced.err);
    CHECK(replaced.exit_code == 0);
    CHECK(slurp(dir / "m/buildings.geojson") != before);
    // The same run again resumes (no --overwrite needed, same bytes); other
    // options are refused, and with --overwrite start afresh (before: refused
    // with or without --overwrite).
    const std::string first = slurp(dir / "m/buildings.geojson");
    CHECK(run_cli("run --quiet" + inputs + " --out " + (dir / "m")).exit_code == 0);
    CHECK(slurp(dir / "m/buildings.geojson") == first);
    const auto other = run_cli("run --quiet" + inputs + " --tile-size 64 --out " + (dir / "m"));
    CHECK(other.exit_code == 1);
    CHECK(other.err.find("holds a run with other options") != std::string::npos);
    CHECK(other.err.find("--overwrite") != std::string::npos);
    const auto fresh = run_cli("--overwrite run --quiet" + inputs + " --tile-size 64 --out " + (dir / "m"));
    INFO(fresh.err);
    CHECK(fresh.exit_code == 0);
    CHECK(json::parse(slurp(dir / "m/manifest.json"))["tiles"].size() > 1);
    // A file where the folder should be.
    std::ofstream(dir / "file") << "x";
    const auto file = run_cli("--overwrite run --quiet" + inputs + " --out " + (dir / "file"));
    CHECK(file.exit_code == 1);
    CHECK(file.err.find(dir / "file") != std::string::npos);
}

TEST_CASE("Heights from a cloud without a vertical CRS (IGN Lidar HD, EPSG:2154 only) say their datum is unnamed", "[cli][crs][sweep]") {
    ScratchDir dir("sweep_vertical");
    const std::string ign = shared_data("ign_lidarhd_bdtopo_west/");
    const std::string cloud = ign + "lidarhd_870200_6617083_west.las", fp = ign + "bdtopo_buildings_west.geojson";
    // Before: heights, roofs, rasterize and run wrote heights in an unnamed datum without a word.
    const auto h = run_cli("heights --footprints " + fp + " --cloud " + cloud + " --out " + (dir / "h.gpkg"));
    INFO(h.err);
    REQUIRE(h.exit_code == 0);
    CHECK(h.err.find("warning: " + cloud + ": no vertical CRS") != std::string::npos);
    const auto r = run_cli("cloud rasterize --cloud " + cloud + " --gsd 1 --out " + (dir / "r"));
    CHECK(r.exit_code == 0);
    CHECK(r.err.find("no vertical CRS") != std::string::npos);
    const auto roofs = run_cli("roofs --footprints " + fp + " --cloud " + cloud + " --formats cityjson --out " + (dir / "roofs"));
    CHECK(roofs.exit_code == 0);
    CHECK(roofs.err.find("no vertical CRS") != std::string::npos);
    const auto run = run_cli("run --ortho " + ign + "rgb_from_points_0p5m_west.tif --cloud " + cloud + " --formats geojson --out " + (dir / "run"));
    REQUIRE(run.exit_code == 0);
    const json report = json::parse(slurp(dir / "run/run_report.json"));
    bool said = false;
    for (const auto& w : report["warnings"]) said = said || w.get<std::string>().find("no vertical CRS") != std::string::npos;
    CHECK(said);
    // Given one, nothing is said and the outputs name it.
    const auto named = run_cli("heights --footprints " + fp + " --cloud " + cloud + " --cloud-crs EPSG:2154+5720 --out " + (dir / "h2.gpkg"));
    CHECK(named.exit_code == 0);
    CHECK(named.err.find("no vertical CRS") == std::string::npos);
    const auto roofs2 = run_cli("roofs --footprints " + fp + " --cloud " + cloud + " --vertical-crs EPSG:5720 --formats cityjson --out " + (dir / "roofs2"));
    CHECK(roofs2.exit_code == 0);
    CHECK(roofs2.err.find("no vertical CRS") == std::string::npos);
    // EPSG:5698 = RGF93 / Lambert-93 + NGF-IGN69 height.
    CHECK(json::parse(slurp(dir / "roofs2/buildings.city.json"))["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/5698");
}

TEST_CASE("A few points km away do not make the grid of cloud rasterize and cloud-only footprints (Autzen)", "[cli][cloud][sweep]") {
    ScratchDir dir("sweep_far_grid");
    const std::string src = shared_data("autzen_oregon/autzen_trim.las");
    std::vector<FarPoint> far = kAutzenFar;
    far.insert(far.end(), kAutzenLow.begin(), kAutzenLow.end());
    write_with_points(src, dir / "far.las", far);
    // Before: footprints exited 3 (out of memory: a grid of 18289 x 12193
    // cells needing 19.6 GB); rasterize wrote 9145 x 6097 rasters in 43 s.
    const auto fp = run_cli("footprints --cloud " + (dir / "far.las") + " --out " + (dir / "far.gpkg"));
    INFO(fp.err);
    REQUIRE(fp.exit_code == 0);
    CHECK(fp.err.find("warning: " + (dir / "far.las") + ": 3 of 110006 points lie over") != std::string::npos);
    REQUIRE(run_cli("footprints --quiet --cloud " + src + " --out " + (dir / "clean.gpkg")).exit_code == 0);
    const auto count = [](const std::string& path) {
        return json::parse(run_cli("info --json " + path).out)["layers"][0]["feature_count"].get<int>();
    };
    CHECK(count(dir / "far.gpkg") == count(dir / "clean.gpkg"));
    const auto ras = run_cli("cloud rasterize --quiet --cloud " + (dir / "far.las") + " --gsd 1 --out " + (dir / "rf"));
    INFO(ras.err);
    REQUIRE(ras.exit_code == 0);
    REQUIRE(run_cli("cloud rasterize --quiet --cloud " + src + " --gsd 1 --out " + (dir / "rc")).exit_code == 0);
    CHECK(slurp(dir / "rf/dsm.tif") == slurp(dir / "rc/dsm.tif"));
    CHECK(slurp(dir / "rf/dtm.tif") == slurp(dir / "rc/dtm.tif"));
}

TEST_CASE("Options read late are checked first: a folder as --config or --manifest, a projected --vertical-crs, a missing --texture-ortho", "[cli][errors][sweep]") {
    ScratchDir dir("sweep_options");
    std::filesystem::create_directories(dir / "folder");
    const std::string ign = shared_data("ign_lidarhd_bdtopo_west/");
    const std::string roofs = "roofs --footprints " + ign + "bdtopo_buildings_west.geojson --cloud " + ign + "lidarhd_870200_6617083_west.las";
    struct Case {
        std::string args, subject, problem, out;
    };
    // Before: exit 70 "internal error: basic_filebuf::underflow ..." for the
    // folders; EPSG:2154 taken as the vertical CRS without a word (exit 0);
    // a missing texture ortho refused after geojson, gpkg and CityGML were written.
    const std::vector<Case> cases = {
        {"run --config " + (dir / "folder") + " --ortho " + ign + "rgb_from_points_0p5m_west.tif --out " + (dir / "a"), dir / "folder",
         "is a directory", dir / "a"},
        {"run --manifest " + (dir / "folder") + " --out " + (dir / "b"), dir / "folder", "is a directory", dir / "b"},
        {roofs + " --vertical-crs EPSG:2154 --out " + (dir / "c"), "--vertical-crs", "is not a vertical CRS", dir / "c"},
        {roofs + " --texture-ortho " + (dir / "missing.tif") + " --out " + (dir / "d"), dir / "missing.tif", "file not found", dir / "d"},
        {"export --in " + shared_data("delft_ahn3_bgt_west/bgt_pand_west_with_ref_heights.geojson") + " --vertical-crs EPSG:28992 --out " + (dir / "e"),
         "--vertical-crs", "is not a vertical CRS", dir / "e"},
    };
    for (const Case& c : cases) {
        const auto r = run_cli(c.args);
        INFO(c.args << "\n" << r.err);
        CHECK(r.exit_code == 1);
        CHECK(r.err.rfind("cityforge: error: " + c.subject + ": ", 0) == 0);
        CHECK(r.err.find(c.problem) != std::string::npos);
        CHECK_FALSE(std::filesystem::exists(c.out));
    }
}

TEST_CASE("export of a run's own buildings.geojson (RFC 7946 lon/lat) works in the UTM zone of its centre and names it", "[cli][export][sweep]") {
    ScratchDir dir("sweep_export_lonlat");
    REQUIRE(run_cli("synth --quiet --out " + (dir / "s") + " --size-m 200 --seed 5").exit_code == 0);
    const auto run = run_cli("run --quiet --ortho " + (dir / "s/ortho.tif") + " --cloud " + (dir / "s/cloud.las") + " --out " + (dir / "r"));
    INFO(run.err);
    REQUIRE(run.exit_code == 0);
    const auto r = run_cli("export --in " + (dir / "r/buildings.geojson") + " --out " + (dir / "e"));
    INFO(r.err);
    // Before: exit 1 "buildings are in a geographic CRS; ... reproject with ogr2ogr -t_srs".
    REQUIRE(r.exit_code == 0);
    CHECK(r.err.find("29 buildings (EPSG:32650") != std::string::npos);  // the summary names the CRS written
    const json mine = json::parse(slurp(dir / "e/buildings.city.json"));
    const json runs = json::parse(slurp(dir / "r/buildings.city.json"));  // the run's own model, in its working CRS (UTM 50N)
    CHECK(mine["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/32650");
    CHECK(mine["metadata"]["referenceSystem"] == runs["metadata"]["referenceSystem"]);
    std::size_t run_buildings = 0;  // the run's model also has LOD2 building parts
    for (const auto& [id, o] : runs["CityObjects"].items()) run_buildings += o["type"] == "Building";
    CHECK(mine["CityObjects"].size() == run_buildings);
    // The same place to a centimetre (the GeoJSON's lon/lat have 7 decimals).
    for (int k : {0, 1, 3, 4}) CHECK(std::abs(mine["metadata"]["geographicalExtent"][k].get<double>() - runs["metadata"]["geographicalExtent"][k].get<double>()) < 0.02);
    CHECK(std::filesystem::exists(dir / "e/buildings.glb"));
}

TEST_CASE("audits of inputs that do not overlap are an error naming both files and their extents, with nothing written", "[cli][audit][sweep]") {
    ScratchDir dir("sweep_audit_apart");
    // Kampala (OpenStreetMap, EPSG:3857) against BD TOPO in Brittany (EPSG:2154); IGN Lidar HD against Autzen, Oregon.
    const std::string kampala = shared_data("oam_kampala_rgba/kampala_z19_east_buildings.geojson");
    const std::string bdtopo = shared_data("ign_lidarhd_bdtopo_west/bdtopo_buildings_west.geojson");
    const std::string ign_las = shared_data("ign_lidarhd_bdtopo_west/lidarhd_870200_6617083_west.las");
    const std::string autzen = shared_data("autzen_oregon/autzen_trim.las");
    struct Case {
        std::string args, pred, ref, out;
    };
    // Before: exit 0 with F1 0 (and all-zero reports written) for each.
    const std::vector<Case> cases = {
        {"audit footprints --pred " + kampala + " --ref " + bdtopo, kampala, bdtopo, dir / "f"},
        {"audit heights --ref-field hauteur --pred " + kampala + " --ref " + bdtopo, kampala, bdtopo, dir / "h"},
        {"audit rectangles --in " + kampala + " --original " + bdtopo, kampala, bdtopo, dir / "r"},
        {"audit clouds --pred " + ign_las + " --ref " + autzen, ign_las, autzen, dir / "c"},
    };
    for (const Case& c : cases) {
        const auto r = run_cli(c.args + " --out " + c.out);
        INFO(c.args << "\n" << r.err);
        CHECK(r.exit_code == 1);
        CHECK(r.err.rfind("cityforge: error: " + c.pred + ": does not overlap the reference " + c.ref + ": predicted ", 0) == 0);
        CHECK(r.err.find(", reference ") != std::string::npos);
        CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
        CHECK_FALSE(std::filesystem::exists(c.out));
    }
    // Both in EPSG:2154, the reference's CRS: Kampala's extent is far off the Lambert-93 zone.
    const auto f = run_cli(cases[0].args + " --out " + (dir / "f"));
    CHECK(f.err.find("870205.2, 6617091.1 - 870231.6, 6617142.3 EPSG:2154") != std::string::npos);
}

TEST_CASE("The whole-run decisions of a cloud on a larger ortho do not depend on how far the ortho reaches (Autzen)", "[cli][run][sweep]") {
    ScratchDir dir("sweep_plan_sample");
    const std::string ortho = shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif");
    const std::string cloud = shared_data("autzen_oregon/autzen_trim.las");
    // The ortho's last 714 rows, its whole width: the cloud lies in them; their centre is ~60 m east of the cloud.
    REQUIRE(run_command("gdal_translate -q -srcwin 0 3671 3248 714 " + ortho + " " + (dir / "strip.tif")).exit_code == 0);
    // A crop around the cloud (gdal_translate -projwin on its extent, clipped at the ortho's lower edge).
    REQUIRE(run_command("gdal_translate -q -srcwin 384 3864 1182 521 " + ortho + " " + (dir / "crop.tif")).exit_code == 0);
    std::vector<json> plans;
    for (const std::string& o : {ortho, dir / "strip.tif", dir / "crop.tif"}) {
        const std::string out = dir / ("plan" + std::to_string(plans.size()) + ".json");
        const auto r = run_cli("plan --quiet --ortho " + o + " --cloud " + cloud + " --out " + out);
        INFO(r.err);
        REQUIRE(r.exit_code == 0);
        plans.push_back(json::parse(slurp(out))["options"]);
    }
    // Before: the strip sampled the 400 m around its own centre (outlier limit 2.33 ft against 2.03).
    for (std::size_t k = 1; k < plans.size(); ++k) {
        INFO(k);
        CHECK(plans[k]["cleaning"]["outlier_limit_m"] == plans[0]["cleaning"]["outlier_limit_m"]);
        CHECK(plans[k]["extraction"]["cloud_cell_px"] == plans[0]["extraction"]["cloud_cell_px"]);
        CHECK(plans[k]["extraction"]["use_point_classes"] == plans[0]["extraction"]["use_point_classes"]);
    }
    CHECK(plans[0]["cleaning"]["outlier_limit_m"].get<double>() > 1.0);
}
