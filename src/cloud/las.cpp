#include "cloud/las.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <vector>
#include <sys/mman.h>
#include <tbb/parallel_for.h>

#include "core/atomic_file.hpp"
#include "cloud/le_bytes.hpp"
#include "core/error.hpp"
#include "core/log.hpp"

namespace cityforge {
namespace {

using bytes::get;
using bytes::put;

std::string format_double(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.6g", v);
    return b;
}

// Where a point format keeps the fields a PointCloud holds.
struct RecordLayout {
    bool extended, gps, color;
    int class_offset, gps_offset, rgb;
    explicit RecordLayout(const LasHeader& h)
        : extended(h.point_format >= 6), gps(h.has_gps_time()), color(h.has_color()), class_offset(extended ? 16 : 15),
          gps_offset(extended ? 22 : 20), rgb(rgb_offsets[h.point_format]) {}
    // Offset of the RGB triplet within the record for each format.
    static constexpr int rgb_offsets[] = {-1, -1, 20, 28, -1, 28, -1, 30, 30, -1, 30};
};

// One point's fields as read_chunk hands them out (gps_time and colour only
// when the format has them).
struct LasPoint {
    double x = 0, y = 0, z = 0, gps_time = 0;
    uint16_t intensity = 0, red = 0, green = 0, blue = 0;
    uint8_t return_number = 1, number_of_returns = 1, classification = 1;
};

inline double las_coordinate(const char* p, const LasHeader& h, int k) { return get<int32_t>(p + 4 * k) * h.scale[k] + h.offset[k]; }

// The one decoding of a record (read_chunk and split_las_into_windows).
inline LasPoint decode_record(const char* p, const LasHeader& h, const RecordLayout& l) {
    LasPoint q;
    q.x = las_coordinate(p, h, 0), q.y = las_coordinate(p, h, 1), q.z = las_coordinate(p, h, 2);
    q.intensity = get<uint16_t>(p + 12);
    const auto bits = static_cast<uint8_t>(p[14]);
    q.return_number = static_cast<uint8_t>(l.extended ? (bits & 0x0F) : (bits & 0x07));
    q.number_of_returns = static_cast<uint8_t>(l.extended ? bits >> 4 : (bits >> 3) & 0x07);
    const auto cls = static_cast<uint8_t>(p[l.class_offset]);
    q.classification = static_cast<uint8_t>(l.extended ? cls : (cls & 0x1F));
    if (l.gps) q.gps_time = get<double>(p + l.gps_offset);
    if (l.color) q.red = get<uint16_t>(p + l.rgb), q.green = get<uint16_t>(p + l.rgb + 2), q.blue = get<uint16_t>(p + l.rgb + 4);
    return q;
}

constexpr int kHeaderSize = 375;
constexpr int kRecordLength = 36;  // point format 7

// The one encoding of a point-format-7 record (LasWriter::write and
// split_las_into_windows): all 36 bytes at `p` written.
inline void encode_record7(char* p, const LasPoint& q, bool gps, bool color, const std::array<double, 3>& scale,
                           const std::array<double, 3>& offset, const std::string& path) {
    std::memset(p, 0, kRecordLength);
    const double xyz[3] = {q.x, q.y, q.z};
    for (int k = 0; k < 3; ++k) {
        const double v = std::round((xyz[k] - offset[k]) / scale[k]);
        if (v < std::numeric_limits<int32_t>::min() || v > std::numeric_limits<int32_t>::max())
            throw Error(path, "coordinate out of range for the LAS scale/offset");
        bytes::store<int32_t>(p + 4 * k, static_cast<int32_t>(v));
    }
    bytes::store<uint16_t>(p + 12, q.intensity);
    const uint8_t rn = std::clamp<uint8_t>(q.return_number, 1, 15), nr = std::clamp<uint8_t>(q.number_of_returns, 1, 15);
    p[14] = static_cast<char>(rn | (nr << 4));
    p[16] = static_cast<char>(q.classification);
    if (gps) bytes::store<double>(p + 22, q.gps_time);
    if (color) bytes::store<uint16_t>(p + 30, q.red), bytes::store<uint16_t>(p + 32, q.green), bytes::store<uint16_t>(p + 34, q.blue);
}

}  // namespace

void LasRecordStats::add(const LasRecordStats& o) {
    for (int k = 0; k < 3; ++k) min[k] = std::min(min[k], o.min[k]), max[k] = std::max(max[k], o.max[k]);
    for (int r = 0; r < 15; ++r) by_return[r] += o.by_return[r];
}

std::string las_text(const char* p, std::size_t n) {
    if (n == 0 || p == nullptr) return {};
    std::string s(p, strnlen(p, n));
    while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
    return s;
}

void PointCloud::truncate(std::size_t n) {
    for (auto* v : {&x, &y, &z, &gps_time}) v->resize(std::min(v->size(), n));
    for (auto* v : {&intensity, &red, &green, &blue}) v->resize(std::min(v->size(), n));
    for (auto* v : {&classification, &return_number, &number_of_returns}) v->resize(std::min(v->size(), n));
}

void PointCloud::grow(std::size_t n, bool color, bool gps) {
    const std::size_t to = size() + n;
    reserve(to, color, gps);
    for (auto* v : {&x, &y, &z}) v->resize(to);
    intensity.resize(to);
    for (auto* v : {&classification, &return_number, &number_of_returns}) v->resize(to);
    if (gps) gps_time.resize(to);
    if (color) red.resize(to), green.resize(to), blue.resize(to);
}

void PointCloud::roll_back(const Mark& m) {
    truncate(m.size);
    if (!m.gps_time) gps_time.clear();
    if (!m.color) red.clear(), green.clear(), blue.clear();
}

void PointCloud::clear() {
    for (auto* v : {&x, &y, &z, &gps_time}) v->clear();
    for (auto* v : {&intensity, &red, &green, &blue}) v->clear();
    for (auto* v : {&classification, &return_number, &number_of_returns}) v->clear();
}

void PointCloud::append(const PointCloud& src, std::size_t i) {
    x.push_back(src.x[i]), y.push_back(src.y[i]), z.push_back(src.z[i]);
    intensity.push_back(src.intensity[i]), classification.push_back(src.classification[i]);
    return_number.push_back(src.return_number[i]), number_of_returns.push_back(src.number_of_returns[i]);
    if (src.has_gps_time()) gps_time.push_back(src.gps_time[i]);
    if (src.has_color()) red.push_back(src.red[i]), green.push_back(src.green[i]), blue.push_back(src.blue[i]);
}

namespace {
// Marks the whole 2 MiB pages inside a fresh block of `v`'s capacity for
// transparent huge pages (a hint, as LargeBufferAllocator gives): a cloud of
// 127 M points first touches ~5.5 GB, 1.3 M page faults on 4 kB pages.
template <class V>
void advise_huge_pages(const V& v) {
    constexpr std::uintptr_t huge = std::uintptr_t(2) << 20;
    const auto first = (reinterpret_cast<std::uintptr_t>(v.data()) + huge - 1) & ~(huge - 1);
    const auto last = (reinterpret_cast<std::uintptr_t>(v.data() + v.capacity())) & ~(huge - 1);
    if (last > first) ::madvise(reinterpret_cast<void*>(first), last - first, MADV_HUGEPAGE);
}
}  // namespace

void PointCloud::reserve(std::size_t n, bool color, bool gps) {
    // Grow geometrically: readers call this once per chunk.
    if (n <= x.capacity() && (!color || n <= red.capacity()) && (!gps || n <= gps_time.capacity())) return;
    n = std::max(n, 2 * x.capacity());
    auto grow = [n](auto& v) {
        if (n <= v.capacity()) return;
        v.reserve(n);
        advise_huge_pages(v);
    };
    grow(x), grow(y), grow(z), grow(intensity);
    grow(classification), grow(return_number), grow(number_of_returns);
    if (gps) grow(gps_time);
    if (color) grow(red), grow(green), grow(blue);
}

int las_min_record_length(int format) {
    static constexpr int lengths[] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
    if (format < 0 || format > 10) throw Error("unknown LAS point format " + std::to_string(format));
    return lengths[format];
}

bool LasHeader::has_color() const {
    return point_format == 2 || point_format == 3 || point_format == 5 || point_format == 7 || point_format == 8 ||
           point_format == 10;
}
bool LasHeader::has_gps_time() const { return point_format != 0 && point_format != 2; }

LasReader::LasReader(const std::string& path) : LasReader(RandomAccessFile(path, "a point cloud file")) {}

LasReader::LasReader(RandomAccessFile file) : path_(file.path()), file_(std::move(file)) {
    const std::string& path = path_;
    const uint64_t file_size = file_.size();
    char hdr[375] = {};
    const std::size_t got = file_.read_at(0, hdr, sizeof hdr);
    if (got == 0) throw Error(path, "empty file (0 bytes), not a LAS file");
    if (got < 4 || std::memcmp(hdr, "LASF", 4) != 0) throw Error(path, "not a LAS file (no LASF signature)");
    if (got < 227) throw Error(path, "truncated LAS header: the file ends after " + std::to_string(got) + " bytes, a header needs at least 227");
    LasHeader& h = header_;
    h.version_major = static_cast<uint8_t>(hdr[24]);
    h.version_minor = static_cast<uint8_t>(hdr[25]);
    if (h.version_major != 1 || h.version_minor > 4)
        throw Error(path, "unsupported LAS version " + std::to_string(h.version_major) + "." + std::to_string(h.version_minor));
    h.system_identifier = las_text(hdr + 26, 32);
    h.generating_software = las_text(hdr + 58, 32);
    h.crs.wkt_bit = (get<uint16_t>(hdr + 6) & 0x10) != 0;
    const auto header_size = get<uint16_t>(hdr + 94);
    h.offset_to_points = get<uint32_t>(hdr + 96);
    const auto n_vlr = get<uint32_t>(hdr + 100);
    const auto raw_format = static_cast<uint8_t>(hdr[104]);
    const bool compressed = (raw_format & 0xC0) != 0;  // LASzip sets bit 7 (old writers bit 6)
    h.point_format = raw_format & 0x3F;
    if (h.point_format > 10) throw Error(path, "unknown LAS point format " + std::to_string(h.point_format));
    h.point_record_length = get<uint16_t>(hdr + 105);
    if (h.point_record_length < las_min_record_length(h.point_format))
        throw Error(path, "point record length " + std::to_string(h.point_record_length) + " is too short for point format " +
                              std::to_string(h.point_format));
    h.point_count = get<uint32_t>(hdr + 107);
    for (int i = 0; i < 3; ++i) {
        h.scale[i] = get<double>(hdr + 131 + 8 * i);
        h.offset[i] = get<double>(hdr + 155 + 8 * i);
        h.max[i] = get<double>(hdr + 179 + 16 * i);
        h.min[i] = get<double>(hdr + 187 + 16 * i);
    }
    // Scales outside [1e-12, 1e4] and offsets beyond 1e12 are no real survey's
    // (0.01 m, 1e-7 degree, 1 m are); they would turn every record into a
    // coordinate nothing downstream can grid.
    for (double s : h.scale)
        if (!(s >= 1e-12 && s <= 1e4))
            throw Error(path, "coordinate scale factor " + format_double(s) + " in the LAS header is outside [1e-12, 1e4] (corrupt header)");
    for (double o : h.offset)
        if (!(std::abs(o) <= 1e12)) throw Error(path, "coordinate offset " + format_double(o) + " in the LAS header is not a finite value within 1e12 (corrupt header)");
    if (h.version_minor >= 4 && header_size >= 375 && got >= 375) {
        const auto count64 = get<uint64_t>(hdr + 247);
        if (count64 != 0 || h.point_count == 0) h.point_count = count64;
    }
    h.header_size = header_size;
    h.vlr_count = n_vlr;
    if (h.version_minor >= 4 && header_size >= 375 && got >= 375) {
        h.evlr_offset = get<uint64_t>(hdr + 235);
        h.evlr_count = get<uint32_t>(hdr + 243);
    }
    if (header_size < 227 || h.offset_to_points < header_size || h.offset_to_points > file_size)
        throw Error(path, "corrupt LAS header (header size / offset to point data)");

    // VLRs: look for the CRS (OGC WKT 2112, GeoKeyDirectory 34735).
    uint64_t pos = header_size;
    for (uint32_t i = 0; i < n_vlr && pos + 54 <= h.offset_to_points; ++i) {
        char vh[54];
        if (!file_.read_exact_at(pos, vh, 54)) throw Error(path, "truncated variable length record header");
        const std::string user = las_text(vh + 2, 16);
        const auto record_id = get<uint16_t>(vh + 18);
        const auto length = get<uint16_t>(vh + 20);
        if (pos + 54 + length > h.offset_to_points) throw Error(path, "variable length record runs past the point data");
        if (user == "LASF_Projection" || user == "liblas") {
            std::vector<char> data(length);
            if (!file_.read_exact_at(pos + 54, data.data(), length)) throw Error(path, "truncated variable length record");
            if (record_id == 2112) (user == "liblas" ? h.crs.liblas_wkt : h.crs.wkt) = las_text(data.data(), data.size());
            else if (user == "LASF_Projection" && record_id == 34735) {
                h.crs.geokey_directory.resize(length / 2);
                if (!h.crs.geokey_directory.empty())  // memcpy from an empty record's null pointer is undefined
                    std::memcpy(h.crs.geokey_directory.data(), data.data(), h.crs.geokey_directory.size() * 2);
            } else if (user == "LASF_Projection" && record_id == 34736) {
                h.crs.geo_double_params.resize(length / 8);
                if (!h.crs.geo_double_params.empty())
                    std::memcpy(h.crs.geo_double_params.data(), data.data(), h.crs.geo_double_params.size() * 8);
            } else if (user == "LASF_Projection" && record_id == 34737) {
                if (!data.empty()) h.crs.geo_ascii_params.assign(data.data(), data.size());
            }
        }
        if (compressed && user == "laszip encoded" && record_id == 22204) {
            std::vector<char> data(length);
            if (!file_.read_exact_at(pos + 54, data.data(), length)) throw Error(path, "truncated LASzip VLR");
            h.laz = parse_laszip_vlr(data, path);
        }
        pos += 54 + length;
    }
    // LAS 1.4 may keep the WKT in an extended VLR after the points.
    if (h.version_minor >= 4 && header_size >= 375) {
        uint64_t epos = get<uint64_t>(hdr + 235);
        const auto n_evlr = get<uint32_t>(hdr + 243);
        // Every bound is checked as a difference so that no length wraps the
        // position (a length near 2^64 once looped forever); each record moves
        // the position forward by at least 60 bytes, so the loop ends.
        for (uint32_t i = 0; i < n_evlr && epos <= file_size && file_size - epos >= 60; ++i) {
            char eh[60];
            if (!file_.read_exact_at(epos, eh, 60)) break;
            const std::string user = las_text(eh + 2, 16);
            const auto record_id = get<uint16_t>(eh + 18);
            const auto length = get<uint64_t>(eh + 20);
            if (length > file_size - epos - 60) throw Error(path, "extended variable length record " + std::to_string(i) + " (" + std::to_string(length) + " bytes at " + std::to_string(epos) + ") runs past the end of the file");
            if (user == "LASF_Projection" && record_id == 2112 && length < (1u << 24)) {
                std::vector<char> data(length);
                if (!file_.read_exact_at(epos + 60, data.data(), data.size())) throw Error(path, "truncated extended variable length record " + std::to_string(i));
                h.crs.evlr_wkt = las_text(data.data(), data.size());
            }
            epos += 60 + length;
        }
    }
    // The header's bounds screen the records (see read_chunk) when they are
    // usable: finite, ordered and not left all zero by the writer.
    bool bounds_set = false, bounds_ok = true;
    for (int k = 0; k < 3; ++k) {
        bounds_ok = bounds_ok && std::isfinite(h.min[k]) && std::isfinite(h.max[k]) && h.min[k] <= h.max[k];
        bounds_set = bounds_set || h.min[k] != 0.0 || h.max[k] != 0.0;
    }
    screen_bounds_ = bounds_ok && bounds_set;
    for (int k = 0; k < 3; ++k)  // one quantum: writers may bound the unrounded coordinates
        bounds_tolerance_[k] = h.scale[k] + 1e-9 * std::max(std::abs(h.min[k]), std::abs(h.max[k]));
    total_ = h.point_count;
    if (compressed) {
        if (!h.laz) throw Error(path, "LAZ-compressed points (point format byte " + std::to_string(raw_format) + ") but no LASzip VLR (laszip encoded/22204)");
        check_laz_supported(*h.laz, h.point_format, h.point_record_length, path);
        laz_ = std::make_unique<LazPointSource>(file_, *h.laz, h.offset_to_points, h.point_count, h.point_record_length);
        return;
    }
    // Compared as a quotient: point_count x record length can wrap 2^64.
    if (h.point_count > (file_size - h.offset_to_points) / static_cast<uint64_t>(h.point_record_length))
        throw Error(path, "header says " + std::to_string(h.point_count) + " points but the file holds only " +
                              std::to_string((file_size - h.offset_to_points) / h.point_record_length) + " (truncated or corrupt)");
    file_.advise_sequential();  // a hint: a larger read-ahead window
}

LasReader::~LasReader() = default;

std::size_t LasReader::reserve_hint() const {
    // An uncompressed file holds its records (checked on open); a LAZ header
    // may claim any count, so it is only trusted up to 2^24 points.
    const uint64_t left = points_remaining();
    return static_cast<std::size_t>(laz_ ? std::min<uint64_t>(left, 1u << 24) : left);
}

std::size_t LasReader::read_records(std::vector<char>& buf, std::size_t max_points) {
    if (laz_ && read_ == 0 && &buf != &buffer_) laz_->set_point_fields_only(false);
    const auto n = static_cast<std::size_t>(std::min<uint64_t>(max_points, points_remaining()));
    buf.resize(n * static_cast<std::size_t>(header_.point_record_length));
    if (n == 0) return 0;
    return read_into(buf.data(), n);
}

std::size_t LasReader::read_records(char* out, std::size_t max_points) {
    if (laz_ && read_ == 0) laz_->set_point_fields_only(false);
    const auto n = static_cast<std::size_t>(std::min<uint64_t>(max_points, points_remaining()));
    if (n == 0) return 0;
    return read_into(out, n);
}

std::size_t LasReader::read_into(char* out, std::size_t n) {
    if (laz_) {
        if (laz_->read(out, n) != n) throw Error(path_, "LAZ chunks hold fewer points than the header announces");
    } else {
        const std::size_t rl = static_cast<std::size_t>(header_.point_record_length);
        if (!file_.read_exact_at(header_.offset_to_points + read_ * rl, out, n * rl)) throw Error(path_, "truncated point records");
    }
    read_ += n;
    return n;
}

void LasReader::select_laz_chunks(const std::vector<bool>& keep) {
    if (!laz_ || read_ != 0) throw Error(path_, "chunk selection needs a LAZ file before its first read");
    laz_->select_chunks(keep);
    total_ = laz_->selected_points();
}

void LasReader::report_end() {
    if (end_reported_ || dropped_outside_ == 0) return;
    end_reported_ = true;
    const std::string what = std::to_string(dropped_outside_) + " of " + std::to_string(screened_) + " points lie outside the header's bounds";
    if (dropped_outside_ == screened_) throw Error(path_, "all " + what + " (corrupt header or point records)");
    log::warning(path_ + ": " + what + " and were dropped (corrupt records?)");
}

void LasReader::account_screened(uint64_t points, uint64_t dropped) {
    if (points == 0) return report_end();
    screened_ += points;
    dropped_outside_ += dropped;
}

void LasReader::restrict_to_box(double min_x, double min_y, double max_x, double max_y) {
    if (laz_ || read_ != 0) return;
    box_ = std::array<double, 4>{min_x, min_y, max_x, max_y};
}

std::size_t LasReader::read_chunk(PointCloud& out, std::size_t max_points) {
    while (box_) {
        const auto n = static_cast<std::size_t>(std::min<uint64_t>(max_points, points_remaining()));
        if (n == 0) {
            report_end();
            return 0;
        }
        uint64_t dropped = 0;
        const std::size_t kept = append_records_in_box(out, n, dropped);
        screened_ += n, dropped_outside_ += dropped;
        if (kept > 0) return kept;  // else: read on, 0 means the end
    }
    while (true) {
        const std::size_t base = out.size();
        const std::size_t n = read_chunk_unscreened(out, max_points);
        if (n == 0) {
            report_end();
            return 0;
        }
        screened_ += n;
        // Checked while decoding, in parallel: the (serial) compaction only when a point is out.
        if (!chunk_has_outside_) return n;
        const std::size_t dropped = out.remove_from(base, [&](std::size_t i) { return outside_bounds(out.x[i], out.y[i], out.z[i]); });
        dropped_outside_ += dropped;
        if (dropped < n) return n - dropped;  // else: read on, 0 means the end
    }
}

std::size_t LasReader::read_chunk_unscreened(PointCloud& out, std::size_t max_points) {
    if (laz_ && read_ == 0) laz_->set_point_fields_only(true);  // LAZ: skip layers a PointCloud does not hold
    // LAZ: the chunk's records decoded into buffer_ (reused between chunks).
    // LAS: read below, block by block, by the tasks that decode them.
    const std::size_t n = laz_ ? read_records(buffer_, max_points) : static_cast<std::size_t>(std::min<uint64_t>(max_points, points_remaining()));
    if (n == 0) return 0;
    // A chunk that cannot be read (or memory that cannot be had) leaves `out`
    // as it was: the points appended for this chunk are taken off again.
    const PointCloud::Mark before = out.mark();
    try {
        append_records(out, n);
    } catch (...) {
        out.roll_back(before);  // the attributes this chunk added are taken off too
        throw;
    }
    return n;
}

namespace {
// Writes decoded point q into slot k of `out` (grown to hold it; colour and
// GPS time only when the point format has them).
inline void store_point(PointCloud& out, std::size_t k, const LasPoint& q, bool gps, bool color) {
    out.x[k] = q.x, out.y[k] = q.y, out.z[k] = q.z;
    out.intensity[k] = q.intensity;
    out.return_number[k] = q.return_number, out.number_of_returns[k] = q.number_of_returns;
    out.classification[k] = q.classification;
    if (gps) out.gps_time[k] = q.gps_time;
    if (color) out.red[k] = q.red, out.green[k] = q.green, out.blue[k] = q.blue;
}
}  // namespace

std::size_t LasReader::record_block() const { return std::max<std::size_t>(1, (std::size_t(256) << 10) / header_.point_record_length); }

template <class Visit>
void LasReader::read_record_blocks(std::size_t n, const Visit& visit) const {
    const std::size_t rl = header_.point_record_length, block = record_block();
    const uint64_t start = header_.offset_to_points + read_ * rl;
    tbb::parallel_for(std::size_t(0), (n + block - 1) / block, [&](std::size_t b) {
        thread_local std::vector<char> records;
        const std::size_t first = b * block, count = std::min(block, n - first);
        if (records.size() < count * rl) records.resize(count * rl);
        if (!file_.read_exact_at(start + first * rl, records.data(), count * rl)) throw Error(path_, "truncated point records");
        visit(static_cast<const char*>(records.data()), first, count, b);
    });
}

void LasReader::append_records(PointCloud& out, std::size_t n) {
    const LasHeader& h = header_;
    const std::size_t rl = h.point_record_length;
    const RecordLayout layout(h);
    const bool color = layout.color, gps = layout.gps;
    // Resize once, then fill by index (much faster than per-field push_back).
    const std::size_t base = out.size();
    out.grow(n, color, gps);
    // Records decoded in parallel blocks: each point's fields depend on its
    // record only. The bounds screen is checked on the way.
    auto decode = [&](const char* records, std::size_t first, std::size_t count) {
        bool out_here = false;
        for (std::size_t i = 0; i != count; ++i) {
            const LasPoint q = decode_record(records + i * rl, h, layout);
            out_here = out_here || outside_bounds(q.x, q.y, q.z);
            store_point(out, base + first + i, q, gps, color);
        }
        return out_here;
    };
    std::atomic<bool> outside{false};
    if (laz_) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1u << 16), [&](const tbb::blocked_range<std::size_t>& range) {
            if (decode(buffer_.data() + range.begin() * rl, range.begin(), range.size())) outside.store(true, std::memory_order_relaxed);
        });
    } else {
        // Blocks of ~256 kB of records, each read with pread at its own
        // offset into its task's buffer, which stays in that core's cache for
        // the decoding: the copy out of the page cache is shared by the cores
        // and no chunk-sized buffer is written and read again. A block the
        // file no longer holds (cut short since it was opened) is the one
        // "truncated point records" error, whichever task meets it.
        read_record_blocks(n, [&](const char* records, std::size_t first, std::size_t count, std::size_t) {
            if (decode(records, first, count)) outside.store(true, std::memory_order_relaxed);
        });
        read_ += n;
    }
    chunk_has_outside_ = outside.load();
}

std::size_t LasReader::append_records_in_box(PointCloud& out, std::size_t n, uint64_t& dropped) {
    const LasHeader& h = header_;
    const std::size_t rl = h.point_record_length;
    const RecordLayout layout(h);
    const bool color = layout.color, gps = layout.gps;
    const std::array<double, 4> box = *box_;
    // Blocks of records as append_records reads them, each keeping its
    // points in the box; then appended in block order.
    const std::size_t block = record_block();
    const std::size_t blocks = (n + block - 1) / block;
    std::vector<std::vector<LasPoint>> kept(blocks);
    std::vector<uint64_t> outside(blocks, 0);
    read_record_blocks(n, [&](const char* records, std::size_t, std::size_t count, std::size_t b) {
        for (std::size_t i = 0; i != count; ++i) {
            const LasPoint q = decode_record(records + i * rl, h, layout);
            if (outside_bounds(q.x, q.y, q.z)) ++outside[b];
            else if (q.x >= box[0] && q.x <= box[2] && q.y >= box[1] && q.y <= box[3]) kept[b].push_back(q);
        }
    });
    read_ += n;
    std::size_t total = 0;
    for (std::size_t b = 0; b < blocks; ++b) total += kept[b].size(), dropped += outside[b];
    if (total == 0) return 0;
    const std::size_t base = out.size();
    const PointCloud::Mark before = out.mark();
    try {
        out.grow(total, color, gps);
    } catch (...) {
        out.roll_back(before);
        throw;
    }
    std::size_t k = base;
    for (const std::vector<LasPoint>& points : kept)
        for (const LasPoint& q : points) store_point(out, k++, q, gps, color);
    return total;
}

PointCloud read_las(const std::string& path, LasHeader* header) {
    LasReader reader(path);
    if (header) *header = reader.header();
    PointCloud cloud;
    cloud.reserve(reader.reserve_hint(), reader.header().has_color(), reader.header().has_gps_time());
    while (reader.read_chunk(cloud, 1u << 20) > 0) {
    }
    return cloud;
}

// ---------------------------------------------------------------- writer

LasWriter::LasWriter(const std::string& path, const std::array<double, 3>& scale, const std::array<double, 3>& offset,
                     const std::string& crs_wkt, const std::string& generating_software)
    : path_(path), scale_(scale), offset_(offset) {
    for (double s : scale_)
        if (!(s > 0.0)) throw Error(path, "LAS scale must be positive");
    tmp_path_ = temporary_path_for(path).string();
    out_.open(tmp_path_, std::ios::binary | std::ios::trunc);
    if (!out_) throw Error(path, "cannot open for writing");

    std::vector<char> hdr(kHeaderSize, 0);
    std::memcpy(hdr.data(), "LASF", 4);
    // Global encoding bit 4: the CRS is WKT. Always set: point formats 6-10
    // with the bit clear are a file error (LAS 1.4 R15, "Coordinate Reference
    // System Representation"), with or without a CRS record.
    put<uint16_t>(hdr, 6, 0x10);
    hdr[24] = 1;
    hdr[25] = 4;
    std::strncpy(hdr.data() + 26, "cityforge", 32);
    std::strncpy(hdr.data() + 58, generating_software.c_str(), 31);
    put<uint16_t>(hdr, 90, 1);     // creation day of year: fixed so output bytes are reproducible
    put<uint16_t>(hdr, 92, 2026);
    put<uint16_t>(hdr, 94, kHeaderSize);
    const uint32_t wkt_len = crs_wkt.empty() ? 0 : static_cast<uint32_t>(crs_wkt.size() + 1);
    offset_to_points_ = kHeaderSize + (wkt_len ? 54 + wkt_len : 0);
    put<uint32_t>(hdr, 96, offset_to_points_);
    put<uint32_t>(hdr, 100, wkt_len ? 1 : 0);
    hdr[104] = 7;
    put<uint16_t>(hdr, 105, kRecordLength);
    for (int i = 0; i < 3; ++i) {
        put<double>(hdr, 131 + 8 * i, scale_[i]);
        put<double>(hdr, 155 + 8 * i, offset_[i]);
    }
    out_.write(hdr.data(), static_cast<std::streamsize>(hdr.size()));
    if (wkt_len) {
        if (wkt_len > 65535) throw Error(path, "CRS WKT too long for a VLR");
        std::vector<char> vh(54, 0);
        std::strncpy(vh.data() + 2, "LASF_Projection", 16);
        put<uint16_t>(vh, 18, 2112);
        put<uint16_t>(vh, 20, static_cast<uint16_t>(wkt_len));
        std::strncpy(vh.data() + 22, "OGC WKT coordinate system", 32);
        out_.write(vh.data(), 54);
        out_.write(crs_wkt.c_str(), wkt_len);  // includes the terminating NUL
    }
}

LasWriter::~LasWriter() {
    if (!closed_) {
        out_.close();
        discard_file(tmp_path_);
    }
}

void LasWriter::write(const PointCloud& c) {
    const std::size_t n = c.size();
    buffer_.resize(n * kRecordLength);
    const bool gps = c.has_gps_time(), color = c.has_color();
    for (std::size_t i = 0; i < n; ++i) {
        LasPoint q;
        q.x = c.x[i], q.y = c.y[i], q.z = c.z[i];
        if (!c.intensity.empty()) q.intensity = c.intensity[i];
        if (!c.return_number.empty()) q.return_number = c.return_number[i];
        if (!c.number_of_returns.empty()) q.number_of_returns = c.number_of_returns[i];
        if (!c.classification.empty()) q.classification = c.classification[i];
        if (gps) q.gps_time = c.gps_time[i];
        if (color) q.red = c.red[i], q.green = c.green[i], q.blue = c.blue[i];
        encode_record7(buffer_.data() + i * kRecordLength, q, gps, color, scale_, offset_, path_);
    }
    write_records(buffer_.data(), n);
}

void LasWriter::write_records(const char* records, std::size_t n) {
    if (n == 0) return;
    // Bounds and return counts from the stored integers (q x scale + offset,
    // as the header states them), in parallel blocks: min, max and sums do
    // not depend on the blocks.
    const LasRecordStats s = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, 1u << 16), LasRecordStats{},
        [&](const tbb::blocked_range<std::size_t>& r, LasRecordStats acc) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                const char* p = records + i * kRecordLength;
                for (int k = 0; k < 3; ++k) {
                    const double v = double(get<int32_t>(p + 4 * k)) * scale_[k] + offset_[k];
                    acc.min[k] = std::min(acc.min[k], v), acc.max[k] = std::max(acc.max[k], v);
                }
                // Return number 0 (invalid in LAS 1.4) has no bin: not counted.
                if (const int ret = static_cast<uint8_t>(p[14]) & 0x0F; ret >= 1) ++acc.by_return[ret - 1];
            }
            return acc;
        },
        [](LasRecordStats a, const LasRecordStats& b) {
            a.add(b);
            return a;
        });
    stats_.add(s);
    out_.write(records, static_cast<std::streamsize>(n * kRecordLength));
    if (!out_) throw Error(path_, "write failed (disk full?)");
    count_ += n;
}

void LasWriter::close() {
    if (closed_) return;
    auto seek_put = [&](std::streamoff pos, const void* data, std::size_t len) {
        out_.seekp(pos);
        out_.write(static_cast<const char*>(data), static_cast<std::streamsize>(len));
    };
    // The legacy point count (107) and legacy counts by return (111..130)
    // stay zero: a LAS 1.4 file of point format 7 (WKT bit set) cannot be
    // read by a LAS 1.0-1.3 reader, so it does not keep legacy compatibility
    // and the specification (1.4 R15, "Legacy Number of point records")
    // requires zero there; the 64-bit counts below are the counts.
    if (count_ == 0) stats_.min.fill(0.0), stats_.max.fill(0.0);
    for (int k = 0; k < 3; ++k) {
        seek_put(179 + 16 * k, &stats_.max[k], 8);
        seek_put(187 + 16 * k, &stats_.min[k], 8);
    }
    seek_put(247, &count_, 8);
    for (int r = 0; r < 15; ++r) seek_put(255 + 8 * r, &stats_.by_return[r], 8);
    out_.flush();
    const bool ok = static_cast<bool>(out_);
    out_.close();
    if (!ok) {
        discard_file(tmp_path_);
        closed_ = true;
        throw Error(path_, "write failed (disk full?)");
    }
    commit_file(tmp_path_, path_);
    closed_ = true;
}

std::vector<uint64_t> split_las_into_windows(const std::string& path, const std::vector<std::array<double, 4>>& windows,
                                             const std::vector<std::string>& out_paths, const std::string& crs_wkt, std::size_t chunk_points) {
    if (chunk_points == 0) throw Error(path, "split into windows: chunk_points must be positive");
    if (windows.size() != out_paths.size()) throw Error(path, "split into windows: " + std::to_string(windows.size()) + " windows but " + std::to_string(out_paths.size()) + " output files");
    LasReader reader(path);
    const LasHeader& h = reader.header();
    const RecordLayout layout(h);
    const std::size_t n_windows = windows.size();
    std::vector<std::unique_ptr<LasWriter>> writers;
    for (std::size_t w = 0; w < n_windows; ++w) writers.push_back(std::make_unique<LasWriter>(out_paths[w], h.scale, h.offset, crs_wkt));

    // The windows' distinct edges cut the plane into cells; a point's cell is
    // found by two binary searches and lists the windows that hold it. With
    // xs sorted, ix = upper_bound(xs, x): min_x <= x < max_x exactly when
    // index(min_x) < ix <= index(max_x) (the same comparisons as testing
    // each window). Windows with a NaN edge hold no point, as before.
    std::vector<double> xs, ys;
    auto usable = [](const std::array<double, 4>& e) { return !std::isnan(e[0]) && !std::isnan(e[1]) && !std::isnan(e[2]) && !std::isnan(e[3]); };
    for (const auto& e : windows)
        if (usable(e)) xs.push_back(e[0]), xs.push_back(e[2]), ys.push_back(e[1]), ys.push_back(e[3]);
    for (auto* v : {&xs, &ys}) {
        std::sort(v->begin(), v->end());
        v->erase(std::unique(v->begin(), v->end()), v->end());
    }
    const std::size_t cols = xs.size() + 1, rows = ys.size() + 1;
    std::vector<std::vector<uint32_t>> cell_lists(cols * rows);
    auto index_of = [](const std::vector<double>& v, double e) { return static_cast<std::size_t>(std::lower_bound(v.begin(), v.end(), e) - v.begin()); };
    for (std::size_t w = 0; w < n_windows; ++w) {
        if (!usable(windows[w])) continue;
        const std::size_t a = index_of(xs, windows[w][0]), b = index_of(xs, windows[w][2]);
        const std::size_t c = index_of(ys, windows[w][1]), d = index_of(ys, windows[w][3]);
        for (std::size_t ix = a + 1; ix <= b; ++ix)
            for (std::size_t iy = c + 1; iy <= d; ++iy) cell_lists[ix * rows + iy].push_back(static_cast<uint32_t>(w));
    }
    std::vector<uint32_t> cell_start(cell_lists.size() + 1, 0), cell_windows;
    for (std::size_t c = 0; c < cell_lists.size(); ++c) {
        cell_windows.insert(cell_windows.end(), cell_lists[c].begin(), cell_lists[c].end());
        cell_start[c + 1] = static_cast<uint32_t>(cell_windows.size());
    }
    constexpr uint32_t kDropped = std::numeric_limits<uint32_t>::max();
    auto cell_of = [&](double x, double y) {
        const auto ix = static_cast<std::size_t>(std::upper_bound(xs.begin(), xs.end(), x) - xs.begin());
        const auto iy = static_cast<std::size_t>(std::upper_bound(ys.begin(), ys.end(), y) - ys.begin());
        return static_cast<uint32_t>(ix * rows + iy);
    };

    const std::size_t kChunk = chunk_points;
    constexpr std::size_t kBlock = std::size_t(1) << 16;
    const std::size_t rl = static_cast<std::size_t>(h.point_record_length);
    std::vector<char> raw;
    std::vector<uint32_t> cell(kChunk);
    std::vector<uint64_t> count, at, first(n_windows), total(n_windows), written(n_windows, 0);
    std::vector<char> out;
    while (true) {
        const std::size_t n = reader.read_records(raw, kChunk);
        if (n == 0) break;
        const std::size_t blocks = (n + kBlock - 1) / kBlock;
        count.assign(blocks * n_windows, 0);
        std::vector<uint64_t> dropped(blocks, 0);
        // Pass 1, in parallel blocks: each point's cell (or the screen's
        // verdict) and each block's count per window.
        tbb::parallel_for(std::size_t(0), blocks, [&](std::size_t b) {
            uint64_t* c = count.data() + b * n_windows;
            for (std::size_t i = b * kBlock, end = std::min(n, i + kBlock); i < end; ++i) {
                const char* p = raw.data() + i * rl;
                const double x = las_coordinate(p, h, 0), y = las_coordinate(p, h, 1);
                if (reader.outside_bounds(x, y, las_coordinate(p, h, 2))) {
                    cell[i] = kDropped, ++dropped[b];
                    continue;
                }
                const uint32_t k = cell[i] = cell_of(x, y);
                for (uint32_t j = cell_start[k]; j < cell_start[k + 1]; ++j) ++c[cell_windows[j]];
            }
        });
        uint64_t dropped_all = 0;
        for (uint64_t d : dropped) dropped_all += d;
        reader.account_screened(n, dropped_all);
        // Each window's records side by side in `out`, block after block (file order).
        at.assign(blocks * n_windows, 0);
        uint64_t next = 0;
        for (std::size_t w = 0; w < n_windows; ++w) {
            first[w] = next;
            for (std::size_t b = 0; b < blocks; ++b) at[b * n_windows + w] = next, next += count[b * n_windows + w];
            total[w] = next - first[w];
        }
        out.resize(next * kRecordLength);
        // Pass 2, in parallel blocks: each kept point encoded once, copied to its windows.
        tbb::parallel_for(std::size_t(0), blocks, [&](std::size_t b) {
            uint64_t* a = at.data() + b * n_windows;
            char record[kRecordLength];
            for (std::size_t i = b * kBlock, end = std::min(n, i + kBlock); i < end; ++i) {
                const uint32_t k = cell[i];
                if (k == kDropped || cell_start[k] == cell_start[k + 1]) continue;
                encode_record7(record, decode_record(raw.data() + i * rl, h, layout), layout.gps, layout.color, h.scale, h.offset, out_paths[cell_windows[cell_start[k]]]);
                for (uint32_t j = cell_start[k]; j < cell_start[k + 1]; ++j) std::memcpy(out.data() + a[cell_windows[j]]++ * kRecordLength, record, kRecordLength);
            }
        });
        // The windows' files written side by side: copying into the page
        // cache is most of the split's time, and each file is its own stream.
        tbb::parallel_for(std::size_t(0), n_windows, [&](std::size_t w) {
            writers[w]->write_records(out.data() + first[w] * kRecordLength, total[w]);
        });
        for (std::size_t w = 0; w < n_windows; ++w) written[w] += total[w];
    }
    reader.account_screened(0, 0);
    for (auto& wr : writers) wr->close();
    return written;
}

}  // namespace cityforge
