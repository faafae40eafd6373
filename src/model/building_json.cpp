#include "model/building_json.hpp"

#include "core/error.hpp"

namespace cityforge {
namespace {

using json = nlohmann::json;

json ring2(const Ring& r) {
    json a = json::array();
    for (const MapPoint& p : r) a.push_back({p.x, p.y});
    return a;
}
Ring ring2_from(const json& a) {
    Ring r;
    for (const auto& p : a) r.push_back({p.at(0).get<double>(), p.at(1).get<double>()});
    return r;
}
json ring3(const Ring3& r) {
    json a = json::array();
    for (const Point3& p : r) a.push_back({p.x, p.y, p.z});
    return a;
}
Ring3 ring3_from(const json& a) {
    Ring3 r;
    for (const auto& p : a) r.push_back({p.at(0).get<double>(), p.at(1).get<double>(), p.at(2).get<double>()});
    return r;
}
const char* type_name(SurfaceType t) { return t == SurfaceType::ground ? "ground" : t == SurfaceType::wall ? "wall" : "roof"; }
SurfaceType type_from(const std::string& s) {
    if (s == "ground") return SurfaceType::ground;
    if (s == "roof") return SurfaceType::roof;
    if (s == "wall") return SurfaceType::wall;
    throw Error("unknown surface type '" + s + "'");
}
json value_json(const AttributeValue& v) {
    if (std::holds_alternative<int64_t>(v)) return {{"i", std::get<int64_t>(v)}};
    if (std::holds_alternative<double>(v)) return {{"d", std::get<double>(v)}};
    if (std::holds_alternative<std::string>(v)) return {{"s", std::get<std::string>(v)}};
    return nullptr;
}
AttributeValue value_from(const json& j) {
    if (j.is_null()) return {};
    if (j.contains("i")) return j["i"].get<int64_t>();
    if (j.contains("d")) return j["d"].get<double>();
    return j.at("s").get<std::string>();
}
template <typename T>
json opt(const std::optional<T>& v) {
    return v ? json(*v) : json(nullptr);
}
std::optional<double> opt_from(const json& j) { return j.is_null() ? std::nullopt : std::optional<double>(j.get<double>()); }

}  // namespace

json building_to_json(const Building& b) {
    json j;
    j["id"] = b.id;
    json parts = json::array();
    for (const Polygon& p : b.footprint) {
        json rings = json::array({ring2(p.outer)});
        for (const Ring& h : p.holes) rings.push_back(ring2(h));
        parts.push_back(rings);
    }
    j["footprint"] = parts;
    j["ground_z"] = opt(b.ground_z);
    j["height_m"] = opt(b.height_m);
    json attrs = json::array();
    for (const auto& [name, value] : b.attributes) attrs.push_back({name, value_json(value)});
    j["attributes"] = attrs;
    json lod2 = json::array();
    for (const Solid& s : b.lod2) {
        json faces = json::array();
        for (const Face& f : s.faces) {
            json rings = json::array({ring3(f.outer)});
            for (const Ring3& h : f.holes) rings.push_back(ring3(h));
            faces.push_back({{"type", type_name(f.type)}, {"rings", rings}});
        }
        lod2.push_back(faces);
    }
    j["lod2"] = lod2;
    j["roof_type"] = b.roof_type;
    j["status"] = b.status;
    j["reason"] = b.reason;
    return j;
}

Building building_from_json(const json& j, const std::string& where) {
    try {
        Building b;
        b.id = j.at("id").get<std::string>();
        for (const auto& part : j.at("footprint")) {
            Polygon p;
            p.outer = ring2_from(part.at(0));
            for (std::size_t k = 1; k < part.size(); ++k) p.holes.push_back(ring2_from(part[k]));
            b.footprint.push_back(std::move(p));
        }
        b.ground_z = opt_from(j.at("ground_z"));
        b.height_m = opt_from(j.at("height_m"));
        for (const auto& a : j.at("attributes")) b.attributes.emplace_back(a.at(0).get<std::string>(), value_from(a.at(1)));
        for (const auto& solid : j.at("lod2")) {
            Solid s;
            for (const auto& f : solid) {
                Face face;
                face.type = type_from(f.at("type").get<std::string>());
                const auto& rings = f.at("rings");
                face.outer = ring3_from(rings.at(0));
                for (std::size_t k = 1; k < rings.size(); ++k) face.holes.push_back(ring3_from(rings[k]));
                s.faces.push_back(std::move(face));
            }
            b.lod2.push_back(std::move(s));
        }
        b.roof_type = j.at("roof_type").get<std::string>();
        b.status = j.at("status").get<std::string>();
        b.reason = j.at("reason").get<std::string>();
        return b;
    } catch (const nlohmann::json::exception& e) {
        throw Error(where, std::string("malformed building: ") + e.what());
    } catch (const Error& e) {
        throw Error(where, e.what());
    }
}

}  // namespace cityforge
