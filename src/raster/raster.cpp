#include "raster/raster.hpp"

#include <cmath>
#include <cstdlib>
#include <cpl_string.h>
#include <filesystem>
#include <gdal_priv.h>
#include <gdal_utils.h>
#include <gdalwarper.h>
#include <ogr_spatialref.h>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/memory.hpp"
#include "crs/gdal_util.hpp"

namespace cityforge {
namespace {

SampleType from_gdal(GDALDataType t) {
    switch (t) {
        case GDT_Byte: return SampleType::byte;
        case GDT_UInt16: return SampleType::uint16;
        case GDT_Int16: return SampleType::int16;
        case GDT_UInt32: return SampleType::uint32;
        case GDT_Int32: return SampleType::int32;
        case GDT_Float32: return SampleType::float32;
        case GDT_Float64: return SampleType::float64;
        default: return SampleType::other;
    }
}

template <typename T> constexpr GDALDataType gdal_type();
template <> constexpr GDALDataType gdal_type<uint8_t>() { return GDT_Byte; }
template <> constexpr GDALDataType gdal_type<uint16_t>() { return GDT_UInt16; }
template <> constexpr GDALDataType gdal_type<int16_t>() { return GDT_Int16; }
template <> constexpr GDALDataType gdal_type<uint32_t>() { return GDT_UInt32; }
template <> constexpr GDALDataType gdal_type<float>() { return GDT_Float32; }
template <> constexpr GDALDataType gdal_type<double>() { return GDT_Float64; }

// The CRS to store in a GeoTIFF. GDAL's GeoTIFF writer stores a compound CRS
// as ProjectedCSTypeGeoKey + VerticalCSTypeGeoKey only when its parts carry
// EPSG codes; the WKT2 of a registered compound (EPSG:7415) carries its code
// on the compound alone, which GDAL would store as a user-defined CRS that
// reads back without any code. Rebuilt from the codes when they are known.
bool geotiff_srs(const std::string& wkt, OGRSpatialReference& srs) {
    if (srs.importFromWkt(wkt.c_str()) != OGRERR_NONE) return false;
    if (!srs.IsCompound()) return true;
    auto epsg_of = [](const OGRSpatialReference& s, const char* node) -> int {
        const char* auth = s.GetAuthorityName(node);
        const char* code = s.GetAuthorityCode(node);
        return auth && code && EQUAL(auth, "EPSG") ? std::atoi(code) : 0;
    };
    OGRSpatialReference horizontal(srs);
    horizontal.StripVertical();
    const int h = epsg_of(horizontal, nullptr), v = epsg_of(srs, "VERT_CS");
    if (h > 0 && v > 0) return true;  // the parts carry their codes: GDAL writes them
    OGRSpatialReference rebuilt;
    if (const int whole = epsg_of(srs, nullptr); whole > 0 && rebuilt.importFromEPSG(whole) == OGRERR_NONE) srs = rebuilt;
    return true;
}

}  // namespace

std::string to_string(SampleType t) {
    switch (t) {
        case SampleType::byte: return "Byte";
        case SampleType::uint16: return "UInt16";
        case SampleType::int16: return "Int16";
        case SampleType::uint32: return "UInt32";
        case SampleType::int32: return "Int32";
        case SampleType::float32: return "Float32";
        case SampleType::float64: return "Float64";
        case SampleType::other: return "unsupported";
    }
    return "unsupported";
}

struct RasterReader::Impl {
    GDALDataset* ds = nullptr;      // what is read: the file, or the warped VRT over it
    GDALDataset* source = nullptr;  // the file when `ds` is a warped VRT
    ~Impl() {
        if (ds) GDALClose(ds);
        if (source) GDALClose(source);
    }
};

namespace {
// Geotransform, CRS-dependent measures and extent of `ds` into `info`.
void describe_grid(RasterInfo& info, const std::array<double, 6>& gt) {
    info.transform = GeoTransform::from_gdal(gt);
    info.gsd = ground_sample_distance(info.crs, info.transform, info.width, info.height);
    info.metres_per_unit = ground_metres_per_unit(info.crs, info.transform, info.width, info.height);
    const MapPoint a = info.transform.pixel_to_map({0.0, 0.0});
    const MapPoint b = info.transform.pixel_to_map({double(info.width), double(info.height)});
    info.extent = {std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
}
}  // namespace

namespace {
// Band descriptions, the alpha band and the per-dataset mask of `ds` into `info`.
void describe_bands(GDALDataset& ds, RasterInfo& info) {
    info.bands.clear();
    for (int b = 1; b <= ds.GetRasterCount(); ++b) {
        GDALRasterBand* band = ds.GetRasterBand(b);
        RasterBandInfo bi;
        bi.type = from_gdal(band->GetRasterDataType());
        int has_nodata = 0;
        const double nd = band->GetNoDataValue(&has_nodata);
        if (has_nodata) bi.nodata = nd;
        bi.color_interpretation = GDALGetColorInterpretationName(band->GetColorInterpretation());
        bi.description = band->GetDescription();
        info.bands.push_back(bi);
    }
    const int n = ds.GetRasterCount();
    info.alpha_band = n > 1 && ds.GetRasterBand(n)->GetColorInterpretation() == GCI_AlphaBand ? n : 0;
    info.masked = n > 0 && (ds.GetRasterBand(1)->GetMaskFlags() & GMF_PER_DATASET) != 0;
}
}  // namespace

std::vector<int> image_bands(const RasterInfo& info) {
    std::vector<int> out;
    for (int b = 1; b <= info.band_count(); ++b)
        if (b != info.alpha_band) out.push_back(b);
    return out;
}

std::vector<uint8_t> RasterReader::read_mask(const PixelWindow& w) const {
    std::vector<uint8_t> valid(static_cast<std::size_t>(w.width) * static_cast<std::size_t>(w.height), 1);
    if (!info_.masked) return valid;
    if (w.width <= 0 || w.height <= 0 || w.col < 0 || w.row < 0 || w.col + w.width > info_.width || w.row + w.height > info_.height)
        throw Error(info_.path, "window outside the raster");
    GdalErrorCapture capture;
    GDALRasterBand* mask = impl_->ds->GetRasterBand(1)->GetMaskBand();
    const bool alpha = (impl_->ds->GetRasterBand(1)->GetMaskFlags() & GMF_ALPHA) != 0;
    std::vector<uint8_t> m(valid.size());
    if (!mask || mask->RasterIO(GF_Read, w.col, w.row, w.width, w.height, m.data(), w.width, w.height, GDT_Byte, 0, 0, nullptr) != CE_None)
        throw Error(info_.path, "cannot read the mask band" + capture.suffix());
    for (std::size_t i = 0; i < m.size(); ++i) valid[i] = alpha ? m[i] >= 128 : m[i] != 0;
    return valid;
}

std::vector<uint8_t> valid_pixels(const RasterReader& reader, const PixelWindow& window, const Image<float>& image,
                                  const std::vector<int>& bands) {
    std::vector<uint8_t> valid = data_mask(image, reader.info(), bands);
    const std::vector<uint8_t> mask = reader.read_mask(window);
    for (std::size_t i = 0; i < valid.size(); ++i) valid[i] = valid[i] && mask[i];
    return valid;
}

CrsInfo working_crs_for(const RasterInfo& info, const std::string& working_crs) {
    if (!working_crs.empty()) return crs_from_user_input(working_crs, "--working-crs");
    if (!info.crs.geographic) return info.crs;
    const MapPoint c = info.transform.pixel_to_map({info.width / 2.0, info.height / 2.0});
    return utm_crs_for(info.crs, c);
}

RasterReader::RasterReader(const std::string& path, const RasterOpenOptions& options) : impl_(new Impl) {
    ensure_gdal_registered();
    require_dataset_exists(path);
    GdalErrorCapture capture;
    impl_->ds = GDALDataset::FromHandle(GDALOpenEx(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY, nullptr, nullptr, nullptr));
    if (!impl_->ds) throw Error(path, "not a raster GDAL can read" + capture.suffix());
    GDALDataset& ds = *impl_->ds;

    info_.path = path;
    info_.driver = ds.GetDriver() ? ds.GetDriver()->GetDescription() : "";
    info_.width = ds.GetRasterXSize();
    info_.height = ds.GetRasterYSize();
    if (ds.GetRasterCount() <= 0) throw Error(path, "raster has no bands");
    if (info_.width <= 0 || info_.height <= 0) throw Error(path, "raster has zero size");
    describe_bands(ds, info_);
    ds.GetRasterBand(1)->GetBlockSize(&info_.block_width, &info_.block_height);

    std::array<double, 6> gt{};
    const bool has_gt = ds.GetGeoTransform(gt.data()) == CE_None;
    const OGRSpatialReference* srs = ds.GetSpatialRef();
    if (!options.assume_crs.empty()) {
        info_.crs = crs_from_user_input(options.assume_crs, path);
    } else {
        info_.crs = crs_from_ogr(srs, path);
    }

    if (has_gt) {
        if (gt[2] != 0.0 || gt[4] != 0.0)
            throw Error(path, "rotated or sheared geotransform is not supported (warp it north-up first, e.g. gdalwarp)");
        if (gt[1] <= 0.0 || gt[5] == 0.0) throw Error(path, "geotransform has a zero or negative pixel width");
    }
    info_.georeferenced = has_gt && !info_.crs.empty();
    if (!info_.georeferenced) {
        if (!options.allow_pixel_coordinates) {
            if (!has_gt) throw Error(path, "raster has no georeferencing (no geotransform)");
            throw Error(path, "raster has a geotransform but no coordinate reference system (give one with --crs)");
        }
        if (!has_gt) gt = {0.0, 1.0, 0.0, 0.0, 0.0, -1.0};
    }
    describe_grid(info_, gt);
    info_.source_crs = info_.crs;
    if (!info_.georeferenced) return;
    const bool warp = !options.working_crs.empty() || (options.project_geographic && info_.crs.geographic);
    if (!warp) return;
    const CrsInfo target = working_crs_for(info_, options.working_crs);
    if (same_crs(target, info_.crs)) return;
    // A warped VRT over the file: reads go through GDAL's warper, on demand.
    // The image bands, and an alpha band that is 0 outside the file (and
    // where the file's own alpha or mask says so): no invented black pixels.
    GDALWarpOptions* wo = GDALCreateWarpOptions();
    const std::vector<int> bands = image_bands(info_);
    wo->nBandCount = static_cast<int>(bands.size());
    wo->panSrcBands = static_cast<int*>(CPLMalloc(sizeof(int) * bands.size()));
    wo->panDstBands = static_cast<int*>(CPLMalloc(sizeof(int) * bands.size()));
    for (std::size_t i = 0; i < bands.size(); ++i) wo->panSrcBands[i] = bands[i], wo->panDstBands[i] = static_cast<int>(i) + 1;
    wo->nSrcAlphaBand = info_.alpha_band;
    wo->nDstAlphaBand = wo->nBandCount + 1;
    GDALDatasetH vrt = GDALAutoCreateWarpedVRT(GDALDataset::ToHandle(&ds), info_.crs.wkt.c_str(), target.wkt.c_str(), GRA_Bilinear, 0.125, wo);
    GDALDestroyWarpOptions(wo);
    if (!vrt) throw Error(path, "cannot warp onto " + target.label() + capture.suffix());
    impl_->source = impl_->ds;
    impl_->ds = GDALDataset::FromHandle(vrt);
    GDALDataset& w = *impl_->ds;
    info_.warped = true;
    info_.crs = target;
    info_.width = w.GetRasterXSize(), info_.height = w.GetRasterYSize();
    describe_bands(w, info_);
    w.GetRasterBand(1)->GetBlockSize(&info_.block_width, &info_.block_height);
    std::array<double, 6> wgt{};
    w.GetGeoTransform(wgt.data());
    describe_grid(info_, wgt);
}

RasterReader::~RasterReader() = default;
RasterReader::RasterReader(RasterReader&&) noexcept = default;
RasterReader& RasterReader::operator=(RasterReader&&) noexcept = default;

template <typename T>
Image<T> RasterReader::read(const PixelWindow& w, const std::vector<int>& bands_in) const {
    return read_resampled<T>(w, w.width, w.height, bands_in, "nearest");
}

template <typename T>
Image<T> RasterReader::read_resampled(const PixelWindow& w, int out_width, int out_height,
                                      const std::vector<int>& bands_in, const std::string& resampling) const {
    std::vector<int> bands = bands_in;
    if (bands.empty())
        for (int b = 1; b <= info_.band_count(); ++b) bands.push_back(b);
    for (int b : bands)
        if (b < 1 || b > info_.band_count())
            throw Error(info_.path, "band " + std::to_string(b) + " does not exist (raster has " +
                                        std::to_string(info_.band_count()) + ")");
    for (int b : bands)
        if (info_.bands[b - 1].type == SampleType::other)
            throw Error(info_.path, "band " + std::to_string(b) + " has an unsupported data type");
    if (w.width <= 0 || w.height <= 0 || w.col < 0 || w.row < 0 || w.col + w.width > info_.width ||
        w.row + w.height > info_.height)
        throw Error(info_.path, "window outside the raster");
    if (out_width <= 0 || out_height <= 0) throw Error(info_.path, "resampled size must be positive");
    GDALRasterIOExtraArg extra;
    INIT_RASTERIO_EXTRA_ARG(extra);
    if (resampling == "nearest") extra.eResampleAlg = GRIORA_NearestNeighbour;
    else if (resampling == "bilinear") extra.eResampleAlg = GRIORA_Bilinear;
    else if (resampling == "cubic") extra.eResampleAlg = GRIORA_Cubic;
    else if (resampling == "average") extra.eResampleAlg = GRIORA_Average;
    else throw Error("resampling", "unknown method '" + resampling + "'");
    // A read larger than the memory there is (a 65,000 x 65,000 ortho) is
    // refused before it is tried, naming the raster and the sizes.
    const double bytes = static_cast<double>(out_width) * out_height * static_cast<double>(bands.size()) * sizeof(T);
    const double usable = usable_memory_bytes();
    const std::string what = std::to_string(out_width) + " x " + std::to_string(out_height) + " pixels x " + std::to_string(bands.size()) +
                             " band(s) need " + format_bytes(bytes);
    const std::string advice = ": tile it (run --tile-size) or crop it (gdal_translate -srcwin)";
    if (usable > 0 && bytes > usable) throw OutOfMemory(info_.path, what + ", more than the " + format_bytes(usable) + " this process may use" + advice);
    Image<T> image;
    try {
        image = Image<T>(out_width, out_height, static_cast<int>(bands.size()));
    } catch (const std::bad_alloc&) {
        throw OutOfMemory(info_.path, what + advice);
    }
    GdalErrorCapture capture;
    const CPLErr err = impl_->ds->RasterIO(GF_Read, w.col, w.row, w.width, w.height, image.data.data(), out_width,
                                           out_height, gdal_type<T>(), static_cast<int>(bands.size()), bands.data(), 0,
                                           0, 0, &extra);
    if (err != CE_None) throw Error(info_.path, "cannot read pixel data" + capture.suffix());
    return image;
}

template Image<uint8_t> RasterReader::read(const PixelWindow&, const std::vector<int>&) const;
template Image<uint8_t> RasterReader::read_resampled(const PixelWindow&, int, int, const std::vector<int>&, const std::string&) const;
template Image<uint16_t> RasterReader::read(const PixelWindow&, const std::vector<int>&) const;
template Image<uint16_t> RasterReader::read_resampled(const PixelWindow&, int, int, const std::vector<int>&, const std::string&) const;
template Image<int16_t> RasterReader::read(const PixelWindow&, const std::vector<int>&) const;
template Image<int16_t> RasterReader::read_resampled(const PixelWindow&, int, int, const std::vector<int>&, const std::string&) const;
template Image<uint32_t> RasterReader::read(const PixelWindow&, const std::vector<int>&) const;
template Image<uint32_t> RasterReader::read_resampled(const PixelWindow&, int, int, const std::vector<int>&, const std::string&) const;
template Image<float> RasterReader::read(const PixelWindow&, const std::vector<int>&) const;
template Image<float> RasterReader::read_resampled(const PixelWindow&, int, int, const std::vector<int>&, const std::string&) const;
template Image<double> RasterReader::read(const PixelWindow&, const std::vector<int>&) const;
template Image<double> RasterReader::read_resampled(const PixelWindow&, int, int, const std::vector<int>&, const std::string&) const;

RasterInfo read_raster_info(const std::string& path, const RasterOpenOptions& options) {
    return RasterReader(path, options).info();
}

template <typename T>
void write_geotiff(const std::string& path, const Image<T>& image, const GeoTransform& transform,
                   const std::string& crs_wkt, const GeoTiffWriteOptions& options) {
    ensure_gdal_registered();
    if (image.width <= 0 || image.height <= 0 || image.bands <= 0) throw Error(path, "refusing to write an empty raster");
    GDALDriver* driver = GetGDALDriverManager()->GetDriverByName("GTiff");
    if (!driver) throw Error(path, "GDAL has no GTiff driver");
    const std::filesystem::path tmp = temporary_path_for(path);
    GdalErrorCapture capture;
    CPLStringList co;
    const bool tiled = image.width > options.block_size || image.height > options.block_size;
    if (tiled) {
        co.SetNameValue("TILED", "YES");
        co.SetNameValue("BLOCKXSIZE", std::to_string(options.block_size).c_str());
        co.SetNameValue("BLOCKYSIZE", std::to_string(options.block_size).c_str());
    }
    co.SetNameValue("COMPRESS", options.compression.c_str());
    if (options.compression == "DEFLATE" || options.compression == "LZW" || options.compression == "ZSTD")
        co.SetNameValue("PREDICTOR", (std::is_floating_point_v<T> ? "3" : "2"));
    if (image.bands > 1) co.SetNameValue("INTERLEAVE", "PIXEL");
    if (options.rgb && image.bands == 3 && std::is_same_v<T, uint8_t>) co.SetNameValue("PHOTOMETRIC", "RGB");
    if (static_cast<double>(image.pixel_count()) * image.bands * sizeof(T) > 3.5e9) co.SetNameValue("BIGTIFF", "YES");

    GDALDataset* ds = driver->Create(tmp.c_str(), image.width, image.height, image.bands, gdal_type<T>(), co.List());
    if (!ds) throw Error(path, "cannot create GeoTIFF" + user_named(capture.suffix(), tmp, path));
    bool ok = true;
    auto gt = transform.to_gdal();
    ok = ok && ds->SetGeoTransform(gt.data()) == CE_None;
    if (!crs_wkt.empty()) {
        OGRSpatialReference srs;
        ok = ok && geotiff_srs(crs_wkt, srs);
        ok = ok && ds->SetSpatialRef(&srs) == CE_None;
    }
    for (int b = 0; b < image.bands && ok; ++b) {
        GDALRasterBand* band = ds->GetRasterBand(b + 1);
        if (options.nodata) ok = band->SetNoDataValue(*options.nodata) == CE_None;
        if (b < static_cast<int>(options.band_descriptions.size())) band->SetDescription(options.band_descriptions[b].c_str());
    }
    if (ok)
        ok = ds->RasterIO(GF_Write, 0, 0, image.width, image.height, const_cast<T*>(image.data.data()), image.width,
                          image.height, gdal_type<T>(), image.bands, nullptr, 0, 0, 0, nullptr) == CE_None;
    GDALClose(ds);
    ok = ok && CPLGetLastErrorType() < CE_Failure;
    if (ok) {
        // GDAL 3.6's GDALClose reports no error: read the file back (a full
        // disk leaves a truncated file whose last blocks fail to read).
        std::unique_ptr<GDALDataset> back(GDALDataset::Open(tmp.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
        ok = back && back->GetRasterXSize() == image.width && back->GetRasterYSize() == image.height && back->GetRasterCount() == image.bands;
        std::vector<T> row(static_cast<std::size_t>(image.width) * image.bands);
        for (int y = 0; ok && y < image.height; ++y)
            ok = back->RasterIO(GF_Read, 0, y, image.width, 1, row.data(), image.width, 1, gdal_type<T>(), image.bands, nullptr, 0, 0, 0, nullptr) == CE_None;
        ok = ok && CPLGetLastErrorType() < CE_Failure;
    }
    if (!ok) {
        const std::string why = user_named(capture.suffix(), tmp, path);
        discard_file(tmp);
        throw Error(path, "writing GeoTIFF failed (disk full?)" + why);
    }
    commit_file(tmp, path);
}

template void write_geotiff(const std::string&, const Image<uint8_t>&, const GeoTransform&, const std::string&, const GeoTiffWriteOptions&);
template void write_geotiff(const std::string&, const Image<uint16_t>&, const GeoTransform&, const std::string&, const GeoTiffWriteOptions&);
template void write_geotiff(const std::string&, const Image<int16_t>&, const GeoTransform&, const std::string&, const GeoTiffWriteOptions&);
template void write_geotiff(const std::string&, const Image<uint32_t>&, const GeoTransform&, const std::string&, const GeoTiffWriteOptions&);
template void write_geotiff(const std::string&, const Image<float>&, const GeoTransform&, const std::string&, const GeoTiffWriteOptions&);
template void write_geotiff(const std::string&, const Image<double>&, const GeoTransform&, const std::string&, const GeoTiffWriteOptions&);

void build_vrt_mosaic(const std::string& path, const std::vector<std::string>& parts) {
    ensure_gdal_registered();
    GdalErrorCapture capture;
    std::vector<const char*> names;
    std::vector<std::string> absolute;
    for (const std::string& p : parts) absolute.push_back(std::filesystem::absolute(p).string());
    for (const std::string& p : absolute) names.push_back(p.c_str());
    const std::filesystem::path tmp = temporary_path_for(path);
    GDALDatasetH vrt = GDALBuildVRT(tmp.string().c_str(), static_cast<int>(names.size()), nullptr, names.data(), nullptr, nullptr);
    if (!vrt) throw Error(path, "cannot build the VRT mosaic" + capture.suffix());
    GDALClose(vrt);
    std::unique_ptr<GDALDataset> back(GDALDataset::Open(tmp.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
    if (!back || CPLGetLastErrorType() >= CE_Failure) {
        back.reset();
        const std::string why = capture.suffix();
        discard_file(tmp);
        throw Error(path, "writing the VRT mosaic failed (disk full?)" + why);
    }
    back.reset();
    commit_file(tmp, path);
}

std::vector<uint8_t> data_mask(const Image<float>& image, const RasterInfo& info, const std::vector<int>& bands) {
    std::vector<uint8_t> valid(image.pixel_count(), 1);
    for (int b = 0; b < image.bands; ++b) {
        const int source = bands.empty() ? b + 1 : bands.at(static_cast<std::size_t>(b));
        if (source < 1 || source > info.band_count()) throw Error(info.path, "band " + std::to_string(source) + " does not exist");
        const auto& nd = info.bands[static_cast<std::size_t>(source - 1)].nodata;
        if (!nd) continue;
        const float* v = image.band_data(b);
        for (std::size_t i = 0; i < valid.size(); ++i)
            if (v[i] == static_cast<float>(*nd)) valid[i] = 0;
    }
    return valid;
}

}  // namespace cityforge
