#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <gdal_priv.h>

#include "core/error.hpp"
#include "crs/gdal_util.hpp"
#include "raster/raster.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

namespace {
// Writes a small GeoTIFF with an arbitrary geotransform (or none) through GDAL directly.
void write_plain_tiff(const std::string& path, const double* gt, const char* epsg, int bands = 1) {
    ensure_gdal_registered();
    GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GTiff");
    GDALDataset* ds = drv->Create(path.c_str(), 8, 6, bands, GDT_Byte, nullptr);
    if (gt) ds->SetGeoTransform(const_cast<double*>(gt));
    if (epsg) {
        OGRSpatialReference srs;
        srs.SetFromUserInput(epsg);
        ds->SetSpatialRef(&srs);
    }
    GDALClose(ds);
}
}  // namespace

TEST_CASE("SpaceNet Atlanta panchromatic tile: UInt16 - UTM 16N - 0.5 m", "[raster][real]") {
    const RasterInfo info = read_raster_info(shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif"));
    CHECK(info.width == 450);
    CHECK(info.height == 900);
    REQUIRE(info.band_count() == 1);
    CHECK(info.bands[0].type == SampleType::uint16);
    REQUIRE(info.bands[0].nodata.has_value());
    CHECK(*info.bands[0].nodata == 0.0);
    CHECK(info.crs.epsg == 32616);
    CHECK(info.gsd.x_m == Approx(0.5).margin(1e-6));
    CHECK(info.gsd.y_m == Approx(0.5).margin(1e-6));
    CHECK(info.extent.min_x == Approx(733601.0).margin(0.5));
    CHECK(info.extent.max_x == Approx(733826.0).margin(0.5));
    CHECK(info.extent.min_y == Approx(3724689.0).margin(0.5));
    CHECK(info.extent.max_y == Approx(3725139.0).margin(0.5));
}

TEST_CASE("Autzen ortho in international feet: GSD comes out in metres", "[raster][real]") {
    const RasterInfo info = read_raster_info(shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif"));
    CHECK(info.width == 3248);
    CHECK(info.height == 4385);
    CHECK(info.band_count() == 3);
    CHECK(info.bands[0].type == SampleType::byte);
    CHECK(info.crs.horizontal_epsg == 2994);
    CHECK(info.crs.linear_unit_m == Approx(0.3048));
    CHECK(info.gsd.x_m == Approx(0.3048).margin(1e-6));
    CHECK(info.extent.min_x == Approx(635615.4278659122).margin(1e-3));
    CHECK(info.extent.max_y == Approx(853362.6430851521).margin(1e-3));
}

TEST_CASE("Windowed reads equal the same pixels of a whole read", "[raster]") {
    RasterReader reader(shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif"));
    const Image<uint8_t> window = reader.read<uint8_t>({1000, 2000, 64, 32});
    const Image<float> window_f = reader.read<float>({1000, 2000, 64, 32}, {2});
    REQUIRE(window.bands == 3);
    REQUIRE(window_f.bands == 1);
    const Image<uint8_t> bigger = reader.read<uint8_t>({990, 1990, 100, 100});
    for (int b = 0; b < 3; ++b)
        for (int r = 0; r < 32; r += 7)
            for (int c = 0; c < 64; c += 5) REQUIRE(window.at(b, c, r) == bigger.at(b, c + 10, r + 10));
    for (int r = 0; r < 32; ++r) REQUIRE(window_f.at(0, 3, r) == float(window.at(1, 3, r)));
    CHECK_THROWS_WITH(reader.read<uint8_t>({3200, 0, 100, 10}), Catch::Contains("window outside the raster"));
    CHECK_THROWS_WITH(reader.read<uint8_t>({0, 0, 10, 10}, {4}), Catch::Contains("band 4 does not exist"));
}

TEST_CASE("Pixel <-> map transforms invert each other", "[raster]") {
    const GeoTransform t{635615.4278659122, 1.0, 853362.6430851521, -1.0};
    const MapPoint m = t.pixel_to_map({12.25, 7.5});
    const PixelPoint p = t.map_to_pixel(m);
    CHECK(p.col == Approx(12.25));
    CHECK(p.row == Approx(7.5));
    CHECK(t.pixel_centre(0, 0).x == Approx(635615.9278659122));
    CHECK(t.window(10, 20).origin_y == Approx(853362.6430851521 - 20));
}

TEST_CASE("Label and float rasters round-trip with georeferencing - tiled and compressed", "[raster]") {
    ScratchDir dir("raster_rt");
    const RasterInfo src = read_raster_info(shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif"));
    Image<uint32_t> labels(300, 280, 1);
    for (std::size_t i = 0; i < labels.data.size(); ++i) labels.data[i] = static_cast<uint32_t>(i * 2654435761u % 100000u);
    write_geotiff(dir / "labels.tif", labels, src.transform, src.crs.wkt);
    Image<float> heights(300, 280, 1);
    for (std::size_t i = 0; i < heights.data.size(); ++i) heights.data[i] = static_cast<float>(i) * 0.25f;
    GeoTiffWriteOptions fo;
    fo.nodata = -9999.0;
    write_geotiff(dir / "heights.tif", heights, src.transform, src.crs.wkt, fo);

    RasterReader lr(dir / "labels.tif");
    CHECK(lr.info().bands[0].type == SampleType::uint32);
    CHECK(lr.info().crs.epsg == 32616);
    CHECK(lr.info().block_width == 256);  // tiled
    CHECK(lr.info().extent.min_x == Approx(src.extent.min_x));
    CHECK(lr.read_all<uint32_t>().data == labels.data);
    RasterReader hr(dir / "heights.tif");
    CHECK(hr.info().bands[0].nodata == -9999.0);
    CHECK(hr.read_all<float>().data == heights.data);
    GDALDataset* ds = GDALDataset::Open((dir / "labels.tif").c_str());
    REQUIRE(ds);
    const char* compression = ds->GetMetadataItem("COMPRESSION", "IMAGE_STRUCTURE");
    CHECK(std::string(compression ? compression : "") == "DEFLATE");
    GDALClose(ds);
}

TEST_CASE("Rasters without usable georeferencing are refused with the file named", "[raster][errors]") {
    ScratchDir dir("raster_bad");
    const double rotated[6] = {500000, 0.5, 0.1, 4400000, 0.1, -0.5};
    const double north_up[6] = {500000, 0.5, 0, 4400000, 0, -0.5};
    write_plain_tiff(dir / "nogeo.tif", nullptr, nullptr);
    write_plain_tiff(dir / "rotated.tif", rotated, "EPSG:32650");
    write_plain_tiff(dir / "nocrs.tif", north_up, nullptr);

    CHECK_THROWS_WITH(read_raster_info(dir / "nogeo.tif"), Catch::Contains("nogeo.tif") && Catch::Contains("no georeferencing"));
    CHECK_THROWS_WITH(read_raster_info(dir / "rotated.tif"), Catch::Contains("rotated.tif") && Catch::Contains("rotated"));
    CHECK_THROWS_WITH(read_raster_info(dir / "nocrs.tif"), Catch::Contains("nocrs.tif") && Catch::Contains("no coordinate reference system"));
    CHECK_THROWS_WITH(read_raster_info(dir / "missing.tif"), Catch::Contains("missing.tif: file not found"));
    {
        std::ofstream(dir / "text.tif") << "this is not a raster\n";
    }
    CHECK_THROWS_WITH(read_raster_info(dir / "text.tif"), Catch::Contains("text.tif") && Catch::Contains("not a raster"));
    {
        std::ofstream(dir / "empty.vrt") << "<VRTDataset rasterXSize=\"10\" rasterYSize=\"10\"></VRTDataset>\n";
    }
    CHECK_THROWS_WITH(read_raster_info(dir / "empty.vrt"), Catch::Contains("empty.vrt") && Catch::Contains("bands"));

    RasterOpenOptions pixel;
    pixel.allow_pixel_coordinates = true;
    const RasterInfo info = read_raster_info(dir / "nogeo.tif", pixel);
    CHECK_FALSE(info.georeferenced);
    CHECK(info.gsd.x_m == 1.0);
    RasterOpenOptions assume;
    assume.assume_crs = "EPSG:32650";
    CHECK(read_raster_info(dir / "nocrs.tif", assume).crs.epsg == 32650);
}

TEST_CASE("Unreadable pixel data is reported - not crashed on", "[raster][errors]") {
    ScratchDir dir("raster_trunc");
    const std::string src = shared_data("spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif");
    std::string bytes = cityforge::test::slurp(src);
    bytes.resize(bytes.size() / 3);
    std::ofstream(dir / "truncated.tif", std::ios::binary) << bytes;
    bool reported = false;
    try {
        RasterReader r(dir / "truncated.tif");
        r.read_all<uint16_t>();
    } catch (const Error& e) {
        reported = std::string(e.what()).find("truncated.tif") != std::string::npos;
    }
    CHECK(reported);
}

TEST_CASE("A failed write leaves no file behind", "[raster][errors]") {
    ScratchDir dir("raster_wfail");
    Image<uint8_t> img(10, 10, 1);
    const std::string target = dir / "no/such/folder/out.tif";
    CHECK_THROWS_WITH(write_geotiff(target, img, GeoTransform{}, ""), Catch::Contains("out.tif"));
    CHECK(dir.file_count() == 0);
    Image<uint8_t> empty;
    CHECK_THROWS_WITH(write_geotiff(dir / "empty.tif", empty, GeoTransform{}, ""), Catch::Contains("empty raster"));
    CHECK(dir.file_count() == 0);
}
