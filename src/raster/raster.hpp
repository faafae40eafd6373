#pragma once
// Georeferenced raster I/O through GDAL: metadata, windowed (block) reads and
// tiled, compressed GeoTIFF writes that keep the source georeferencing.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/geo_transform.hpp"
#include "core/image.hpp"
#include "crs/crs.hpp"

namespace cityforge {

/// Sample types we read and write. `other` marks a type we refuse to process
/// (complex numbers, for example) but can still describe.
enum class SampleType { byte, uint16, int16, uint32, int32, float32, float64, other };
std::string to_string(SampleType t);

struct RasterBandInfo {
    SampleType type = SampleType::byte;
    std::optional<double> nodata;  ///< nodata value in the band's units, if set
    std::string color_interpretation;  ///< "Red", "Gray", "Undefined", ...
    std::string description;
};

/// Everything we learn from a raster's header, without reading pixels.
struct RasterInfo {
    std::string path;
    std::string driver;          ///< GDAL short name, e.g. "GTiff"
    int width = 0;               ///< columns
    int height = 0;              ///< rows
    int block_width = 0;         ///< natural block size of band 1
    int block_height = 0;
    std::vector<RasterBandInfo> bands;
    bool georeferenced = false;  ///< false only when opened with allow_pixel_coordinates
    GeoTransform transform;      ///< identity-like (1, -1) when not georeferenced
    CrsInfo crs;                 ///< horizontal (+ vertical) CRS of the grid read (the working CRS when warped)
    GroundSampleDistance gsd;    ///< ground metres per pixel along x and y at the centre
    double metres_per_unit = 1.0;  ///< ground metres per CRS unit at the centre (ground_metres_per_unit; 0 = geographic)
    Extent extent;               ///< in CRS units
    /// True when the file is read through a warped grid (RasterOpenOptions::
    /// project_geographic / working_crs); `source_crs` is then the file's CRS.
    bool warped = false;
    CrsInfo source_crs;          ///< the file's own CRS (same as `crs` when not warped)
    /// 1-based last band when GDAL reads it as alpha (ColorInterp=Alpha): a
    /// mask, not a colour. 0 = none. A warped grid always has one (the warper's
    /// alpha: 0 outside the file).
    int alpha_band = 0;
    /// GDAL has a per-dataset mask for the pixels (an alpha band, an internal
    /// or external .msk mask band): read_mask() reads it.
    bool masked = false;

    int band_count() const { return static_cast<int>(bands.size()); }
};

struct RasterOpenOptions {
    /// Accept a raster without geotransform/CRS and use pixel coordinates
    /// (x = column, y = -row, GSD 1 m). Off by default: such rasters are refused.
    bool allow_pixel_coordinates = false;
    /// CRS to assume (or override with) when the raster has none; any
    /// SetFromUserInput text ("EPSG:32616"). Empty = use the file's.
    std::string assume_crs;
    /// Read a raster in a geographic CRS (lon/lat) through a warped grid in
    /// a local projected CRS: the UTM zone of its centre (or `working_crs`),
    /// bilinear, about the same number of pixels. Commands that measure in
    /// metres (footprints, run) set it; `info` and `segment` describe and
    /// label the file's own grid.
    bool project_geographic = false;
    /// Read the raster warped onto this CRS ("EPSG:32723"), whatever its own
    /// CRS (empty = its own, or UTM for a geographic one with project_geographic).
    std::string working_crs;
};

/// A pixel window: columns [col, col + width), rows [row, row + height).
struct PixelWindow {
    int col = 0;
    int row = 0;
    int width = 0;
    int height = 0;
};

/// An open raster. Reads are windowed so a 40,000 x 40,000 tile never has to
/// be loaded whole. Not thread-safe: open one reader per thread.
class RasterReader {
public:
    /// Opens and validates `path`. Throws Error naming the file when it is
    /// missing, not a raster, has no bands, no georeferencing (unless allowed)
    /// or a rotated geotransform.
    explicit RasterReader(const std::string& path, const RasterOpenOptions& options = {});
    ~RasterReader();
    RasterReader(RasterReader&&) noexcept;
    RasterReader& operator=(RasterReader&&) noexcept;

    const RasterInfo& info() const { return info_; }

    /// Reads `window` of the 1-based `bands` (all bands when empty) converted
    /// to T (uint8_t, uint16_t, int16_t, uint32_t, float or double). Throws
    /// Error naming the file when the window is outside the raster or the data
    /// cannot be decoded.
    template <typename T>
    Image<T> read(const PixelWindow& window, const std::vector<int>& bands = {}) const;

    /// Reads `window` resampled to out_width x out_height pixels (GDAL's
    /// RasterIO resampling: "nearest", "bilinear", "cubic" or "average").
    template <typename T>
    Image<T> read_resampled(const PixelWindow& window, int out_width, int out_height, const std::vector<int>& bands,
                            const std::string& resampling) const;

    /// Reads the whole raster (explicit, for callers that know it fits).
    template <typename T>
    Image<T> read_all(const std::vector<int>& bands = {}) const {
        return read<T>(PixelWindow{0, 0, info_.width, info_.height}, bands);
    }

    /// Validity of `window` from GDAL's per-dataset mask (alpha band >= 50 %,
    /// internal or external mask band != 0): 1 = data, 0 = masked; all 1 when
    /// the raster has none (nodata values are data_mask's). Throws Error
    /// naming the file when the mask cannot be read.
    std::vector<uint8_t> read_mask(const PixelWindow& window) const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
    RasterInfo info_;
};

/// Data mask of an image read from the raster `info` describes: 0 where any
/// image band holds its source band's nodata value, else 1. `bands` = the
/// 1-based source band of each image band (empty: image band k is band k+1).
std::vector<uint8_t> data_mask(const Image<float>& image, const RasterInfo& info, const std::vector<int>& bands = {});

/// The 1-based bands holding image values: every band but the alpha band.
std::vector<int> image_bands(const RasterInfo& info);

/// data_mask() of `image` (read from `bands` over `window`) and the reader's
/// per-dataset mask (alpha, mask band): 1 where both say data.
std::vector<uint8_t> valid_pixels(const RasterReader& reader, const PixelWindow& window, const Image<float>& image,
                                  const std::vector<int>& bands);

/// The working CRS for a raster `info` describes (in its own CRS): `working_crs`
/// when given, else the UTM zone of its centre when it is geographic, else its
/// own CRS. Every command that needs metres on a lon/lat input uses it.
CrsInfo working_crs_for(const RasterInfo& info, const std::string& working_crs = {});

/// Convenience: open `path` and return its header information.
RasterInfo read_raster_info(const std::string& path, const RasterOpenOptions& options = {});

/// Options of a GeoTIFF write.
struct GeoTiffWriteOptions {
    std::optional<double> nodata;           ///< written to every band when set
    std::string compression = "DEFLATE";    ///< GDAL COMPRESS= value ("NONE" allowed)
    int block_size = 256;                   ///< tile edge in pixels (multiple of 16)
    std::vector<std::string> band_descriptions;  ///< optional, one per band
    bool rgb = false;                       ///< mark 3 Byte bands as RGB (PHOTOMETRIC=RGB)
};

/// Writes `image` as a tiled, compressed GeoTIFF with the given georeferencing
/// (transform + CRS WKT; an empty WKT writes no CRS). The file appears only
/// when complete (temporary file + rename). Supported T: uint8_t, uint16_t,
/// int16_t, uint32_t, float, double.
template <typename T>
void write_geotiff(const std::string& path, const Image<T>& image, const GeoTransform& transform,
                   const std::string& crs_wkt, const GeoTiffWriteOptions& options = {});

/// A GDAL VRT mosaic of rasters that share a grid and CRS (e.g. the tiles of
/// a run). Throws Error naming `path` when GDAL cannot build it.
void build_vrt_mosaic(const std::string& path, const std::vector<std::string>& parts);

}  // namespace cityforge
