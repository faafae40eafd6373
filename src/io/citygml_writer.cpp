#include "io/citygml_writer.hpp"

#include <charconv>
#include <cmath>

#include "core/atomic_file.hpp"
#include "core/xml_text.hpp"
#include "core/error.hpp"
#include "core/version.hpp"

namespace cityforge {

std::string gml_id_for(const std::string& id) {
    std::string out = "bldg_";
    for (char c : id) out += (std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-') ? c : '_';
    return out;
}

namespace {

class GmlWriter {
public:
    GmlWriter(std::ostream& out, int decimals) : out_(out), decimals_(decimals) {}

    void number(double v) {
        char buf[64];
        const auto r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::fixed, decimals_);
        out_.write(buf, r.ptr - buf);
    }
    // posList of a closed ring (first vertex repeated at the end, as GML requires).
    void pos_list(const Ring3& r) {
        out_ << "<gml:LinearRing><gml:posList>";
        for (std::size_t i = 0; i <= r.size(); ++i) {
            const Point3& p = r[i % r.size()];
            if (i) out_ << ' ';
            number(p.x), out_ << ' ', number(p.y), out_ << ' ', number(p.z);
        }
        out_ << "</gml:posList></gml:LinearRing>";
    }
    void polygon(const Ring3& outer, const std::vector<Ring3>& holes, const std::string& gml_id) {
        out_ << "<gml:Polygon";
        if (!gml_id.empty()) out_ << " gml:id=\"" << gml_id << '"';
        out_ << "><gml:exterior>";
        pos_list(outer);
        out_ << "</gml:exterior>";
        for (const Ring3& h : holes) {
            out_ << "<gml:interior>";
            pos_list(h);
            out_ << "</gml:interior>";
        }
        out_ << "</gml:Polygon>";
    }
    void solid_inline(const Solid& s, const std::string& gml_id) {
        out_ << "<gml:Solid gml:id=\"" << gml_id << "\"><gml:exterior><gml:CompositeSurface>";
        for (const Face& f : s.faces) {
            out_ << "<gml:surfaceMember>";
            polygon(f.outer, f.holes, "");
            out_ << "</gml:surfaceMember>";
        }
        out_ << "</gml:CompositeSurface></gml:exterior></gml:Solid>";
    }
    std::ostream& out() { return out_; }

private:
    std::ostream& out_;
    int decimals_;
};

void write_attribute(std::ostream& out, const std::string& name, const AttributeValue& v) {
    if (std::holds_alternative<std::monostate>(v)) return;  // CityGML has no null: leave it out
    if (std::holds_alternative<int64_t>(v)) {
        const int64_t i = std::get<int64_t>(v);
        // gen:intAttribute is xs:integer; keep it for values that fit 32 bits as most readers expect.
        if (i >= INT32_MIN && i <= INT32_MAX)
            out << "<gen:intAttribute name=\"" << xml_escape(name) << "\"><gen:value>" << i << "</gen:value></gen:intAttribute>\n";
        else
            out << "<gen:stringAttribute name=\"" << xml_escape(name) << "\"><gen:value>" << i << "</gen:value></gen:stringAttribute>\n";
    } else if (std::holds_alternative<double>(v)) {
        const double d = std::get<double>(v);
        if (!std::isfinite(d)) return;
        char buf[64];
        const auto r = std::to_chars(buf, buf + sizeof buf, d);
        out << "<gen:doubleAttribute name=\"" << xml_escape(name) << "\"><gen:value>" << std::string(buf, r.ptr) << "</gen:value></gen:doubleAttribute>\n";
    } else {
        out << "<gen:stringAttribute name=\"" << xml_escape(name) << "\"><gen:value>" << xml_escape(std::get<std::string>(v))
            << "</gen:value></gen:stringAttribute>\n";
    }
}

std::string join(const std::vector<std::string>& v) {
    std::string s;
    for (const std::string& e : v) s += (s.empty() ? "" : "; ") + e;
    return s;
}

// lod2Solid (referencing the semantic surfaces' polygons, as in the OGC examples) and boundedBy surfaces.
void write_lod2(std::ostream& out, GmlWriter& gml, const std::vector<Solid>& solids, const std::string& id) {
    auto poly_id = [&](std::size_t s, std::size_t f) { return id + ".s" + std::to_string(s) + ".f" + std::to_string(f); };
    auto shell = [&](std::size_t s) {
        out << "<gml:Solid gml:id=\"" << id << ".lod2." << s << "\"><gml:exterior><gml:CompositeSurface>";
        for (std::size_t f = 0; f < solids[s].faces.size(); ++f) out << "<gml:surfaceMember xlink:href=\"#" << poly_id(s, f) << "\"/>";
        out << "</gml:CompositeSurface></gml:exterior></gml:Solid>";
    };
    out << "<bldg:lod2Solid>";
    if (solids.size() == 1) shell(0);
    else {
        out << "<gml:CompositeSolid gml:id=\"" << id << ".lod2\">";
        for (std::size_t s = 0; s < solids.size(); ++s) out << "<gml:solidMember>", shell(s), out << "</gml:solidMember>";
        out << "</gml:CompositeSolid>";
    }
    out << "</bldg:lod2Solid>\n";
    for (std::size_t s = 0; s < solids.size(); ++s)
        for (std::size_t f = 0; f < solids[s].faces.size(); ++f) {
            const Face& face = solids[s].faces[f];
            const char* type = citygml_name(face.type);
            out << "<bldg:boundedBy><bldg:" << type << " gml:id=\"" << poly_id(s, f) << ".surface\"><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>";
            gml.polygon(face.outer, face.holes, poly_id(s, f));
            out << "</gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface></bldg:" << type << "></bldg:boundedBy>\n";
        }
}

}  // namespace

CityGmlWriteReport write_citygml(const std::string& path, const CityModel& model, const CityGmlWriteOptions& o) {
    if (o.lod != 1 && o.lod != 2) throw Error(path, "CityGML export writes LOD 1 or LOD 2 (LOD 0 footprints are in both)");
    // Without an EPSG code the envelope has no srsName (it is optional in GML); the CRS is named in the header comment.
    const std::string srs = model.crs.gml_srs_name();
    AtomicTextFile file(path);
    std::ostream& out = file.stream();
    GmlWriter gml(out, o.decimals);
    const auto e = model_extent(model);
    out << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
        << "<core:CityModel xmlns:core=\"http://www.opengis.net/citygml/2.0\" xmlns:bldg=\"http://www.opengis.net/citygml/building/2.0\""
           " xmlns:gen=\"http://www.opengis.net/citygml/generics/2.0\" xmlns:gml=\"http://www.opengis.net/gml\""
           " xmlns:xlink=\"http://www.w3.org/1999/xlink\" xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\""
           " xsi:schemaLocation=\"http://www.opengis.net/citygml/building/2.0 http://schemas.opengis.net/citygml/building/2.0/building.xsd"
           " http://www.opengis.net/citygml/generics/2.0 http://schemas.opengis.net/citygml/generics/2.0/generics.xsd\">\n"
        << "<!-- written by cityforge " << version() << "; CRS " << xml_escape(model.crs.label) << "; LOD " << o.lod << " -->\n"
        << "<gml:name>" << xml_escape(model.title) << "</gml:name>\n"
        << "<gml:boundedBy><gml:Envelope" << (srs.empty() ? std::string() : " srsName=\"" + srs + "\"") << " srsDimension=\"3\"><gml:lowerCorner>";
    gml.number(e[0]), out << ' ', gml.number(e[1]), out << ' ', gml.number(e[2]);
    out << "</gml:lowerCorner><gml:upperCorner>";
    gml.number(e[3]), out << ' ', gml.number(e[4]), out << ' ', gml.number(e[5]);
    out << "</gml:upperCorner></gml:Envelope></gml:boundedBy>\n";

    CityGmlWriteReport rep;
    const double fallback_z = fallback_footprint_z(model);
    for (const Building& b : model.buildings) {
        const std::string id = gml_id_for(b.id);
        const std::vector<Solid>& solids = o.lod == 1 ? b.lod1 : b.lod2;
        out << "<core:cityObjectMember>\n<bldg:Building gml:id=\"" << id << "\">\n";
        // Generic attributes: the sources', then ours (they belong to _CityObject, before bldg: properties).
        write_attribute(out, "cityforge_id", b.id);
        for (const auto& [name, value] : b.attributes) write_attribute(out, name, value);
        write_attribute(out, "status", b.status);
        if (!b.ground_z && !b.footprint.empty()) write_attribute(out, "footprint_z_estimated", int64_t(1));
        if (!b.reason.empty()) write_attribute(out, "reason", b.reason);
        const auto& errs = o.lod == 1 ? b.lod1_errors : b.lod2_errors;
        // CityGML 2.0 has LOD 1 and 2 only: the refined LOD (3DBAG's naming) as an attribute.
        if (!solids.empty()) write_attribute(out, "refined_lod", std::string(o.lod == 1 ? "1.2" : "2.2"));
        if (o.lod == 2 && b.roof_parts.size() > 1) write_attribute(out, "lod22_parts", int64_t(b.roof_parts.size()));
        if (!solids.empty()) {
            write_attribute(out, "lod" + std::to_string(o.lod) + "_valid", int64_t(errs.empty() ? 1 : 0));
            if (!errs.empty()) write_attribute(out, "lod" + std::to_string(o.lod) + "_errors", join(errs));
            write_attribute(out, "volume_m3", (o.lod == 1 ? b.lod1_volume : b.lod2_volume) * model.crs.volume_unit_m3());
        }
        if (o.lod == 2 && !b.roof_type.empty()) out << "<bldg:roofType>" << xml_escape(b.roof_type) << "</bldg:roofType>\n";
        if (b.height_m) out << "<bldg:measuredHeight uom=\"m\">", gml.number(*b.height_m), out << "</bldg:measuredHeight>\n";
        if (!b.footprint.empty()) {
            // Every building keeps its footprint; one without ground (no_height) at the model's median ground.
            const double z0 = b.ground_z ? *b.ground_z : fallback_z;
            out << "<bldg:lod0FootPrint><gml:MultiSurface>";
            for (const Polygon& p : b.footprint) {
                Ring3 outer;
                std::vector<Ring3> holes;
                for (const MapPoint& q : p.outer) outer.push_back({q.x, q.y, z0});
                for (const Ring& h : p.holes) {
                    holes.emplace_back();
                    for (const MapPoint& q : h) holes.back().push_back({q.x, q.y, z0});
                }
                out << "<gml:surfaceMember>";
                gml.polygon(outer, holes, "");
                out << "</gml:surfaceMember>";
            }
            out << "</gml:MultiSurface></bldg:lod0FootPrint>\n";
        }
        if (!solids.empty()) {
            ++rep.with_geometry;
            if (o.lod == 1) {
                out << "<bldg:lod1Solid>";
                if (solids.size() == 1) gml.solid_inline(solids[0], id + ".lod1");
                else {
                    out << "<gml:CompositeSolid gml:id=\"" << id << ".lod1\">";
                    for (std::size_t i = 0; i < solids.size(); ++i) {
                        out << "<gml:solidMember>";
                        gml.solid_inline(solids[i], id + ".lod1." + std::to_string(i));
                        out << "</gml:solidMember>";
                    }
                    out << "</gml:CompositeSolid>";
                }
                out << "</bldg:lod1Solid>\n";
            } else if (b.roof_parts.size() > 1) {
                // LOD2.2: one BuildingPart per roof part where heights step (after boundedBy in the schema's order).
                for (std::size_t k = 0; k < b.roof_parts.size(); ++k) {
                    const RoofPart& part = b.roof_parts[k];
                    const std::string pid = id + "-" + std::to_string(k);
                    out << "<bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id=\"" << pid << "\">\n";
                    write_attribute(out, "cityforge_id", b.id + "-" + std::to_string(k));
                    write_attribute(out, "refined_lod", std::string("2.2"));
                    write_attribute(out, "lod22_valid", int64_t(part.lod22_errors.empty() ? 1 : 0));
                    if (!part.lod22_errors.empty()) write_attribute(out, "lod22_errors", join(part.lod22_errors));
                    write_attribute(out, "volume_m3", part.lod22_volume * model.crs.volume_unit_m3());
                    write_lod2(out, gml, {part.lod22}, pid);
                    out << "</bldg:BuildingPart></bldg:consistsOfBuildingPart>\n";
                }
            } else {
                write_lod2(out, gml, solids, id);
            }
        }
        out << "</bldg:Building>\n</core:cityObjectMember>\n";
        ++rep.buildings;
    }
    out << "</core:CityModel>\n";
    file.commit();
    return rep;
}

}  // namespace cityforge
