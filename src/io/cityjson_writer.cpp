#include "io/cityjson_writer.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <nlohmann/json.hpp>
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

json building_json(const Building& b, const CityJsonWriteOptions& o, const ModelCrs& crs, VertexPool& pool, double fallback_z) {
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
    const double unit3 = crs.linear_unit_m * crs.linear_unit_m * crs.z_unit_m;
    if (want1 && !b.lod1.empty()) {
        attrs["lod1_valid"] = b.lod1_errors.empty();
        if (!b.lod1_errors.empty()) attrs["lod1_errors"] = b.lod1_errors;
        attrs["lod1_volume_m3"] = b.lod1_volume * unit3;
    }
    if (want2 && !b.lod2.empty()) {
        attrs["lod2_valid"] = b.lod2_errors.empty();
        if (!b.lod2_errors.empty()) attrs["lod2_errors"] = b.lod2_errors;
        attrs["lod2_volume_m3"] = b.lod2_volume * unit3;
        if (!b.roof_type.empty()) attrs["roofType"] = b.roof_type;
    }
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
    if (want1 && !b.lod1.empty()) geometry.push_back(solids_json(b.lod1, "1", pool));
    if (want2 && !b.lod2.empty()) geometry.push_back(solids_json(b.lod2, "2", pool));
    obj["geometry"] = geometry;
    // Extent of this building (footprint x/y; z from its solids or ground).
    const auto e = building_extent(b);
    obj["geographicalExtent"] = {e[0], e[1], e[2], e[3], e[4], e[5]};
    return obj;
}

json vertices_json(const VertexPool& pool) {
    json v = json::array();
    for (const Key& k : pool.list()) v.push_back({k[0], k[1], k[2]});
    return v;
}

}  // namespace

CityJsonWriteReport write_cityjson(const std::string& path, const CityModel& model, const CityJsonWriteOptions& o) {
    const std::string rs = model.crs.cityjson_reference_system();
    if (rs.empty()) throw Error(path, "the model's CRS (" + model.crs.label + ") has no EPSG code to name in referenceSystem");
    if (!(o.scale > 0)) throw Error(path, "CityJSON vertex scale must be > 0");
    const auto e = model_extent(model);
    // Translate to a whole number of quanta near the minimum corner, so vertices stay small integers.
    const std::array<double, 3> translate{std::floor(e[0]), std::floor(e[1]), std::floor(e[2])};
    json header;
    header["type"] = "CityJSON";
    header["version"] = "2.0";
    header["transform"] = {{"scale", {o.scale, o.scale, o.scale}}, {"translate", {translate[0], translate[1], translate[2]}}};
    header["metadata"] = {{"referenceSystem", rs}, {"geographicalExtent", {e[0], e[1], e[2], e[3], e[4], e[5]}}, {"title", model.title}};
    header["CityObjects"] = json::object();
    header["vertices"] = json::array();

    AtomicTextFile file(path);
    std::ostream& out = file.stream();
    CityJsonWriteReport rep;
    VertexPool pool(translate, o.scale);
    const double fallback_z = fallback_footprint_z(model);
    if (o.sequence) {
        out << header.dump() << '\n';
        for (const Building& b : model.buildings) {
            pool.clear();
            json f;
            f["type"] = "CityJSONFeature";
            f["id"] = b.id;
            f["CityObjects"] = {{b.id, building_json(b, o, model.crs, pool, fallback_z)}};
            f["vertices"] = vertices_json(pool);
            rep.vertices += pool.list().size();
            out << f.dump() << '\n';
            ++rep.buildings;
        }
    } else {
        // Streamed: the header's members, then one CityObject at a time, then the vertices.
        out << "{\"type\":\"CityJSON\",\"version\":\"2.0\",\"transform\":" << header["transform"].dump()
            << ",\"metadata\":" << header["metadata"].dump() << ",\"CityObjects\":{";
        for (const Building& b : model.buildings) {
            out << (rep.buildings ? ",\n" : "\n") << json(b.id).dump() << ':' << building_json(b, o, model.crs, pool, fallback_z).dump();
            ++rep.buildings;
        }
        out << "\n},\"vertices\":[";
        const auto& list = pool.list();
        for (std::size_t i = 0; i < list.size(); ++i) out << (i ? "," : "") << '[' << list[i][0] << ',' << list[i][1] << ',' << list[i][2] << ']';
        out << "]}\n";
        rep.vertices = list.size();
    }
    file.commit();
    return rep;
}

}  // namespace cityforge
