#pragma once
// `cityforge cloud translate`: any cloud we read (LAS, LAZ, COPC, PLY, XYZ)
// to an uncompressed LAS file, optionally cropped to a box (like
// `pdal translate` / `las2las`). LAS/LAZ input keeps its header, point format
// and VLRs/EVLRs: the LASzip VLR and the COPC records are dropped, the
// compression bit cleared, offsets and counts updated, and the point records
// are written byte for byte as stored (LAS) or decoded (LAZ). PLY/XYZ input
// becomes LAS 1.4 point format 7 at 1 mm (no CRS: those formats carry none
// unless `crs_wkt` gives one).
#include <array>
#include <cstdint>
#include <optional>
#include <string>

namespace cityforge {

struct CloudTranslateOptions {
    std::string input;
    std::string output;  ///< .las
    /// Keep only points with min_x <= x <= max_x and min_y <= y <= max_y
    /// ({min_x, min_y, max_x, max_y}, file CRS units); unset = all points.
    std::optional<std::array<double, 4>> bounds;
    std::string crs_wkt;     ///< PLY/XYZ input only: CRS to store (empty = none)
    bool overwrite = false;  ///< replace an existing output
    /// Throws Error for a missing input/output, output == input, a non-.las
    /// output name, or an empty/inverted box.
    void validate() const;
};

struct CloudTranslateResult {
    uint64_t points_read = 0;     ///< points decoded from the input
    uint64_t points_written = 0;
    bool decompressed = false;    ///< the input was LAZ
    bool copc_nodes_skipped = false;  ///< a COPC crop decoded only some nodes
    uint64_t laz_chunks = 0;          ///< chunks of a LAZ input
    uint64_t laz_chunks_skipped = 0;  ///< of them, not decoded: COPC nodes, or layered chunks whose XY layer has no point in --bounds
    std::string points_sha256;    ///< SHA-256 of the written point records
};

/// Writes options.output (temporary file + rename: no half-written output).
/// Throws Error naming the file on unreadable input, an existing output
/// without `overwrite`, or a crop that keeps no point.
CloudTranslateResult translate_cloud(const CloudTranslateOptions& options);

}  // namespace cityforge
