#pragma once
// Roof texture atlas of a city model cut from its ortho: the layout
// (model/roof_texture) filled with the ortho's pixels (GDAL), PNG-encoded.
#include <string>

#include "model/roof_texture.hpp"

namespace cityforge {

/// Cuts every LOD2 building's roof window from `ortho_path` at the ortho's
/// GSD. Byte bands are copied unchanged (bands 1-3; one band is repeated as
/// grey); other sample types are scaled linearly between the atlas' 2nd and
/// 98th percentiles per band. Throws Error naming the ortho when it cannot be
/// read or its horizontal CRS is not the model's.
RoofTextureAtlas build_roof_texture_atlas(const CityModel& model, const std::string& ortho_path, const RoofTextureOptions& options = {});

}  // namespace cityforge
