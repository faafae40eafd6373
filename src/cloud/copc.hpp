#pragma once
// COPC (Cloud Optimized Point Cloud, copc.io 1.0): a LAS 1.4 / LAZ file whose
// first VLR is the COPC info record (user "copc", record 1) and whose EVLR
// "copc"/1000 holds an octree hierarchy; every octree node with points is one
// variable-size LAZ chunk. A window query selects the chunks (nodes) whose
// cube meets the window, so only those are decoded.
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cloud/las.hpp"

namespace cityforge {

/// The COPC info VLR (coordinates in the file's CRS units).
struct CopcInfo {
    double center_x = 0, center_y = 0, center_z = 0;  ///< root cube centre
    double halfsize = 0;                              ///< root cube half side
    double spacing = 0;                               ///< point spacing at the root level
    uint64_t root_hierarchy_offset = 0, root_hierarchy_size = 0;
    double gps_time_min = 0, gps_time_max = 0;
};

/// One octree node that holds points (a LAZ chunk).
struct CopcNode {
    int32_t level = 0, x = 0, y = 0, z = 0;  ///< voxel key
    uint64_t offset = 0;                     ///< file offset of its chunk
    int32_t byte_size = 0;
    int32_t point_count = 0;
    /// "level-x-y-z", as COPC tools print keys.
    std::string key() const;
    /// Cube bounds {min_x, min_y, min_z, max_x, max_y, max_z}.
    std::array<double, 6> bounds(const CopcInfo& info) const;
};

struct CopcHierarchy {
    CopcInfo info;
    std::vector<CopcNode> nodes;  ///< nodes with points, sorted by file offset (= chunk order)
    int max_level = 0;
    uint64_t pages = 0;           ///< hierarchy pages read
};

/// Reads the COPC info VLR and the whole hierarchy of `file` (LasReader::file(),
/// with `header` from that LasReader: the same open file as its points).
/// Returns nullopt when the file is not COPC; throws Error naming the file
/// for a corrupt hierarchy (pages outside the file, loops).
std::optional<CopcHierarchy> read_copc_hierarchy(const RandomAccessFile& file, const LasHeader& header);

/// For each chunk of `chunks`: true when its node's cube (x/y, padded by
/// `pad` CRS units) meets [min_x, max_x) × [min_y, max_y) and its level is
/// <= max_level (-1 = all levels). Throws Error when the chunk table and the
/// hierarchy disagree.
std::vector<bool> copc_chunks_in_box(const CopcHierarchy& h, const std::vector<LazChunk>& chunks, double min_x, double min_y,
                                     double max_x, double max_y, double pad, int max_level, const std::string& path);

}  // namespace cityforge
