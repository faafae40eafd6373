#pragma once
// glTF 2.0 binary (.glb) meshes of buildings: one primitive per surface type
// (ground, wall, roof: each its own material), flat normals, per-building
// feature ids (EXT_mesh_features) and a property table of the buildings'
// attributes (EXT_structural_metadata), as 3D Tiles 1.1 content or as a
// standalone model. Textured roofs (from the ortho) are a fourth primitive
// whose material has a baseColorTexture. glTF is y-up: the encoder turns the z-up frame it is
// given into glTF's (x, z, -y).
#include <array>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "model/building_model.hpp"

namespace cityforge {

/// Type of a property table column.
enum class GltfPropertyType { string, float64, int64 };

/// One property of the buildings' metadata class ("building").
struct GltfProperty {
    std::string name;        ///< metadata property id: letters, digits, '_' (others are replaced by '_')
    std::string source;      ///< the building attribute it comes from (or id, status, reason, lod, height_m, ground_z, roof_z, roof_type)
    GltfPropertyType type = GltfPropertyType::string;
};

/// The properties written for every building of `model`: id, status, reason,
/// lod, height_m, ground_z, roof_z, roof_type, then every source attribute
/// (typed by its first non-null value). The same for every tile of a model.
std::vector<GltfProperty> building_properties(const CityModel& model);

/// Missing numbers in the property table (EXT_structural_metadata `noData`).
inline constexpr double kGltfNoData = -9999.0;

/// What to encode: buildings (property table rows, feature id = row) with
/// their faces in a local right-handed z-up frame (metres or CRS units), and
/// the translation of that frame (z-up too) written on the glb's node.
struct GlbContent {
    std::vector<const Building*> buildings;
    std::vector<std::vector<Face>> faces;  ///< per building, in the local frame
    std::vector<std::string> lods;          ///< per building: the LOD its faces are ("1.2", "2.2")
    /// Roof textures (optional): per building, per face, the (u, v) of each of
    /// face_vertices(face), glTF's convention (v down from the image's top);
    /// an empty list leaves the face untextured. Empty = no textures.
    std::vector<std::vector<std::vector<std::array<float, 2>>>> uv;
    std::string texture_png;                ///< the roofs' image (PNG bytes), embedded; required with `uv`
    std::array<double, 3> translation{0, 0, 0};
    nlohmann::json extras;                  ///< written as the asset's extras (CRS, origin) when not null
};

struct GlbStats {
    std::size_t triangles = 0, vertices = 0, features = 0;
};

/// The .glb bytes. Deterministic: same content, same bytes.
std::string encode_glb(const GlbContent& content, const std::vector<GltfProperty>& properties, GlbStats* stats = nullptr);

}  // namespace cityforge
