#include "cloud/las.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <vector>
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

}  // namespace

std::string las_text(const char* p, std::size_t n) {
    if (n == 0 || p == nullptr) return {};
    std::string s(p, strnlen(p, n));
    while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
    return s;
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

void PointCloud::reserve(std::size_t n, bool color, bool gps) {
    // Grow geometrically: readers call this once per chunk.
    if (n <= x.capacity() && (!color || n <= red.capacity()) && (!gps || n <= gps_time.capacity())) return;
    n = std::max(n, 2 * x.capacity());
    x.reserve(n), y.reserve(n), z.reserve(n), intensity.reserve(n);
    classification.reserve(n), return_number.reserve(n), number_of_returns.reserve(n);
    if (gps) gps_time.reserve(n);
    if (color) red.reserve(n), green.reserve(n), blue.reserve(n);
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

LasReader::LasReader(const std::string& path) : path_(path) {
    namespace fs = std::filesystem;
    if (!fs::exists(path)) throw Error(path, "file not found");
    if (fs::is_directory(path)) throw Error(path, "is a directory, not a point cloud file");
    in_.open(path, std::ios::binary);
    if (!in_) throw Error(path, "cannot open for reading");
    const auto file_size = static_cast<uint64_t>(fs::file_size(path));
    char hdr[375] = {};
    in_.read(hdr, sizeof hdr);
    const auto got = static_cast<std::size_t>(in_.gcount());
    in_.clear();
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
        in_.seekg(static_cast<std::streamoff>(pos));
        in_.read(vh, 54);
        if (!in_) throw Error(path, "truncated variable length record header");
        const std::string user = las_text(vh + 2, 16);
        const auto record_id = get<uint16_t>(vh + 18);
        const auto length = get<uint16_t>(vh + 20);
        if (pos + 54 + length > h.offset_to_points) throw Error(path, "variable length record runs past the point data");
        if (user == "LASF_Projection" || user == "liblas") {
            std::vector<char> data(length);
            in_.read(data.data(), length);
            if (!in_) throw Error(path, "truncated variable length record");
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
            in_.read(data.data(), length);
            if (!in_) throw Error(path, "truncated LASzip VLR");
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
            in_.seekg(static_cast<std::streamoff>(epos));
            in_.read(eh, 60);
            if (!in_) break;
            const std::string user = las_text(eh + 2, 16);
            const auto record_id = get<uint16_t>(eh + 18);
            const auto length = get<uint64_t>(eh + 20);
            if (length > file_size - epos - 60) throw Error(path, "extended variable length record " + std::to_string(i) + " (" + std::to_string(length) + " bytes at " + std::to_string(epos) + ") runs past the end of the file");
            if (user == "LASF_Projection" && record_id == 2112 && length < (1u << 24)) {
                std::vector<char> data(length);
                in_.read(data.data(), static_cast<std::streamsize>(length));
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
        laz_ = std::make_unique<LazPointSource>(path, *h.laz, h.offset_to_points, h.point_count, h.point_record_length);
        return;
    }
    // Compared as a quotient: point_count x record length can wrap 2^64.
    if (h.point_count > (file_size - h.offset_to_points) / static_cast<uint64_t>(h.point_record_length))
        throw Error(path, "header says " + std::to_string(h.point_count) + " points but the file holds only " +
                              std::to_string((file_size - h.offset_to_points) / h.point_record_length) + " (truncated or corrupt)");
    in_.seekg(h.offset_to_points);
}

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
        const auto bytes = static_cast<std::streamsize>(n * static_cast<std::size_t>(header_.point_record_length));
        in_.read(out, bytes);
        if (in_.gcount() != bytes) throw Error(path_, "truncated point records");
    }
    read_ += n;
    return n;
}

void LasReader::select_laz_chunks(const std::vector<bool>& keep) {
    if (!laz_ || read_ != 0) throw Error(path_, "chunk selection needs a LAZ file before its first read");
    laz_->select_chunks(keep);
    total_ = laz_->selected_points();
}

std::size_t LasReader::read_chunk(PointCloud& out, std::size_t max_points) {
    const LasHeader& h = header_;
    while (true) {
        const std::size_t base = out.size();
        const std::size_t n = read_chunk_unscreened(out, max_points);
        if (n == 0) {
            if (!end_reported_ && dropped_outside_ > 0) {
                end_reported_ = true;
                const std::string what = std::to_string(dropped_outside_) + " of " + std::to_string(screened_) +
                                         " points lie outside the header's bounds";
                if (dropped_outside_ == screened_)
                    throw Error(path_, "all " + what + " (corrupt header or point records)");
                log::warning(path_ + ": " + what + " and were dropped (corrupt records?)");
            }
            return 0;
        }
        screened_ += n;
        if (!screen_bounds_) return n;
        auto outside = [&](std::size_t i) {
            const double v[3] = {out.x[i], out.y[i], out.z[i]};
            for (int k = 0; k < 3; ++k)
                if (v[k] < h.min[k] - bounds_tolerance_[k] || v[k] > h.max[k] + bounds_tolerance_[k]) return true;
            return false;
        };
        // Checked in parallel first: the (serial) compaction only when a point is out.
        if (!any_point(base, out.size(), outside)) return n;
        const std::size_t dropped = out.remove_from(base, outside);
        dropped_outside_ += dropped;
        if (dropped < n) return n - dropped;  // else: read on, 0 means the end
    }
}

std::size_t LasReader::read_chunk_unscreened(PointCloud& out, std::size_t max_points) {
    if (laz_ && read_ == 0) laz_->set_point_fields_only(true);  // LAZ: skip layers a PointCloud does not hold
    std::vector<char>& buf = buffer_;  // reused between chunks: no page faults per chunk
    const std::size_t n = read_records(buf, max_points);
    if (n == 0) return 0;
    const LasHeader& h = header_;
    const std::size_t rl = h.point_record_length;
    const bool extended = h.point_format >= 6;
    const bool color = h.has_color();
    const bool gps = h.has_gps_time();
    // Offset of the RGB triplet within the record for each format.
    static constexpr int rgb_offset[] = {-1, -1, 20, 28, -1, 28, -1, 30, 30, -1, 30};
    // Resize once, then fill by index (much faster than per-field push_back).
    const std::size_t base = out.size();
    out.reserve(base + n, color, gps);
    for (auto* v : {&out.x, &out.y, &out.z}) v->resize(base + n);
    out.intensity.resize(base + n);
    for (auto* v : {&out.classification, &out.return_number, &out.number_of_returns}) v->resize(base + n);
    if (gps) out.gps_time.resize(base + n);
    if (color) out.red.resize(base + n), out.green.resize(base + n), out.blue.resize(base + n);
    const int class_offset = extended ? 16 : 15;
    const int gps_offset = extended ? 22 : 20;
    const int rgb = rgb_offset[h.point_format];
    // Records decoded in parallel blocks: each point's fields depend on its record only.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1u << 16), [&](const tbb::blocked_range<std::size_t>& range) {
    for (std::size_t i = range.begin(); i != range.end(); ++i) {
        const char* p = buf.data() + i * rl;
        const std::size_t k = base + i;
        out.x[k] = get<int32_t>(p) * h.scale[0] + h.offset[0];
        out.y[k] = get<int32_t>(p + 4) * h.scale[1] + h.offset[1];
        out.z[k] = get<int32_t>(p + 8) * h.scale[2] + h.offset[2];
        out.intensity[k] = get<uint16_t>(p + 12);
        const auto bits = static_cast<uint8_t>(p[14]);
        out.return_number[k] = extended ? (bits & 0x0F) : (bits & 0x07);
        out.number_of_returns[k] = static_cast<uint8_t>(extended ? bits >> 4 : (bits >> 3) & 0x07);
        const auto cls = static_cast<uint8_t>(p[class_offset]);
        out.classification[k] = extended ? cls : (cls & 0x1F);
        if (gps) out.gps_time[k] = get<double>(p + gps_offset);
        if (color) {
            out.red[k] = get<uint16_t>(p + rgb);
            out.green[k] = get<uint16_t>(p + rgb + 2);
            out.blue[k] = get<uint16_t>(p + rgb + 4);
        }
    }
    });
    return n;
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

namespace {
constexpr int kHeaderSize = 375;
constexpr int kRecordLength = 36;  // point format 7
}  // namespace

LasWriter::LasWriter(const std::string& path, const std::array<double, 3>& scale, const std::array<double, 3>& offset,
                     const std::string& crs_wkt, const std::string& generating_software)
    : path_(path), scale_(scale), offset_(offset) {
    for (double s : scale_)
        if (!(s > 0.0)) throw Error(path, "LAS scale must be positive");
    tmp_path_ = temporary_path_for(path).string();
    out_.open(tmp_path_, std::ios::binary | std::ios::trunc);
    if (!out_) throw Error(path, "cannot open for writing");
    min_.fill(std::numeric_limits<double>::infinity());
    max_.fill(-std::numeric_limits<double>::infinity());

    std::vector<char> hdr(kHeaderSize, 0);
    std::memcpy(hdr.data(), "LASF", 4);
    put<uint16_t>(hdr, 6, crs_wkt.empty() ? 0 : 0x10);  // global encoding: bit 4 = CRS is WKT
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
    std::vector<char> buf(n * kRecordLength, 0);
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t p = i * kRecordLength;
        const double xyz[3] = {c.x[i], c.y[i], c.z[i]};
        for (int k = 0; k < 3; ++k) {
            const double q = std::round((xyz[k] - offset_[k]) / scale_[k]);
            if (q < std::numeric_limits<int32_t>::min() || q > std::numeric_limits<int32_t>::max())
                throw Error(path_, "coordinate out of range for the LAS scale/offset");
            put<int32_t>(buf, p + 4 * k, static_cast<int32_t>(q));
            const double v = q * scale_[k] + offset_[k];
            min_[k] = std::min(min_[k], v);
            max_[k] = std::max(max_[k], v);
        }
        put<uint16_t>(buf, p + 12, c.intensity.empty() ? uint16_t(0) : c.intensity[i]);
        const uint8_t rn = c.return_number.empty() ? 1 : std::clamp<uint8_t>(c.return_number[i], 1, 15);
        const uint8_t nr = c.number_of_returns.empty() ? 1 : std::clamp<uint8_t>(c.number_of_returns[i], 1, 15);
        buf[p + 14] = static_cast<char>(rn | (nr << 4));
        buf[p + 16] = static_cast<char>(c.classification.empty() ? 1 : c.classification[i]);
        if (c.has_gps_time()) put<double>(buf, p + 22, c.gps_time[i]);
        if (c.has_color()) {
            put<uint16_t>(buf, p + 30, c.red[i]);
            put<uint16_t>(buf, p + 32, c.green[i]);
            put<uint16_t>(buf, p + 34, c.blue[i]);
        }
        ++by_return_[rn - 1];
    }
    out_.write(buf.data(), static_cast<std::streamsize>(buf.size()));
    if (!out_) throw Error(path_, "write failed (disk full?)");
    count_ += n;
}

void LasWriter::close() {
    if (closed_) return;
    auto seek_put = [&](std::streamoff pos, const void* data, std::size_t len) {
        out_.seekp(pos);
        out_.write(static_cast<const char*>(data), static_cast<std::streamsize>(len));
    };
    const uint32_t legacy = count_ <= std::numeric_limits<uint32_t>::max() ? static_cast<uint32_t>(count_) : 0;
    seek_put(107, &legacy, 4);
    for (int r = 0; r < 5; ++r) {
        const uint32_t v = count_ <= std::numeric_limits<uint32_t>::max() ? static_cast<uint32_t>(by_return_[r]) : 0;
        seek_put(111 + 4 * r, &v, 4);
    }
    if (count_ == 0) min_.fill(0.0), max_.fill(0.0);
    for (int k = 0; k < 3; ++k) {
        seek_put(179 + 16 * k, &max_[k], 8);
        seek_put(187 + 16 * k, &min_[k], 8);
    }
    seek_put(247, &count_, 8);
    for (int r = 0; r < 15; ++r) seek_put(255 + 8 * r, &by_return_[r], 8);
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

}  // namespace cityforge
