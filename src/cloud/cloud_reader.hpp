#pragma once
// Point cloud readers behind one interface: LAS and LAZ/COPC (las.hpp), PLY (ASCII and
// binary, x/y/z plus optional colour, classification, intensity) and XYZ/CSV
// text. Streamed in chunks. No GDAL here: the CRS records the file carries
// are passed on raw; resolve_cloud_crs (io/cloud_crs.hpp) interprets them.
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "cloud/las.hpp"
#include "cloud/point_cloud.hpp"

namespace cityforge {

enum class CloudFormat { las, ply, xyz };
std::string to_string(CloudFormat f);

/// One format's streaming reader.
class CloudFormatReader {
public:
    virtual ~CloudFormatReader() = default;
    /// Appends up to `max_points` points to `out`; returns how many (0 = end).
    virtual std::size_t read_chunk(PointCloud& out, std::size_t max_points) = 0;
    /// Points worth reserving before reading everything (0 = unknown).
    virtual std::size_t reserve_hint() const { return 0; }
    /// See CloudReader::restrict_to_box; the default reads everything.
    virtual void restrict_to_box(double /*min_x*/, double /*min_y*/, double /*max_x*/, double /*max_y*/) {}
};

/// Opens `path` by its content (LAS signature, "ply" magic) or extension
/// (.xyz, .txt, .csv, .pts). Throws Error naming the file on a missing file,
/// unknown format or bad header.
class CloudReader {
public:
    explicit CloudReader(const std::string& path);
    ~CloudReader();
    CloudReader(CloudReader&&) noexcept;
    CloudReader& operator=(CloudReader&&) noexcept;

    CloudFormat format() const { return format_; }
    const std::string& path() const { return path_; }
    /// CRS records stored in the file (LAS VLRs/EVLRs); empty for PLY/XYZ or when absent.
    const LasCrsRecords& crs_records() const { return crs_records_; }
    /// Point count announced by the header (LAS, PLY); 0 when unknown (XYZ).
    uint64_t announced_points() const { return announced_; }
    /// The header's x/y bounds {min_x, min_y, max_x, max_y} (LAS, file CRS
    /// units; points outside them are dropped when read); empty for PLY/XYZ.
    const std::optional<std::array<double, 4>>& announced_bounds() const { return announced_bounds_; }
    /// Appends up to `max_points` points to `out`; returns how many (0 = end).
    /// Points with a NaN or infinite x, y or z (PLY and XYZ may hold them, e.g.
    /// PCL's organized clouds) are dropped, and so are LAS points outside the
    /// header's bounds (LasReader::dropped_outside_bounds). At the end one
    /// warning names the file and the count of each; if no point is left,
    /// this throws Error naming the file.
    std::size_t read_chunk(PointCloud& out, std::size_t max_points);
    /// Points dropped so far for a NaN or infinite coordinate.
    uint64_t dropped_non_finite() const { return dropped_non_finite_; }
    /// True for a COPC file (LAZ with the COPC info VLR and hierarchy).
    bool copc() const { return copc_; }
    /// A hint before the first read: the caller keeps only points with
    /// min_x <= x < max_x, min_y <= y < max_y (file CRS). COPC files then
    /// decode only the octree nodes whose cube meets the box; layered LAZ
    /// (point formats 6-8) only the chunks whose XY layer has a point in it;
    /// uncompressed LAS only the points in the closed box (all of them when
    /// the header's bounds lie inside it); other formats still hand out
    /// every point (the caller filters).
    void restrict_to_box(double min_x, double min_y, double max_x, double max_y) { impl_->restrict_to_box(min_x, min_y, max_x, max_y); }
    /// Before reading everything into `cloud`: reserves room for its points
    /// and those the file certainly holds (an uncompressed LAS: all of them),
    /// so the cloud is not copied as it grows.
    void reserve_for_all(PointCloud& cloud) const;

private:
    std::string path_;
    CloudFormat format_ = CloudFormat::las;
    LasCrsRecords crs_records_;
    uint64_t announced_ = 0;
    std::optional<std::array<double, 4>> announced_bounds_;
    bool copc_ = false;
    bool color_ = false, gps_ = false;  ///< LAS: the point format holds colour / GPS time
    bool end_reported_ = false;
    uint64_t dropped_non_finite_ = 0, seen_ = 0;
    std::unique_ptr<CloudFormatReader> impl_;
};

/// Reads every point (explicit: callers that know it fits). Throws Error
/// naming the file if it holds no point at all.
PointCloud read_point_cloud(const std::string& path);

/// Reads only the points with min_x <= x < max_x and min_y <= y < max_y (file
/// CRS), streaming, so memory follows the box, not the file. May return an
/// empty cloud.
PointCloud read_point_cloud_in(const std::string& path, double min_x, double min_y, double max_x, double max_y);
/// The same points appended to `out` (its points and attributes stay first):
/// the parts of a window read into one cloud without copying it. Throws
/// Error naming the file when it cannot be read or when its points carry
/// other attributes (colour, GPS time) than `out`'s points in a way that
/// cannot be aligned (a PLY or text file without colour after parts with it;
/// a LAS file with colour after parts without gives them zeros); `out` is
/// then as it was before the call.
void append_point_cloud_in(const std::string& path, double min_x, double min_y, double max_x, double max_y, PointCloud& out);

}  // namespace cityforge
