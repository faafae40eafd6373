#include "io/cityjson_writer.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <nlohmann/json.hpp>
#include <map>
#include <unordered_map>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/version.hpp"

namespace cityforge {
namespace {

using json = nlohmann::json;
using Key = std::array<int64_t, 3>;
struct KeyHash {
    std::size_t operator()(const Key& k) const noexcept {
        uint64_t h = 1469598103934665603ull;
        for (int64_t v : k) h = (h ^ static_cast<uint64_t>(v)) * 1099511628211ull;
        return static_cast<std::size_t>(h);
    }
};

// Quantised, deduplicated vertex list.
class VertexPool {
public:
    VertexPool(std::array<double, 3> translate, double scale) : t_(translate), s_(scale) {}
    int64_t add(double x, double y, double z) {
        const Key k{std::llround((x - t_[0]) / s_), std::llround((y - t_[1]) / s_), std::llround((z - t_[2]) / s_)};
        const auto [it, inserted] = index_.emplace(k, static_cast<int64_t>(list_.size()));
        if (inserted) list_.push_back(k);
        return it->second;
    }
    const std::vector<Key>& list() const { return list_; }
    void clear() { index_.clear(), list_.clear(); }

private:
    std::array<double, 3> t_;
    double s_;
    std::unordered_map<Key, int64_t, KeyHash> index_;
    std::vector<Key> list_;
};

// Deduplicated texture coordinates (CityJSON's origin is the image's bottom-left corner).
class UvPool {
public:
    int64_t add(double u, double v) {
        const std::array<int64_t, 2> k{std::llround(u * 1e7), std::llround(v * 1e7)};
        const auto [it, inserted] = index_.emplace(k, static_cast<int64_t>(list_.size()));
        if (inserted) list_.push_back(k);
        return it->second;
    }
    json list_json() const {
        json a = json::array();
        for (const auto& k : list_) a.push_back({double(k[0]) * 1e-7, double(k[1]) * 1e-7});
        return a;
    }
    bool empty() const { return list_.empty(); }
    void clear() { index_.clear(), list_.clear(); }

private:
    std::map<std::array<int64_t, 2>, int64_t> index_;
    std::vector<std::array<int64_t, 2>> list_;
};

json value_json(const AttributeValue& v) {
    if (std::holds_alternative<int64_t>(v)) return std::get<int64_t>(v);
    if (std::holds_alternative<double>(v)) return std::isfinite(std::get<double>(v)) ? json(std::get<double>(v)) : json(nullptr);
    if (std::holds_alternative<std::string>(v)) return std::get<std::string>(v);
    return nullptr;
}

json ring_json(const Ring3& r, VertexPool& pool) {
    json a = json::array();
    for (const Point3& p : r) a.push_back(pool.add(p.x, p.y, p.z));
    return a;
}

json face_json(const Face& f, VertexPool& pool) {
    json rings = json::array();
    rings.push_back(ring_json(f.outer, pool));
    for (const Ring3& h : f.holes) rings.push_back(ring_json(h, pool));
    return rings;
}

int semantic_index(SurfaceType t) { return t == SurfaceType::ground ? 0 : t == SurfaceType::wall ? 1 : 2; }

// Solid (one solid) or CompositeSolid (several) with semantics.
json solids_json(const std::vector<Solid>& solids, const std::string& lod, VertexPool& pool) {
    json g;
    json boundaries = json::array(), values = json::array();
    for (const Solid& s : solids) {
        json shell = json::array(), shell_values = json::array();
        for (const Face& f : s.faces) shell.push_back(face_json(f, pool)), shell_values.push_back(semantic_index(f.type));
        boundaries.push_back(json::array({shell}));
        values.push_back(json::array({shell_values}));
    }
    g["type"] = solids.size() == 1 ? "Solid" : "CompositeSolid";
    g["lod"] = lod;
    g["boundaries"] = solids.size() == 1 ? boundaries[0] : boundaries;
    g["semantics"] = {{"surfaces", json::array({{{"type", "GroundSurface"}}, {{"type", "WallSurface"}}, {{"type", "RoofSurface"}}})},
                      {"values", solids.size() == 1 ? values[0] : values}};
    return g;
}

// Theme "ortho": texture coordinates of the roof rings (texture 0), null for the other surfaces;
// theme "surfaces": a plain material per surface type (0 ground, 1 wall, 2 roof).
void add_roof_texture(json& g, const Solid& s, const RoofTextureLayout& t, const RoofTextureWindow& w, UvPool& uvs) {
    json shell = json::array(), mats = json::array();
    for (const Face& f : s.faces) {
        mats.push_back(semantic_index(f.type));
        if (f.type != SurfaceType::roof) {
            shell.push_back(json::array({json::array({nullptr})}));
            continue;
        }
        json rings = json::array();
        auto ring = [&](const Ring3& r) {
            json a = json::array({0});
            for (const Point3& p : r) {
                const auto uv = t.uv(w, p.x, p.y);
                a.push_back(uvs.add(uv[0], 1.0 - uv[1]));
            }
            rings.push_back(a);
        };
        ring(f.outer);
        for (const Ring3& h : f.holes) ring(h);
        shell.push_back(rings);
    }
    g["texture"] = {{"ortho", {{"values", json::array({shell})}}}};
    g["material"] = {{"surfaces", {{"values", json::array({mats})}}}};
}

json appearance_json(const CityJsonWriteOptions& o, const UvPool& uvs) {
    json a;
    a["materials"] = json::array({{{"name", "GroundSurface"}, {"diffuseColor", {0.45, 0.42, 0.38}}},
                                  {{"name", "WallSurface"}, {"diffuseColor", {0.86, 0.84, 0.78}}},
                                  {{"name", "RoofSurface"}, {"diffuseColor", {0.72, 0.30, 0.24}}}});
    a["textures"] = json::array({{{"type", "PNG"}, {"image", o.texture_image}, {"wrapMode", "clamp"}, {"textureType", "specific"}}});
    a["vertices-texture"] = uvs.list_json();
    a["default-theme-texture"] = "ortho";
    a["default-theme-material"] = "surfaces";
    return a;
}

// The Building and its BuildingParts (one per roof part: LOD1.3 block and LOD2.2 solid), as (id, object) pairs.
std::vector<std::pair<std::string, json>> building_objects(const Building& b, std::size_t index, const CityJsonWriteOptions& o, const ModelCrs& crs,
                                                           VertexPool& pool, UvPool& uvs, double fallback_z) {
    const RoofTextureWindow* tex = o.textures ? o.textures->window_of(index) : nullptr;
    json obj;
    obj["type"] = "Building";
    json attrs = json::object();
    for (const auto& [name, value] : b.attributes) attrs[name] = value_json(value);
    attrs["status"] = b.status;
    if (!b.reason.empty()) attrs["reason"] = b.reason;
    if (b.height_m) attrs["measuredHeight"] = *b.height_m;
    if (b.ground_z) attrs["ground_z"] = *b.ground_z;
    const bool want0 = std::find(o.lods.begin(), o.lods.end(), 0) != o.lods.end();
    if (want0 && !b.ground_z && !b.footprint.empty()) attrs["footprint_z_estimated"] = true;  // no ground here: the model's median
    const double z0 = b.ground_z ? *b.ground_z : fallback_z;
    const bool want1 = std::find(o.lods.begin(), o.lods.end(), 1) != o.lods.end();
    const bool want2 = std::find(o.lods.begin(), o.lods.end(), 2) != o.lods.end();
    const double unit3 = crs.volume_unit_m3();
    // Refined LODs, named as 3DBAG names them (lod12 = "1.2", ...); the list of those written in `lods`.
    json lods = json::array();
    if (want0 && !b.footprint.empty()) lods.push_back("0");
    if (want1 && !b.lod1.empty()) {
        lods.push_back("1.2");
        attrs["lod12_valid"] = b.lod1_errors.empty();
        if (!b.lod1_errors.empty()) attrs["lod12_errors"] = b.lod1_errors;
        attrs["lod12_volume_m3"] = b.lod1_volume * unit3;
    }
    const std::vector<RoofPart>& parts = b.roof_parts;
    auto part_errors = [&](bool lod13) {
        json all = json::array();
        for (std::size_t i = 0; i < parts.size(); ++i)
            for (const std::string& e : lod13 ? parts[i].lod13_errors : parts[i].lod22_errors) all.push_back("part " + std::to_string(i) + ": " + e);
        return all;
    };
    const bool with13 = want1 && !parts.empty(), with22 = want2 && !parts.empty();
    // LOD1.3 or LOD2.2 over the roof parts: validity, errors and the summed volume.
    auto part_lod = [&](bool lod13) {
        const std::string key = lod13 ? "lod13" : "lod22";
        lods.push_back(lod13 ? "1.3" : "2.2");
        const json e = part_errors(lod13);
        double v = 0;
        for (const RoofPart& p : parts) v += lod13 ? p.lod13_volume : p.lod22_volume;
        attrs[key + "_valid"] = e.empty();
        if (!e.empty()) attrs[key + "_errors"] = e;
        attrs[key + "_volume_m3"] = v * unit3;
    };
    if (with13) part_lod(true);
    if (with22) {
        part_lod(false);
        attrs["lod22_parts"] = parts.size();
        if (!b.roof_parts_unsplit.empty()) attrs["lod22_unsplit"] = b.roof_parts_unsplit;
        if (!b.roof_type.empty()) attrs["roofType"] = b.roof_type;
        if (tex) attrs["roof_textured"] = true;
    }
    attrs["lods"] = lods;
    obj["attributes"] = attrs;
    json geometry = json::array();
    if (want0 && !b.footprint.empty()) {
        json surfaces = json::array();
        for (const Polygon& p : b.footprint) {
            Face f;
            for (const MapPoint& q : p.outer) f.outer.push_back({q.x, q.y, z0});
            for (const Ring& h : p.holes) {
                f.holes.emplace_back();
                for (const MapPoint& q : h) f.holes.back().push_back({q.x, q.y, z0});
            }
            surfaces.push_back(face_json(f, pool));
        }
        geometry.push_back({{"type", "MultiSurface"}, {"lod", "0"}, {"boundaries", surfaces}});
    }
    if (want1 && !b.lod1.empty()) geometry.push_back(solids_json(b.lod1, "1.2", pool));
    obj["geometry"] = geometry;
    // Extent of this building (footprint x/y; z from its solids or ground).
    const auto e = building_extent(b);
    obj["geographicalExtent"] = {e[0], e[1], e[2], e[3], e[4], e[5]};
    std::vector<std::pair<std::string, json>> out;
    if (with13 || with22) {
        json children = json::array();
        for (std::size_t i = 0; i < parts.size(); ++i) children.push_back(b.id + "-" + std::to_string(i));
        obj["children"] = children;
    }
    out.emplace_back(b.id, std::move(obj));
    if (with13 || with22)
        for (std::size_t i = 0; i < parts.size(); ++i) {
            const RoofPart& p = parts[i];
            json part;
            part["type"] = "BuildingPart";
            part["parents"] = json::array({b.id});
            json pa = {{"roof_part", i}, {"footprint_part", p.solid}};
            json g = json::array();
            if (with13 && !p.lod13.faces.empty()) {
                pa["lod13_roof_z"] = p.lod13_roof_z;
                pa["lod13_height_m"] = (p.lod13_roof_z - p.ground_z) * crs.z_unit_m;
                pa["lod13_valid"] = p.lod13_errors.empty();
                pa["lod13_volume_m3"] = p.lod13_volume * unit3;
                g.push_back(solids_json({p.lod13}, "1.3", pool));
            }
            if (with22) {
                pa["lod22_valid"] = p.lod22_errors.empty();
                pa["lod22_volume_m3"] = p.lod22_volume * unit3;
                json g22 = solids_json({p.lod22}, "2.2", pool);
                if (tex) add_roof_texture(g22, p.lod22, *o.textures, *tex, uvs);
                g.push_back(std::move(g22));
            }
            part["attributes"] = pa;
            part["geometry"] = g;
            out.emplace_back(b.id + "-" + std::to_string(i), std::move(part));
        }
    return out;
}

json vertices_json(const VertexPool& pool) {
    json v = json::array();
    for (const Key& k : pool.list()) v.push_back({k[0], k[1], k[2]});
    return v;
}

}  // namespace

CityJsonWriteReport write_cityjson(const std::string& path, const CityModel& model, const CityJsonWriteOptions& o) {
    const std::string rs = model.crs.cityjson_reference_system();  // empty without an EPSG code: metadata has none
    if (!(o.scale > 0)) throw Error(path, "CityJSON vertex scale must be > 0");
    const auto e = model_extent(model);
    // Translate to a whole number of quanta near the minimum corner, so vertices stay small integers.
    const std::array<double, 3> translate{std::floor(e[0]), std::floor(e[1]), std::floor(e[2])};
    json header;
    header["type"] = "CityJSON";
    header["version"] = "2.0";
    header["transform"] = {{"scale", {o.scale, o.scale, o.scale}}, {"translate", {translate[0], translate[1], translate[2]}}};
    header["metadata"] = {{"geographicalExtent", {e[0], e[1], e[2], e[3], e[4], e[5]}}, {"title", model.title}};
    if (!rs.empty()) header["metadata"]["referenceSystem"] = rs;
    header["CityObjects"] = json::object();
    header["vertices"] = json::array();

    AtomicTextFile file(path);
    std::ostream& out = file.stream();
    CityJsonWriteReport rep;
    VertexPool pool(translate, o.scale);
    UvPool uvs;
    const double fallback_z = fallback_footprint_z(model);
    const bool want2 = std::find(o.lods.begin(), o.lods.end(), 2) != o.lods.end();
    for (std::size_t bi = 0; bi < model.buildings.size(); ++bi)
        rep.textured_buildings += o.textures && want2 && o.textures->window_of(bi) && !model.buildings[bi].roof_parts.empty();
    if (o.sequence) {
        out << header.dump() << '\n';
        for (std::size_t bi = 0; bi < model.buildings.size(); ++bi) {
            const Building& b = model.buildings[bi];
            pool.clear(), uvs.clear();
            json f;
            f["type"] = "CityJSONFeature";
            f["id"] = b.id;
            f["CityObjects"] = json::object();
            for (auto& [id, obj] : building_objects(b, bi, o, model.crs, pool, uvs, fallback_z)) f["CityObjects"][id] = std::move(obj);
            f["vertices"] = vertices_json(pool);
            if (!uvs.empty()) f["appearance"] = appearance_json(o, uvs);
            rep.vertices += pool.list().size();
            out << f.dump() << '\n';
            ++rep.buildings;
        }
    } else {
        // Streamed: the header's members, then one CityObject at a time, then the vertices.
        out << "{\"type\":\"CityJSON\",\"version\":\"2.0\",\"transform\":" << header["transform"].dump()
            << ",\"metadata\":" << header["metadata"].dump() << ",\"CityObjects\":{";
        for (std::size_t bi = 0; bi < model.buildings.size(); ++bi) {
            const Building& b = model.buildings[bi];
            bool first = true;
            for (const auto& [id, obj] : building_objects(b, bi, o, model.crs, pool, uvs, fallback_z))
                out << (rep.buildings || !first ? ",\n" : "\n") << json(id).dump() << ':' << obj.dump(), first = false;
            ++rep.buildings;
        }
        out << "\n}";
        if (!uvs.empty()) out << ",\"appearance\":" << appearance_json(o, uvs).dump();
        out << ",\"vertices\":[";
        const auto& list = pool.list();
        for (std::size_t i = 0; i < list.size(); ++i) out << (i ? "," : "") << '[' << list[i][0] << ',' << list[i][1] << ',' << list[i][2] << ']';
        out << "]}\n";
        rep.vertices = list.size();
    }
    file.commit();
    return rep;
}

}  // namespace cityforge
