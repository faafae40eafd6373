#pragma once
// CityJSON 2.0 export of a CityModel (one .city.json document) and
// CityJSONSeq (.city.jsonl: a header line, then one CityJSONFeature per
// building). Integer vertices with `transform`, `referenceSystem` naming the
// compound CRS, semantic surfaces, `geographicalExtent`, metadata. Written to
// a temporary file renamed when complete. LODs are the refined ones, named as
// 3DBAG names them: the Building has "0" (footprint) and "1.2" (LOD1 prism, one
// height per footprint); each roof part is a BuildingPart "<id>-<k>" with "1.3"
// (a block at the part's height) and "2.2" (its LOD2 roof, walls and ground).
#include <string>
#include <vector>

#include "model/building_model.hpp"
#include "model/roof_texture.hpp"

namespace cityforge {

struct CityJsonWriteOptions {
    /// Geometries written per building, when it has them: 0 footprint, 1 LOD1.2 + LOD1.3, 2 LOD2.2.
    std::vector<int> lods{0, 1, 2};
    double scale = 0.001;            ///< vertex quantum, CRS units (0.001 = millimetres)
    bool sequence = false;           ///< CityJSONSeq (JSON Lines) instead of one document
    /// Roof textures: LOD2.2 roof surfaces get texture coordinates into `texture_image`
    /// (theme "ortho"), every LOD2.2 surface a plain material by type (theme "surfaces").
    /// Null = none. Must outlive the call.
    const RoofTextureLayout* textures = nullptr;
    std::string texture_image = "textures/roofs.png";  ///< the atlas, relative to the written file
};

struct CityJsonWriteReport {
    std::size_t buildings = 0;  ///< Buildings written (every building, with or without geometry; BuildingParts not counted)
    std::size_t vertices = 0;   ///< vertices written (deduplicated per document or per feature)
    std::size_t textured_buildings = 0;  ///< buildings whose LOD2.2 roofs carry texture coordinates
};

/// metadata.referenceSystem names the model's EPSG code; without any code it
/// is left out (CityJSON has no place for a WKT). Throws Error naming `path`
/// when the file cannot be written.
CityJsonWriteReport write_cityjson(const std::string& path, const CityModel& model, const CityJsonWriteOptions& options = {});

}  // namespace cityforge
