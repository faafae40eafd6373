#include "cloud/cloud_translate.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <vector>

#include "cloud/cloud_reader.hpp"
#include "cloud/copc.hpp"
#include "cloud/las.hpp"
#include "core/atomic_file.hpp"
#include "cloud/le_bytes.hpp"
#include "core/error.hpp"
#include "core/sha256.hpp"

namespace cityforge {
namespace fs = std::filesystem;

namespace {

using bytes::get;
using bytes::put;
std::string user_id(const char* p) { return las_text(p, 16); }  // a VLR/EVLR user id

std::string lower_ext(const std::string& p) {
    std::string e = fs::path(p).extension().string();
    std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return e;
}

bool is_las(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    char sig[4] = {};
    in.read(sig, 4);
    return in.gcount() == 4 && std::memcmp(sig, "LASF", 4) == 0;
}

// Removes the temporary file unless committed.
struct TempFile {
    fs::path path;
    bool committed = false;
    ~TempFile() {
        if (!committed) discard_file(path);
    }
};

CloudTranslateResult translate_las(const CloudTranslateOptions& o) {
    CloudTranslateResult res;
    LasReader reader(o.input);
    const LasHeader h = reader.header();
    res.decompressed = h.laz.has_value();
    const auto file_size = static_cast<uint64_t>(fs::file_size(o.input));
    std::ifstream in(o.input, std::ios::binary);
    if (!in) throw Error(o.input, "cannot open for reading");
    auto read_at = [&](uint64_t pos, char* dst, uint64_t n) {
        in.clear();
        in.seekg(static_cast<std::streamoff>(pos));
        in.read(dst, static_cast<std::streamsize>(n));
        if (static_cast<uint64_t>(in.gcount()) != n) throw Error(o.input, "truncated header or variable length records");
    };
    std::vector<char> header(h.header_size);
    read_at(0, header.data(), header.size());

    // VLRs, without the LASzip and COPC records.
    std::vector<char> vlrs;
    uint32_t vlrs_kept = 0;
    uint64_t pos = h.header_size;
    for (uint32_t i = 0; i < h.vlr_count && pos + 54 <= h.offset_to_points; ++i) {
        char vh[54];
        read_at(pos, vh, 54);
        const auto length = get<uint16_t>(vh + 20);
        const std::string user = user_id(vh + 2);
        const auto id = get<uint16_t>(vh + 18);
        const bool drop = (user == "laszip encoded" && id == 22204) || (user == "copc" && id == 1);
        if (!drop) {
            const std::size_t at = vlrs.size();
            vlrs.resize(at + 54 + length);
            read_at(pos, vlrs.data() + at, 54 + length);
            ++vlrs_kept;
        }
        pos += 54 + length;
    }
    // EVLRs (LAS 1.4), without the COPC hierarchy.
    std::vector<char> evlrs;
    uint32_t evlrs_kept = 0;
    uint64_t epos = h.evlr_offset;
    for (uint32_t i = 0; i < h.evlr_count && epos != 0 && epos + 60 <= file_size; ++i) {
        char eh[60];
        read_at(epos, eh, 60);
        const auto length = get<uint64_t>(eh + 20);
        if (length > file_size - epos - 60) throw Error(o.input, "extended variable length record runs past the end of the file");
        const bool drop = user_id(eh + 2) == "copc" && get<uint16_t>(eh + 18) == 1000;
        if (!drop) {
            const std::size_t at = evlrs.size();
            evlrs.resize(at + 60 + static_cast<std::size_t>(length));
            read_at(epos, evlrs.data() + at, 60 + length);
            ++evlrs_kept;
        }
        epos += 60 + length;
    }

    // A COPC crop decodes only the nodes that meet the box; a layered LAZ
    // crop only the chunks whose XY layer has a point in it.
    if (reader.laz_source()) res.laz_chunks = reader.laz_source()->chunks().size();
    if (o.bounds && reader.laz_source()) {
        const auto& b = *o.bounds;
        std::vector<bool> keep;
        if (const auto copc = read_copc_hierarchy(reader.file(), h)) {
            const double pad = std::max(h.scale[0], h.scale[1]);
            // copc_chunks_in_box takes a half-open box; widen it so max is kept.
            keep = copc_chunks_in_box(*copc, reader.laz_source()->chunks(), b[0], b[1], b[2] + pad, b[3] + pad, pad, -1, o.input);
            res.copc_nodes_skipped = std::find(keep.begin(), keep.end(), false) != keep.end();
        } else {
            keep = reader.laz_source()->chunks_meeting_box({b[0], b[1], b[2], b[3], h.scale[0], h.scale[1], h.offset[0], h.offset[1]});
        }
        if (!keep.empty()) {
            res.laz_chunks_skipped = static_cast<uint64_t>(std::count(keep.begin(), keep.end(), false));
            reader.select_laz_chunks(keep);
        }
    }

    TempFile tmp{temporary_path_for(o.output)};
    std::ofstream out(tmp.path, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(o.output, "cannot open for writing");
    const uint64_t offset_to_points = h.header_size + vlrs.size();
    if (offset_to_points > std::numeric_limits<uint32_t>::max()) throw Error(o.output, "VLRs too large for a LAS header");
    out.write(header.data(), static_cast<std::streamsize>(header.size()));
    out.write(vlrs.data(), static_cast<std::streamsize>(vlrs.size()));

    const std::size_t rl = static_cast<std::size_t>(h.point_record_length);
    const bool extended = h.point_format >= 6;
    std::array<uint64_t, 15> by_return{};
    std::array<double, 3> lo, hi;
    lo.fill(std::numeric_limits<double>::infinity());
    hi.fill(-std::numeric_limits<double>::infinity());
    Sha256 sha;
    std::vector<char> records, kept;
    while (const std::size_t n = reader.read_records(records, 1u << 20)) {
        res.points_read += n;
        const std::vector<char>* block = &records;
        if (o.bounds) {
            const auto& b = *o.bounds;
            kept.clear();
            for (std::size_t i = 0; i < n; ++i) {
                const char* p = records.data() + i * rl;
                const double x = get<int32_t>(p) * h.scale[0] + h.offset[0];
                const double y = get<int32_t>(p + 4) * h.scale[1] + h.offset[1];
                if (x < b[0] || x > b[2] || y < b[1] || y > b[3]) continue;
                const double z = get<int32_t>(p + 8) * h.scale[2] + h.offset[2];
                const double v[3] = {x, y, z};
                for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], v[k]), hi[k] = std::max(hi[k], v[k]);
                const int rn = extended ? (p[14] & 0x0F) : (p[14] & 0x07);
                if (rn >= 1 && rn <= 15) ++by_return[rn - 1];
                kept.insert(kept.end(), p, p + rl);
            }
            block = &kept;
        }
        sha.update(block->data(), block->size());
        out.write(block->data(), static_cast<std::streamsize>(block->size()));
        res.points_written += block->size() / rl;
    }
    if (res.points_written == 0 && o.bounds)
        throw Error(o.input, "no point lies inside --bounds (nothing to write)");
    const uint64_t evlr_start = evlrs_kept ? offset_to_points + res.points_written * rl : 0;
    out.write(evlrs.data(), static_cast<std::streamsize>(evlrs.size()));

    // Header: compression bit cleared, offsets and counts for what we wrote.
    header[104] = static_cast<char>(h.point_format);
    put<uint32_t>(header, 96, static_cast<uint32_t>(offset_to_points));
    put<uint32_t>(header, 100, vlrs_kept);
    const bool legacy_fits = !extended && res.points_written <= std::numeric_limits<uint32_t>::max();
    put<uint32_t>(header, 107, legacy_fits ? static_cast<uint32_t>(res.points_written) : 0u);
    if (o.bounds) {
        for (int r = 0; r < 5; ++r) put<uint32_t>(header, 111 + 4 * r, legacy_fits ? static_cast<uint32_t>(by_return[r]) : 0u);
        for (int k = 0; k < 3; ++k) {
            put<double>(header, 179 + 16 * k, hi[k]);
            put<double>(header, 187 + 16 * k, lo[k]);
        }
    }
    if (h.version_minor >= 4 && h.header_size >= 375) {
        put<uint64_t>(header, 235, evlr_start);
        put<uint32_t>(header, 243, evlrs_kept);
        put<uint64_t>(header, 247, res.points_written);
        if (o.bounds)
            for (int r = 0; r < 15; ++r) put<uint64_t>(header, 255 + 8 * r, by_return[r]);
    }
    out.seekp(0);
    out.write(header.data(), static_cast<std::streamsize>(header.size()));
    out.flush();
    if (!out) throw Error(o.output, "write failed (disk full?)");
    out.close();
    commit_file(tmp.path, o.output);
    tmp.committed = true;
    res.points_sha256 = sha.hex();
    return res;
}

// PLY / XYZ: through the cloud reader into a LAS 1.4 point format 7 file.
CloudTranslateResult translate_other(const CloudTranslateOptions& o) {
    CloudTranslateResult res;
    CloudReader reader(o.input);
    std::unique_ptr<LasWriter> writer;
    PointCloud chunk, kept;
    while (true) {
        chunk.clear();
        const std::size_t n = reader.read_chunk(chunk, 1u << 20);
        if (n == 0) break;
        res.points_read += n;
        PointCloud* block = &chunk;
        if (o.bounds) {
            const auto& b = *o.bounds;
            kept.clear();
            for (std::size_t i = 0; i < chunk.size(); ++i)
                if (chunk.x[i] >= b[0] && chunk.x[i] <= b[2] && chunk.y[i] >= b[1] && chunk.y[i] <= b[3]) kept.append(chunk, i);
            block = &kept;
        }
        if (block->size() == 0) continue;
        if (!writer) {
            // 1 mm grid anchored on a round kilometre near the first point.
            const std::array<double, 3> offset{std::floor(block->x[0] / 1000.0) * 1000.0, std::floor(block->y[0] / 1000.0) * 1000.0,
                                               std::floor(block->z[0] / 1000.0) * 1000.0};
            writer = std::make_unique<LasWriter>(o.output, std::array<double, 3>{0.001, 0.001, 0.001}, offset, o.crs_wkt);
        }
        writer->write(*block);
    }
    if (!writer) throw Error(o.input, o.bounds ? "no point lies inside --bounds (nothing to write)" : "point cloud is empty");
    res.points_written = writer->points_written();
    writer->close();
    // Fingerprint the records as written.
    LasReader check(o.output);
    Sha256 sha;
    std::vector<char> records;
    while (check.read_records(records, 1u << 20) > 0) sha.update(records.data(), records.size());
    res.points_sha256 = sha.hex();
    return res;
}

}  // namespace

void CloudTranslateOptions::validate() const {
    if (input.empty()) throw Error("cloud translate", "no input cloud given");
    if (output.empty()) throw Error("cloud translate", "no output file given");
    if (!fs::exists(input)) throw Error(input, "file not found");
    if (lower_ext(output) != ".las") throw Error(output, "output must be an uncompressed .las file (writing LAZ is not supported)");
    std::error_code ec;
    if (fs::exists(output) && fs::equivalent(input, output, ec)) throw Error(output, "output is the input file");
    if (fs::exists(output) && !overwrite) throw Error(output, "exists (use --overwrite to replace it)");
    if (bounds) {
        const auto& b = *bounds;
        for (double v : b)
            if (!std::isfinite(v)) throw Error("--bounds", "values must be finite numbers");
        if (!(b[0] < b[2]) || !(b[1] < b[3])) throw Error("--bounds", "expected xmin,ymin,xmax,ymax with xmin < xmax and ymin < ymax");
    }
}

CloudTranslateResult translate_cloud(const CloudTranslateOptions& options) {
    options.validate();
    return is_las(options.input) ? translate_las(options) : translate_other(options);
}

}  // namespace cityforge
