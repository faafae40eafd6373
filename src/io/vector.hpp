#pragma once
// Vector data through OGR: describing a dataset and writing polygon features
// (with holes) and attributes in a given CRS. Used for truth files, footprints
// and reports; algorithm modules hand us plain geometry.
#include <cstdint>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "core/geo_transform.hpp"
#include "crs/crs.hpp"

namespace cityforge {

struct VectorLayerInfo {
    std::string name;
    std::string geometry_type;  ///< OGR name, e.g. "Polygon", "Multi Polygon"
    int64_t feature_count = 0;
    CrsInfo crs;
    std::optional<Extent> extent;  ///< in the layer's CRS
    std::vector<std::string> fields;
};

struct VectorInfo {
    std::string path;
    std::string driver;
    std::vector<VectorLayerInfo> layers;
};

/// Opens `path` with OGR and describes its layers. Throws Error naming the
/// file when it is missing or not a vector dataset.
VectorInfo read_vector_info(const std::string& path);

/// A polygon ring: closed implicitly (first point not repeated), CRS units.
using Ring = std::vector<MapPoint>;

/// Polygon with holes: `outer` then any number of `holes`.
struct Polygon {
    Ring outer;
    std::vector<Ring> holes;
};

/// Attribute value of a feature (null = std::monostate).
using AttributeValue = std::variant<std::monostate, int64_t, double, std::string>;

struct Feature {
    Polygon geometry;
    std::vector<AttributeValue> values;  ///< one per field, in schema order
};

enum class FieldType { integer, real, string };
struct FieldDefinition {
    std::string name;
    FieldType type = FieldType::real;
};

struct VectorWriteOptions {
    std::string driver = "GeoJSON";  ///< any OGR driver name, e.g. "GPKG"
    std::string layer = "buildings";
    /// GeoJSON only: write RFC 7946 (WGS84 lon/lat, no crs member) instead of the native CRS.
    bool rfc7946 = false;
    int coordinate_precision = 0;  ///< 0 = driver default
};

/// Writes polygon features in `crs` (temporary file + rename). Rings are
/// written as given; the exterior counter-clockwise, holes clockwise is the
/// caller's job (see orient_polygon).
void write_polygon_features(const std::string& path, const CrsInfo& crs, const std::vector<FieldDefinition>& fields,
                            const std::vector<Feature>& features, const VectorWriteOptions& options = {});

/// Signed area of a ring (> 0 counter-clockwise), CRS units squared.
double signed_area(const Ring& ring);
/// Area of a polygon (outer minus holes), CRS units squared.
double polygon_area(const Polygon& polygon);
/// Makes the outer ring counter-clockwise and holes clockwise (OGC/RFC 7946).
void orient_polygon(Polygon& polygon);

}  // namespace cityforge
