#pragma once
// Lossless JSON form of a Building (one JSON object per line in the tile
// files of `cityforge run`): doubles round-trip exactly, attributes keep
// their types, solids keep their semantics. Schema: schemas/building_line.schema.json.
#include <nlohmann/json.hpp>

#include "model/building_model.hpp"

namespace cityforge {

nlohmann::json building_to_json(const Building& building);

/// Throws Error naming `where` on a malformed object.
Building building_from_json(const nlohmann::json& j, const std::string& where);

}  // namespace cityforge
