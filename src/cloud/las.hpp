#pragma once
// ASPRS LAS 1.0–1.4 reading (point formats 0–10) and LAS 1.4 writing (format
// 7: xyz, intensity, returns, class, GPS time, RGB). Our own code: Debian 12
// has neither PDAL nor LASzip. Reads are streamed in chunks.
#include <array>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <vector>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include "cloud/laz_decoder.hpp"
#include "cloud/point_cloud.hpp"
#include "core/random_access_file.hpp"

namespace cityforge {

/// The CRS records of a LAS file, raw (interpreted by resolve_cloud_crs in
/// io/cloud_crs.hpp, which holds the order of precedence).
struct LasCrsRecords {
    std::string wkt;                         ///< OGC WKT, LASF_Projection 2112 VLR
    std::string evlr_wkt;                    ///< OGC WKT, LASF_Projection 2112 extended VLR (LAS 1.4)
    std::string liblas_wkt;                  ///< libLAS's older "liblas" 2112 VLR
    std::vector<uint16_t> geokey_directory;  ///< LASF_Projection 34735, as unsigned shorts
    std::vector<double> geo_double_params;   ///< LASF_Projection 34736
    std::string geo_ascii_params;            ///< LASF_Projection 34737
    bool wkt_bit = false;                    ///< global encoding bit 4: the WKT is the CRS
    bool empty() const { return wkt.empty() && evlr_wkt.empty() && liblas_wkt.empty() && geokey_directory.empty(); }
};

/// The public header block fields we use, plus what the VLRs told us.
/// The text of a fixed-length LAS field of `n` bytes at `p` (system identifier,
/// VLR user id, WKT record): up to the first NUL, trailing spaces and NULs
/// dropped. `n` = 0 (an empty record) gives "" without reading `p`.
std::string las_text(const char* p, std::size_t n);

struct LasHeader {
    int version_major = 1;
    int version_minor = 4;
    int point_format = 7;          ///< 0..10
    int point_record_length = 36;  ///< bytes, >= the format's minimum
    uint32_t offset_to_points = 0;
    uint64_t point_count = 0;
    std::array<double, 3> scale{0.01, 0.01, 0.01};
    std::array<double, 3> offset{0.0, 0.0, 0.0};
    std::array<double, 3> min{0.0, 0.0, 0.0};  ///< from the header (not recomputed)
    std::array<double, 3> max{0.0, 0.0, 0.0};
    std::string system_identifier;
    std::string generating_software;
    LasCrsRecords crs;               ///< the CRS records as stored (VLRs and EVLRs)
    uint16_t header_size = 0;         ///< bytes of the public header block
    uint32_t vlr_count = 0;
    uint64_t evlr_offset = 0;         ///< LAS 1.4: start of the first EVLR (0 = none)
    uint32_t evlr_count = 0;
    std::optional<LazInfo> laz;      ///< LASzip VLR, when the points are LAZ-compressed
    bool has_color() const;
    bool has_gps_time() const;
};

/// True when `pred(i)` holds for some i in [begin, end): the screens of the
/// readers (points out of bounds, NaN coordinates) check a chunk in parallel
/// blocks and compact it only when one holds.
template <class Pred>
bool any_point(std::size_t begin, std::size_t end, Pred&& pred) {
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(begin, end, 1u << 15), false,
        [&](const tbb::blocked_range<std::size_t>& r, bool found) {
            for (std::size_t i = r.begin(); i != r.end() && !found; ++i) found = pred(i);
            return found;
        },
        [](bool a, bool b) { return a || b; });
}

/// Minimum record length of LAS point format `format` (0..10); throws otherwise.
int las_min_record_length(int format);

/// Streams points from a LAS or LAZ file (LAZ decoded by laz_decoder.hpp,
/// chunks in parallel, handed out in file order). Validates the header on
/// open: throws Error naming the file for a missing file, a non-LAS file, an
/// unsupported LAZ variant, an unknown point format, a bad scale or a point
/// count the file cannot hold.
class LasReader {
public:
    explicit LasReader(const std::string& path);
    /// The same from a file already opened (CloudReader, which looked at its
    /// first bytes to choose the format, hands over that open file: the
    /// format, header and records all come from one descriptor).
    explicit LasReader(RandomAccessFile file);
    ~LasReader();
    LasReader(const LasReader&) = delete;
    LasReader& operator=(const LasReader&) = delete;
    const LasHeader& header() const { return header_; }
    /// Appends up to `max_points` points to `out`; returns how many were read
    /// (0 at the end). Throws Error on a truncated file or a read error,
    /// leaving `out` as it was before the call (its points and which
    /// attributes it holds); the reader is not to be used after it threw.
    /// A reader is used either through read_chunk or through read_records
    /// (LAZ: read_chunk skips the layers a PointCloud does not hold).
    std::size_t read_chunk(PointCloud& out, std::size_t max_points);
    /// Replaces `records` with up to `max_points` raw point records
    /// (point_record_length bytes each, as stored in an uncompressed LAS,
    /// decoded for LAZ); returns how many (0 at the end).
    std::size_t read_records(std::vector<char>& records, std::size_t max_points);
    /// The same into the caller's memory (room for max_points x
    /// point_record_length bytes): a reused buffer costs no zero-filling,
    /// page faults or copy.
    std::size_t read_records(char* out, std::size_t max_points);
    uint64_t points_remaining() const { return total_ - read_; }
    /// Points worth reserving before reading the rest: points_remaining() for
    /// an uncompressed file (its size was checked against the count on open),
    /// at most 2^24 for LAZ (whose header may claim any count).
    std::size_t reserve_hint() const;
    /// The open file the header and points come from (COPC's hierarchy is read from it too).
    const RandomAccessFile& file() const { return file_; }
    /// LAZ only: the chunk decoder (chunk table, chunk selection); null for LAS.
    LazPointSource* laz_source() { return laz_.get(); }
    /// LAZ only, before the first read: decode only the chunks with keep[i].
    void select_laz_chunks(const std::vector<bool>& keep);
    /// Uncompressed LAS only, before the first read: read_chunk hands out
    /// only the points with min_x <= x <= max_x and min_y <= y <= max_y (file
    /// units; closed, so a superset of a caller's half-open box), in file
    /// order; the others are decoded but not stored (a small window of a
    /// large file costs no copy of the whole file's points). The bounds
    /// screen counts and drops as before. Ignored for LAZ (see select_laz_chunks).
    void restrict_to_box(double min_x, double min_y, double max_x, double max_y);
    /// Points read_chunk dropped so far because they lie outside the header's
    /// bounds (by more than one scale quantum): records a corrupt VLR shifted,
    /// or garbage. Screened only when the header bounds are usable (finite,
    /// min <= max, not all zero). At the end of the file a warning names the
    /// file and the count; if every point was outside, read_chunk throws.
    uint64_t dropped_outside_bounds() const { return dropped_outside_; }
    /// The screen read_chunk applies to each point (coordinates in the
    /// file's units): true when the header's bounds are usable and the point
    /// lies beyond them by more than one scale quantum.
    bool outside_bounds(double x, double y, double z) const {
        if (!screen_bounds_) return false;
        const double v[3] = {x, y, z};
        for (int k = 0; k < 3; ++k)
            if (v[k] < header_.min[k] - bounds_tolerance_[k] || v[k] > header_.max[k] + bounds_tolerance_[k]) return true;
        return false;
    }
    /// For a caller that screens raw records (read_records) with
    /// outside_bounds itself: adds `points` screened, `dropped` of them
    /// outside, to dropped_outside_bounds(); `points` = 0 marks the end of the
    /// file and gives read_chunk's end-of-file warning (or its error when
    /// every point was outside).
    void account_screened(uint64_t points, uint64_t dropped);

private:
    void report_end();
    std::size_t read_chunk_unscreened(PointCloud& out, std::size_t max_points);
    /// Decodes the next `n` records (LAZ: already in buffer_) onto the end of `out`.
    void append_records(PointCloud& out, std::size_t n);
    /// restrict_to_box's read: decodes the next `n` records of an
    /// uncompressed file and appends those in box_ and inside the header's
    /// bounds; returns how many it appended, and adds those outside the
    /// bounds to `dropped`. Throws leaving `out` as it was.
    std::size_t append_records_in_box(PointCloud& out, std::size_t n, uint64_t& dropped);
    /// Uncompressed files: records per block of read_record_blocks (~256 kB).
    std::size_t record_block() const;
    /// Uncompressed files: the next `n` records (from read_) in blocks of
    /// record_block(), each read with pread into its task's buffer and
    /// handed to visit(records, first, count, block) in parallel (first =
    /// index of its first record among the n). A block the file no longer
    /// holds throws "truncated point records". Does not advance read_.
    template <class Visit>
    void read_record_blocks(std::size_t n, const Visit& visit) const;
    /// n records (n <= points_remaining()) into `out`.
    std::size_t read_into(char* out, std::size_t n);
    std::string path_;
    /// The file, opened once: header, VLRs, EVLRs and records (LAS: read by
    /// several threads at once; LAZ: by laz_, which borrows it and is
    /// destroyed first) all come from this descriptor.
    RandomAccessFile file_;
    LasHeader header_;
    uint64_t read_ = 0;
    uint64_t total_ = 0;  ///< points this reader hands out (all, or the selected chunks')
    std::vector<char> buffer_;
    std::unique_ptr<LazPointSource> laz_;
    bool screen_bounds_ = false, end_reported_ = false;
    bool chunk_has_outside_ = false;  ///< the last chunk read_chunk_unscreened decoded has a point outside_bounds
    std::array<double, 3> bounds_tolerance_{};
    std::optional<std::array<double, 4>> box_;  ///< restrict_to_box's (min_x, min_y, max_x, max_y)
    uint64_t dropped_outside_ = 0, screened_ = 0;
};

/// Reads the whole file into memory (explicit: callers that know it fits).
PointCloud read_las(const std::string& path, LasHeader* header = nullptr);

/// Bounds and return counts of point records, as a LAS header keeps them.
struct LasRecordStats {
    std::array<double, 3> min{HUGE_VAL, HUGE_VAL, HUGE_VAL};     ///< of the coordinates as stored (scale grid)
    std::array<double, 3> max{-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    std::array<uint64_t, 15> by_return{};                        ///< points with return number 1..15
    void add(const LasRecordStats& o);
};

/// Streams points into a LAS 1.4 point-format-7 file. The file appears under
/// `path` only after close() succeeds (temporary file + rename); a writer
/// destroyed without close() removes its temporary file.
class LasWriter {
public:
    /// `scale`/`offset` define the integer grid (e.g. 0.001 m); `crs_wkt` is
    /// stored as an OGC WKT VLR (empty = no CRS).
    LasWriter(const std::string& path, const std::array<double, 3>& scale, const std::array<double, 3>& offset,
              const std::string& crs_wkt, const std::string& generating_software = "cityforge");
    ~LasWriter();
    LasWriter(const LasWriter&) = delete;
    LasWriter& operator=(const LasWriter&) = delete;

    /// Appends all points of `cloud` (colour written as 0 when it has none).
    void write(const PointCloud& cloud);
    /// Appends `n` point-format-7 records of 36 bytes encoded on this
    /// writer's scale and offset (as write and split_las_into_windows encode
    /// them); the header's bounds and return counts are taken from them (a
    /// record with return number 0, invalid in LAS 1.4, is in no return's count).
    void write_records(const char* records, std::size_t n);
    /// Finishes the header (counts, bounds) and moves the file into place.
    void close();
    uint64_t points_written() const { return count_; }

private:
    std::string path_;
    std::string tmp_path_;
    std::ofstream out_;
    std::array<double, 3> scale_, offset_;
    LasRecordStats stats_;
    std::vector<char> buffer_;  ///< encoded records of write(), reused
    uint64_t count_ = 0;
    uint32_t offset_to_points_ = 0;
    bool closed_ = false;
};

/// One streaming pass over a LAS or LAZ file writes the points inside each
/// window {min_x, min_y, max_x, max_y} (min_x <= x < max_x, min_y <= y <
/// max_y, file units; windows may overlap and a point goes to each that
/// holds it) to out_paths[w], a LasWriter file on the source's scale and
/// offset with `crs_wkt`, in file order. The files hold the same bytes as
/// reading the source with read_chunk (its bounds screen included) and
/// writing each window's points with LasWriter::write, but the records are
/// re-encoded straight from the source's, in parallel, without a
/// PointCloud, `chunk_points` at a time (memory: about 100 bytes each).
/// Returns each window's point count.
std::vector<uint64_t> split_las_into_windows(const std::string& path, const std::vector<std::array<double, 4>>& windows,
                                             const std::vector<std::string>& out_paths, const std::string& crs_wkt,
                                             std::size_t chunk_points = std::size_t(1) << 21);

}  // namespace cityforge
