#pragma once
// CityJSON 2.0 export of a CityModel (one .city.json document) and
// CityJSONSeq (.city.jsonl: a header line, then one CityJSONFeature per
// building). Integer vertices with `transform`, `referenceSystem` naming the
// compound CRS, semantic surfaces, `geographicalExtent`, metadata. Written to
// a temporary file renamed when complete.
#include <string>
#include <vector>

#include "model/building_model.hpp"

namespace cityforge {

struct CityJsonWriteOptions {
    std::vector<int> lods{0, 1, 2};  ///< geometries written per building, when the building has them
    double scale = 0.001;            ///< vertex quantum, CRS units (0.001 = millimetres)
    bool sequence = false;           ///< CityJSONSeq (JSON Lines) instead of one document
};

struct CityJsonWriteReport {
    std::size_t buildings = 0;  ///< CityObjects written (every building, with or without geometry)
    std::size_t vertices = 0;   ///< vertices written (deduplicated per document or per feature)
};

/// Throws Error naming `path` when the model's CRS has no EPSG code or the
/// file cannot be written.
CityJsonWriteReport write_cityjson(const std::string& path, const CityModel& model, const CityJsonWriteOptions& options = {});

}  // namespace cityforge
