#include "raster/quicklook.hpp"

#include <algorithm>
#include <cmath>
#include <cpl_vsi.h>
#include <gdal_priv.h>

#include "core/error.hpp"
#include "crs/crs.hpp"
#include "crs/gdal_util.hpp"
#include "raster/raster.hpp"

namespace cityforge {

std::string encode_png(const std::vector<uint8_t>& bytes, int w, int h, int nb, const std::string& where) {
    if (w <= 0 || h <= 0 || nb <= 0 || bytes.size() != std::size_t(w) * h * nb) throw Error(where, "internal: picture size does not match its pixels");
    GdalErrorCapture capture;
    GDALDriver* mem = GetGDALDriverManager()->GetDriverByName("MEM");
    GDALDriver* png = GetGDALDriverManager()->GetDriverByName("PNG");
    if (!mem || !png) throw Error(where, "GDAL lacks the MEM or PNG driver needed for pictures");
    GDALDataset* ds = mem->Create("", w, h, nb, GDT_Byte, nullptr);
    if (!ds) throw Error(where, "cannot create an in-memory picture");
    const CPLErr err = ds->RasterIO(GF_Write, 0, 0, w, h, const_cast<uint8_t*>(bytes.data()), w, h, GDT_Byte, nb, nullptr, nb,
                                    static_cast<GSpacing>(w) * nb, 1);
    const std::string vsi = "/vsimem/cityforge_picture_" + std::to_string(reinterpret_cast<std::uintptr_t>(ds)) + ".png";
    GDALDataset* out = err == CE_None ? png->CreateCopy(vsi.c_str(), ds, FALSE, nullptr, nullptr, nullptr) : nullptr;
    GDALClose(ds);
    if (!out) throw Error(where, "cannot encode the picture as PNG: " + capture.message());
    GDALClose(out);
    vsi_l_offset size = 0;
    GByte* buf = VSIGetMemFileBuffer(vsi.c_str(), &size, TRUE);
    std::string result(reinterpret_cast<const char*>(buf), static_cast<std::size_t>(size));
    CPLFree(buf);
    return result;
}

Quicklook render_quicklook_png(const std::string& path, const Extent& want, int max_px, const std::string& crs_wkt) {
    RasterReader reader(path);
    if (!crs_wkt.empty() && reader.info().georeferenced && !same_horizontal_crs(reader.info().crs, crs_from_wkt(crs_wkt, path))) {
        RasterOpenOptions warped;
        warped.working_crs = crs_wkt;
        reader = RasterReader(path, warped);
    }
    const RasterInfo& info = reader.info();
    const GeoTransform& gt = info.transform;
    const PixelPoint a = gt.map_to_pixel({want.min_x, want.max_y}), b = gt.map_to_pixel({want.max_x, want.min_y});
    const int c0 = std::clamp(static_cast<int>(std::floor(std::min(a.col, b.col))), 0, info.width);
    const int c1 = std::clamp(static_cast<int>(std::ceil(std::max(a.col, b.col))), 0, info.width);
    const int r0 = std::clamp(static_cast<int>(std::floor(std::min(a.row, b.row))), 0, info.height);
    const int r1 = std::clamp(static_cast<int>(std::ceil(std::max(a.row, b.row))), 0, info.height);
    if (c1 <= c0 || r1 <= r0) throw Error(path, "raster does not overlap the report's footprints");
    const PixelWindow win{c0, r0, c1 - c0, r1 - r0};
    const double scale = std::min(1.0, double(max_px) / std::max(win.width, win.height));
    const int w = std::max(1, static_cast<int>(std::lround(win.width * scale)));
    const int h = std::max(1, static_cast<int>(std::lround(win.height * scale)));
    std::vector<int> bands;
    if (info.band_count() >= 3) bands = {1, 2, 3};
    else bands = {1};
    const Image<float> img = reader.read_resampled<float>(win, w, h, bands, "average");

    // Stretch each band between its 2nd and 98th percentiles.
    const int nb = static_cast<int>(bands.size());
    std::vector<uint8_t> bytes(static_cast<std::size_t>(w) * h * nb);
    for (int band = 0; band < nb; ++band) {
        const float* d = img.band_data(band);
        std::vector<float> v(d, d + img.pixel_count());
        const auto nd = info.bands[bands[band] - 1].nodata;
        if (nd) v.erase(std::remove(v.begin(), v.end(), static_cast<float>(*nd)), v.end());
        float lo = 0, hi = 1;
        if (!v.empty()) {
            std::nth_element(v.begin(), v.begin() + v.size() * 2 / 100, v.end());
            lo = v[v.size() * 2 / 100];
            std::nth_element(v.begin(), v.begin() + v.size() * 98 / 100, v.end());
            hi = v[v.size() * 98 / 100];
        }
        const float span = hi > lo ? hi - lo : 1.0f;
        for (std::size_t i = 0; i < img.pixel_count(); ++i)
            bytes[i * nb + band] = static_cast<uint8_t>(std::clamp((d[i] - lo) / span * 255.0f + 0.5f, 0.0f, 255.0f));
    }

    Quicklook q;
    q.png = encode_png(bytes, w, h, nb, path);
    const MapPoint tl = gt.pixel_to_map({double(c0), double(r0)}), br = gt.pixel_to_map({double(c1), double(r1)});
    q.extent = {std::min(tl.x, br.x), std::min(tl.y, br.y), std::max(tl.x, br.x), std::max(tl.y, br.y)};
    q.width = w, q.height = h;
    return q;
}

}  // namespace cityforge
