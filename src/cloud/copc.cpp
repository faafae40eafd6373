#include "cloud/copc.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <set>

#include "cloud/las.hpp"
#include "cloud/le_bytes.hpp"
#include "core/error.hpp"

namespace cityforge {
namespace {
using bytes::get;
std::string user_id(const char* p) { return las_text(p, 16); }  // a VLR/EVLR user id
}  // namespace

std::string CopcNode::key() const {
    return std::to_string(level) + "-" + std::to_string(x) + "-" + std::to_string(y) + "-" + std::to_string(z);
}

std::array<double, 6> CopcNode::bounds(const CopcInfo& info) const {
    const double side = 2.0 * info.halfsize / std::ldexp(1.0, level);
    const double x0 = info.center_x - info.halfsize + x * side;
    const double y0 = info.center_y - info.halfsize + y * side;
    const double z0 = info.center_z - info.halfsize + z * side;
    return {x0, y0, z0, x0 + side, y0 + side, z0 + side};
}

std::optional<CopcHierarchy> read_copc_hierarchy(const RandomAccessFile& file, const LasHeader& header) {
    if (!header.laz || header.version_minor < 4 || header.header_size < 375) return std::nullopt;
    const std::string& path = file.path();
    const uint64_t file_size = file.size();
    // The info VLR is the first VLR, right after the header.
    char vh[54 + 160];
    if (!file.read_exact_at(header.header_size, vh, sizeof vh)) return std::nullopt;
    if (user_id(vh + 2) != "copc" || get<uint16_t>(vh + 18) != 1) return std::nullopt;
    if (get<uint16_t>(vh + 20) < 160) throw Error(path, "COPC info VLR is shorter than 160 bytes");
    const char* p = vh + 54;
    CopcHierarchy h;
    CopcInfo& info = h.info;
    info.center_x = get<double>(p), info.center_y = get<double>(p + 8), info.center_z = get<double>(p + 16);
    info.halfsize = get<double>(p + 24), info.spacing = get<double>(p + 32);
    info.root_hierarchy_offset = get<uint64_t>(p + 40), info.root_hierarchy_size = get<uint64_t>(p + 48);
    info.gps_time_min = get<double>(p + 56), info.gps_time_max = get<double>(p + 64);
    if (!(info.halfsize > 0) || !std::isfinite(info.halfsize) || !std::isfinite(info.center_x) || !std::isfinite(info.center_y) ||
        !std::isfinite(info.center_z))
        throw Error(path, "COPC info VLR has an invalid root cube");
    // Pages: (offset, size), each a list of 32-byte entries; -1 points = a child page.
    std::vector<std::pair<uint64_t, uint64_t>> todo{{info.root_hierarchy_offset, info.root_hierarchy_size}};
    std::set<uint64_t> seen;
    while (!todo.empty()) {
        const auto [off, size] = todo.back();
        todo.pop_back();
        if (size % 32 != 0 || off > file_size || size > file_size - off)
            throw Error(path, "COPC hierarchy page at " + std::to_string(off) + " (" + std::to_string(size) +
                                  " bytes) lies outside the file or is not a whole number of entries");
        if (!seen.insert(off).second) throw Error(path, "COPC hierarchy pages form a loop (page at " + std::to_string(off) + ")");
        ++h.pages;
        std::vector<char> page(static_cast<std::size_t>(size));
        if (!file.read_exact_at(off, page.data(), page.size())) throw Error(path, "COPC hierarchy page at " + std::to_string(off) + ": the file ends inside it");
        for (std::size_t e = 0; e + 32 <= page.size(); e += 32) {
            const char* q = page.data() + e;
            CopcNode n;
            n.level = get<int32_t>(q), n.x = get<int32_t>(q + 4), n.y = get<int32_t>(q + 8), n.z = get<int32_t>(q + 12);
            n.offset = get<uint64_t>(q + 16);
            n.byte_size = get<int32_t>(q + 24);
            n.point_count = get<int32_t>(q + 28);
            if (n.level < 0 || n.level > 30 || n.x < 0 || n.y < 0 || n.z < 0 || (n.level < 31 && (n.x >> n.level) != 0))
                throw Error(path, "COPC hierarchy has an invalid voxel key " + n.key());
            if (n.point_count == -1) {
                if (n.byte_size < 0) throw Error(path, "COPC hierarchy child page of " + n.key() + " has a negative size");
                todo.push_back({n.offset, static_cast<uint64_t>(n.byte_size)});
            } else if (n.point_count > 0) {
                h.max_level = std::max(h.max_level, n.level);
                h.nodes.push_back(n);
            } else if (n.point_count < -1) {
                throw Error(path, "COPC hierarchy node " + n.key() + " has point count " + std::to_string(n.point_count));
            }
        }
    }
    std::sort(h.nodes.begin(), h.nodes.end(), [](const CopcNode& a, const CopcNode& b) { return a.offset < b.offset; });
    return h;
}

std::vector<bool> copc_chunks_in_box(const CopcHierarchy& h, const std::vector<LazChunk>& chunks, double min_x, double min_y,
                                     double max_x, double max_y, double pad, int max_level, const std::string& path) {
    if (h.nodes.size() != chunks.size())
        throw Error(path, "COPC hierarchy lists " + std::to_string(h.nodes.size()) + " nodes with points but the chunk table " +
                              std::to_string(chunks.size()) + " chunks");
    std::vector<bool> keep(chunks.size(), false);
    for (std::size_t i = 0; i < chunks.size(); ++i) {
        const CopcNode& n = h.nodes[i];
        if (n.offset != chunks[i].offset || static_cast<uint64_t>(n.point_count) != chunks[i].point_count)
            throw Error(path, "COPC node " + n.key() + " (offset " + std::to_string(n.offset) + ", " + std::to_string(n.point_count) +
                                  " points) does not match chunk " + std::to_string(i) + " of the chunk table");
        if (max_level >= 0 && n.level > max_level) continue;
        const auto b = n.bounds(h.info);
        keep[i] = b[0] - pad < max_x && b[3] + pad >= min_x && b[1] - pad < max_y && b[4] + pad >= min_y;
    }
    return keep;
}

}  // namespace cityforge
