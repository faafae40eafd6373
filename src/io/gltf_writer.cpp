#include "io/gltf_writer.hpp"

#include <cmath>
#include <cstring>
#include <limits>
#include <map>

#include "core/error.hpp"
#include "core/version.hpp"
#include "model/face_mesh.hpp"

namespace cityforge {
namespace {

using json = nlohmann::json;

std::string property_id(const std::string& name) {
    std::string s;
    for (char c : name) s += (std::isalnum(static_cast<unsigned char>(c)) || c == '_') ? c : '_';
    if (s.empty() || std::isdigit(static_cast<unsigned char>(s[0]))) s = "_" + s;
    return s;
}

// The binary chunk: every view starts on 8 bytes (float64 metadata needs it).
class BinaryBuffer {
public:
    int add_view(const void* data, std::size_t bytes, std::optional<int> target, json& views) {
        while (bytes_.size() % 8) bytes_.push_back('\0');
        json v = {{"buffer", 0}, {"byteOffset", bytes_.size()}, {"byteLength", bytes}};
        if (target) v["target"] = *target;
        bytes_.append(static_cast<const char*>(data), bytes);
        views.push_back(v);
        return static_cast<int>(views.size()) - 1;
    }
    std::string& bytes() { return bytes_; }

private:
    std::string bytes_;
};

struct Primitive {
    std::vector<float> positions, normals, feature_ids, uvs;
    std::vector<uint32_t> indices;
    std::vector<uint32_t> distinct;  // feature ids seen, ascending (buildings come in order)
};

std::optional<double> number_of(const AttributeValue& v) {
    if (std::holds_alternative<double>(v)) return std::get<double>(v);
    if (std::holds_alternative<int64_t>(v)) return double(std::get<int64_t>(v));
    return std::nullopt;
}

const AttributeValue* attribute_of(const Building& b, const std::string& name) {
    for (const auto& [n, v] : b.attributes)
        if (n == name) return &v;
    return nullptr;
}

// A building's value for a property: a string, a number or null.
AttributeValue property_value(const Building& b, const std::string& lod, const GltfProperty& p) {
    auto opt = [](const std::optional<double>& v) { return v ? AttributeValue(*v) : AttributeValue(); };
    if (p.source == "id") return b.id;
    if (p.source == "status") return b.status;
    if (p.source == "reason") return b.reason;
    if (p.source == "lod") return lod;
    if (p.source == "height_m") return opt(b.height_m);
    if (p.source == "ground_z") return opt(b.ground_z);
    if (p.source == "roof_z") return opt(b.roof_z);
    if (p.source == "roof_type") return b.roof_type;
    const AttributeValue* v = attribute_of(b, p.source);
    return v ? *v : AttributeValue();
}

std::string text_of(const AttributeValue& v) {
    if (std::holds_alternative<std::string>(v)) return std::get<std::string>(v);
    if (std::holds_alternative<int64_t>(v)) return std::to_string(std::get<int64_t>(v));
    if (std::holds_alternative<double>(v)) {
        json j = std::get<double>(v);
        return j.dump();
    }
    return "";
}

}  // namespace

std::vector<GltfProperty> building_properties(const CityModel& model) {
    std::vector<GltfProperty> props{{"id", "id", GltfPropertyType::string},         {"status", "status", GltfPropertyType::string},
                                    {"reason", "reason", GltfPropertyType::string}, {"lod", "lod", GltfPropertyType::string},
                                    {"height_m", "height_m", GltfPropertyType::float64}, {"ground_z", "ground_z", GltfPropertyType::float64},
                                    {"roof_z", "roof_z", GltfPropertyType::float64},     {"roof_type", "roof_type", GltfPropertyType::string}};
    std::map<std::string, int> used;
    for (const GltfProperty& p : props) used[p.name] = 1;
    if (model.buildings.empty()) return props;
    const auto& first = model.buildings.front().attributes;
    for (std::size_t k = 0; k < first.size(); ++k) {
        GltfPropertyType t = GltfPropertyType::string;
        for (const Building& b : model.buildings) {
            if (k >= b.attributes.size()) continue;
            const AttributeValue& v = b.attributes[k].second;
            if (std::holds_alternative<std::monostate>(v)) continue;
            t = std::holds_alternative<int64_t>(v) ? GltfPropertyType::int64
                : std::holds_alternative<double>(v) ? GltfPropertyType::float64
                                                    : GltfPropertyType::string;
            break;
        }
        std::string id = property_id(first[k].first);
        if (used[id]++) id = "attr_" + id;  // a source attribute named like one of ours
        for (int n = 2; used[id] > 1; ++n) id = property_id(first[k].first) + "_" + std::to_string(n), used[id]++;
        props.push_back({id, first[k].first, t});
    }
    return props;
}

std::string encode_glb(const GlbContent& c, const std::vector<GltfProperty>& properties, GlbStats* stats) {
    if (c.faces.size() != c.buildings.size() || c.lods.size() != c.buildings.size() || (!c.uv.empty() && c.uv.size() != c.buildings.size()))
        throw Error("glTF", "internal: one face list, one LOD (and one texture coordinate list) per building are required");
    if (!c.uv.empty() && c.texture_png.empty()) throw Error("glTF", "internal: texture coordinates without an image");
    std::array<Primitive, 4> prims;  // ground, wall, roof, textured roof
    auto type_index = [](SurfaceType t) { return t == SurfaceType::ground ? 0 : t == SurfaceType::wall ? 1 : 2; };
    GlbStats st;
    for (std::size_t b = 0; b < c.buildings.size(); ++b) {
        for (std::size_t fi = 0; fi < c.faces[b].size(); ++fi) {
            const Face& f = c.faces[b][fi];
            const std::vector<std::array<float, 2>>* uv = !c.uv.empty() && fi < c.uv[b].size() && !c.uv[b][fi].empty() ? &c.uv[b][fi] : nullptr;
            const auto tris = triangulate_face(f);
            if (tris.empty()) continue;
            auto n = newell_normal(f.outer);
            const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            if (!(len > 0)) continue;
            for (double& v : n) v /= len;
            const std::vector<Point3> verts = face_vertices(f);
            if (uv && uv->size() != verts.size()) throw Error("glTF", "internal: one texture coordinate per face vertex is required");
            Primitive& p = prims[uv ? 3 : type_index(f.type)];
            if (uv)
                for (const auto& t : *uv) p.uvs.insert(p.uvs.end(), {t[0], t[1]});
            const uint32_t base = static_cast<uint32_t>(p.positions.size() / 3);
            for (const Point3& q : verts) {
                // z-up (x, y, z) -> glTF y-up (x, z, -y)
                p.positions.insert(p.positions.end(), {float(q.x), float(q.z), float(-q.y)});
                p.normals.insert(p.normals.end(), {float(n[0]), float(n[2]), float(-n[1])});
                p.feature_ids.push_back(float(b));
            }
            for (const auto& t : tris) {
                // Skip triangles that collapse in float (the validator flags them).
                auto at = [&](uint32_t i) { return &p.positions[3 * (base + i)]; };
                const float *a = at(t[0]), *bq = at(t[1]), *cq = at(t[2]);
                const double ux = bq[0] - a[0], uy = bq[1] - a[1], uz = bq[2] - a[2];
                const double vx = cq[0] - a[0], vy = cq[1] - a[1], vz = cq[2] - a[2];
                const double cx = uy * vz - uz * vy, cy = uz * vx - ux * vz, cz = ux * vy - uy * vx;
                if (!(cx * cx + cy * cy + cz * cz > 1e-12)) continue;
                if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
                p.indices.insert(p.indices.end(), {base + t[0], base + t[1], base + t[2]});
                ++st.triangles;
            }
            if (p.distinct.empty() || p.distinct.back() != b) p.distinct.push_back(static_cast<uint32_t>(b));
            st.vertices += verts.size();
        }
    }
    st.features = c.buildings.size();

    json gltf;
    gltf["asset"] = {{"version", "2.0"}, {"generator", std::string("cityforge ") + version()}};
    if (!c.extras.is_null()) gltf["asset"]["extras"] = c.extras;
    json views = json::array(), accessors = json::array(), meshes_prims = json::array();
    BinaryBuffer bin;
    const char* material_names[4] = {"GroundSurface", "WallSurface", "RoofSurface", "RoofSurface"};
    const std::array<std::array<double, 4>, 4> colours{{{0.45, 0.42, 0.38, 1.0}, {0.86, 0.84, 0.78, 1.0}, {0.72, 0.30, 0.24, 1.0}, {1.0, 1.0, 1.0, 1.0}}};
    json materials = json::array();
    for (int k = 0; k < 4; ++k) {
        const Primitive& p = prims[k];
        if (p.indices.empty()) continue;
        // Only vertices that some triangle uses would be tidier; every face vertex is used by its triangles
        // unless its face collapsed, which the validator reports as unused data only (not an error).
        std::array<float, 3> lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
        for (std::size_t i = 0; i < p.positions.size(); ++i) lo[i % 3] = std::min(lo[i % 3], p.positions[i]), hi[i % 3] = std::max(hi[i % 3], p.positions[i]);
        const std::size_t nv = p.positions.size() / 3;
        const int pos_view = bin.add_view(p.positions.data(), p.positions.size() * 4, 34962, views);
        accessors.push_back({{"bufferView", pos_view}, {"componentType", 5126}, {"count", nv}, {"type", "VEC3"},
                             {"min", {lo[0], lo[1], lo[2]}}, {"max", {hi[0], hi[1], hi[2]}}});
        const int pos_acc = static_cast<int>(accessors.size()) - 1;
        const int nrm_view = bin.add_view(p.normals.data(), p.normals.size() * 4, 34962, views);
        accessors.push_back({{"bufferView", nrm_view}, {"componentType", 5126}, {"count", nv}, {"type", "VEC3"}});
        const int nrm_acc = static_cast<int>(accessors.size()) - 1;
        const int fid_view = bin.add_view(p.feature_ids.data(), p.feature_ids.size() * 4, 34962, views);
        accessors.push_back({{"bufferView", fid_view}, {"componentType", 5126}, {"count", nv}, {"type", "SCALAR"}});
        const int fid_acc = static_cast<int>(accessors.size()) - 1;
        const int idx_view = bin.add_view(p.indices.data(), p.indices.size() * 4, 34963, views);
        accessors.push_back({{"bufferView", idx_view}, {"componentType", 5125}, {"count", p.indices.size()}, {"type", "SCALAR"}});
        const int idx_acc = static_cast<int>(accessors.size()) - 1;
        json mat = {{"name", k == 3 ? "RoofSurface (ortho texture)" : material_names[k]},
                    {"pbrMetallicRoughness", {{"baseColorFactor", colours[k]}, {"metallicFactor", 0.0}, {"roughnessFactor", 0.9}}},
                    {"doubleSided", true}};
        json attributes = {{"POSITION", pos_acc}, {"NORMAL", nrm_acc}, {"_FEATURE_ID_0", fid_acc}};
        if (k == 3) {
            const int uv_view = bin.add_view(p.uvs.data(), p.uvs.size() * 4, 34962, views);
            accessors.push_back({{"bufferView", uv_view}, {"componentType", 5126}, {"count", nv}, {"type", "VEC2"}});
            attributes["TEXCOORD_0"] = static_cast<int>(accessors.size()) - 1;
            const int img_view = bin.add_view(c.texture_png.data(), c.texture_png.size(), std::nullopt, views);
            gltf["images"] = json::array({{{"bufferView", img_view}, {"mimeType", "image/png"}, {"name", "roofs (ortho)"}}});
            gltf["samplers"] = json::array({{{"magFilter", 9728}, {"minFilter", 9729}, {"wrapS", 33071}, {"wrapT", 33071}}});
            gltf["textures"] = json::array({{{"source", 0}, {"sampler", 0}}});
            mat["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 0}};
        }
        materials.push_back(mat);
        json prim = {{"attributes", attributes},
                     {"indices", idx_acc},
                     {"material", static_cast<int>(materials.size()) - 1},
                     {"mode", 4}};
        prim["extensions"]["EXT_mesh_features"]["featureIds"] = json::array(
            {{{"featureCount", p.distinct.size()}, {"attribute", 0}, {"propertyTable", 0}, {"label", "building"}}});
        prim["extras"] = {{"surface", material_names[k]}};
        meshes_prims.push_back(prim);
    }
    if (meshes_prims.empty()) throw Error("glTF", "no triangles to write (no building has a valid LOD1 or LOD2 solid)");

    // EXT_structural_metadata: the class and one table with a row per building.
    json class_props = json::object(), table_props = json::object();
    const std::size_t rows = c.buildings.size();
    for (const GltfProperty& p : properties) {
        std::vector<AttributeValue> values(rows);
        for (std::size_t r = 0; r < rows; ++r) values[r] = property_value(*c.buildings[r], c.lods[r], p);
        json def;
        if (p.type == GltfPropertyType::string) {
            std::string data;
            std::vector<uint32_t> offsets{0};
            for (const AttributeValue& v : values) data += text_of(v), offsets.push_back(static_cast<uint32_t>(data.size()));
            def = {{"type", "STRING"}};
            if (data.empty()) {  // every value empty: the column is left out (a buffer view cannot be empty)
                class_props[p.name] = {{"type", "STRING"}, {"required", false}};
                continue;
            }
            const int dv = bin.add_view(data.data(), data.size(), std::nullopt, views);
            const int ov = bin.add_view(offsets.data(), offsets.size() * 4, std::nullopt, views);
            table_props[p.name] = {{"values", dv}, {"stringOffsets", ov}, {"stringOffsetType", "UINT32"}};
        } else if (p.type == GltfPropertyType::float64) {
            std::vector<double> data(rows);
            for (std::size_t r = 0; r < rows; ++r) {
                const auto v = number_of(values[r]);
                data[r] = v && std::isfinite(*v) ? *v : kGltfNoData;
            }
            def = {{"type", "SCALAR"}, {"componentType", "FLOAT64"}, {"noData", kGltfNoData}};
            table_props[p.name] = {{"values", bin.add_view(data.data(), data.size() * 8, std::nullopt, views)}};
        } else {
            std::vector<int64_t> data(rows);
            for (std::size_t r = 0; r < rows; ++r)
                data[r] = std::holds_alternative<int64_t>(values[r]) ? std::get<int64_t>(values[r]) : int64_t(kGltfNoData);
            def = {{"type", "SCALAR"}, {"componentType", "INT64"}, {"noData", int64_t(kGltfNoData)}};
            table_props[p.name] = {{"values", bin.add_view(data.data(), data.size() * 8, std::nullopt, views)}};
        }
        if (p.name != p.source) def["description"] = "source attribute '" + p.source + "'";
        if (p.name != "id") def["required"] = false;
        else def["required"] = true, def.erase("noData");
        if (def.value("required", false) || p.type == GltfPropertyType::string) def.erase("noData");
        class_props[p.name] = def;
    }
    // Strings have no noData: an empty string means missing.
    gltf["extensions"]["EXT_structural_metadata"] = {
        {"schema", {{"id", "cityforge_buildings"}, {"classes", {{"building", {{"name", "Building"}, {"properties", class_props}}}}}}},
        {"propertyTables", json::array({{{"name", "buildings"}, {"class", "building"}, {"count", rows}, {"properties", table_props}}})}};
    gltf["extensionsUsed"] = {"EXT_mesh_features", "EXT_structural_metadata"};
    gltf["materials"] = materials;
    gltf["meshes"] = json::array({{{"name", "buildings"}, {"primitives", meshes_prims}}});
    json node = {{"mesh", 0}, {"name", "buildings"}};
    const auto& t = c.translation;
    if (t[0] != 0 || t[1] != 0 || t[2] != 0) node["translation"] = {t[0], t[2], -t[1]};
    gltf["nodes"] = json::array({node});
    gltf["scenes"] = json::array({{{"nodes", {0}}}});
    gltf["scene"] = 0;
    gltf["accessors"] = accessors;
    gltf["bufferViews"] = views;
    std::string& body = bin.bytes();
    while (body.size() % 4) body.push_back('\0');
    gltf["buffers"] = json::array({{{"byteLength", body.size()}}});

    std::string js = gltf.dump();
    while (js.size() % 4) js.push_back(' ');
    std::string out;
    auto u32 = [&](uint32_t v) { out.append(reinterpret_cast<const char*>(&v), 4); };
    const std::size_t total = 12 + 8 + js.size() + 8 + body.size();
    if (total > std::numeric_limits<uint32_t>::max()) throw Error("glTF", "more than 4 GiB of mesh data in one glb; use 3D Tiles");
    out.reserve(total);
    u32(0x46546C67u), u32(2), u32(static_cast<uint32_t>(total));
    u32(static_cast<uint32_t>(js.size())), u32(0x4E4F534Au), out += js;
    u32(static_cast<uint32_t>(body.size())), u32(0x004E4942u), out += body;
    if (stats) *stats = st;
    return out;
}

}  // namespace cityforge
