#pragma once
// `cityforge info`: describe a raster, point cloud or vector file.
#include <map>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "cloud/copc.hpp"
#include "cloud/las.hpp"
#include "io/vector.hpp"
#include "raster/raster.hpp"

namespace cityforge {

struct InspectOptions {
    /// Read every point of a cloud to count classes and measure true bounds
    /// (header values are otherwise reported as written).
    bool cloud_statistics = false;
    /// Override/supply the CRS of a cloud or raster (any SetFromUserInput text).
    std::string assume_crs;
};

struct CloudInfo {
    std::string path;
    LasHeader header;
    CrsInfo crs;
    std::map<int, uint64_t> class_counts;  ///< only with cloud_statistics
    std::optional<std::array<double, 6>> measured_bounds;  ///< minx, miny, minz, maxx, maxy, maxz
    uint64_t laz_chunks = 0;          ///< LAZ: chunks of compressed points
    bool laz_chunk_table = false;     ///< LAZ: the file has a (valid) chunk table
    std::optional<CopcHierarchy> copc;  ///< COPC: info VLR and octree hierarchy
};

/// What `info` found; exactly one of the three is set.
struct DatasetInfo {
    std::optional<RasterInfo> raster;
    std::optional<CloudInfo> cloud;
    std::optional<VectorInfo> vector;
};

/// Detects the kind of `path` (LAS signature, then GDAL raster, then OGR
/// vector) and describes it. Throws Error naming the file if none fits.
DatasetInfo inspect_dataset(const std::string& path, const InspectOptions& options = {});

nlohmann::json to_json(const CrsInfo& crs);
nlohmann::json to_json(const DatasetInfo& info);
/// Human-readable multi-line description (like gdalinfo / lasinfo).
std::string to_text(const DatasetInfo& info);

}  // namespace cityforge
