#include "pipeline/view_run.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <cstring>
#include <fstream>
#include <set>
#include <sstream>

#include "core/atomic_file.hpp"
#include "core/base64.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "crs/crs.hpp"
#include "io/vector.hpp"
#include "pipeline/city_run.hpp"
#include "raster/quicklook.hpp"
#include "view/viewer_assets.hpp"

namespace cityforge {
namespace {

using json = nlohmann::json;
namespace fs = std::filesystem;

json value_json(const AttributeValue& v) {
    if (std::holds_alternative<int64_t>(v)) return std::get<int64_t>(v);
    if (std::holds_alternative<double>(v)) return std::isfinite(std::get<double>(v)) ? json(std::get<double>(v)) : json(nullptr);
    if (std::holds_alternative<std::string>(v)) return std::get<std::string>(v);
    return nullptr;
}

// Centimetres are plenty for a picture; smaller pages open faster.
double cm(double v) { return std::round(v * 100.0) / 100.0; }

// Figures of an audit report: its scalar numbers, one level of objects flattened ("totals.f1").
json audit_figures(const json& r) {
    json f = json::object();
    for (const char* group : {"totals", "measures", "summary", "metrics"})
        if (r.contains(group) && r[group].is_object())
            for (const auto& [k, v] : r[group].items())
                if (v.is_number() || v.is_string()) f[std::string(group) + "." + k] = v;
    for (const auto& [k, v] : r.items())
        if (v.is_number()) f[k] = v;
    return f;
}

// Quality flags a user should see first.
std::vector<std::string> flags_of(const std::map<std::string, json>& a) {
    std::vector<std::string> flags;
    auto str = [&](const char* k) -> std::string {
        const auto it = a.find(k);
        return it != a.end() && it->second.is_string() ? it->second.get<std::string>() : std::string();
    };
    auto num = [&](const char* k) -> std::optional<double> {
        const auto it = a.find(k);
        return it != a.end() && it->second.is_number() ? std::optional<double>(it->second.get<double>()) : std::nullopt;
    };
    if (const std::string h = str("height_quality"); !h.empty() && h != "good") flags.push_back("height: " + h);
    if (const auto v = num("lod1_valid"); v && *v == 0) flags.push_back("LOD1 invalid: " + str("lod1_errors"));
    if (const auto v = num("lod2_valid"); v && *v == 0) flags.push_back("LOD2 invalid: " + str("lod2_errors"));
    if (const std::string f = str("lod2_fallback"); !f.empty()) flags.push_back("LOD2 fallback: " + f);
    if (const auto v = num("fit_iou"); v && *v < 0.8) flags.push_back("loose fit (IoU " + std::to_string(*v).substr(0, 4) + ")");
    if (const auto v = num("audit_iou"); v && *v < 0.5) flags.push_back("audit: poor match (IoU " + std::to_string(*v).substr(0, 4) + ")");
    return flags;
}

// The run's ortho (manifest.json), as given or relative to the run folder; empty when unknown or gone.
std::string run_ortho(const fs::path& dir) {
    const fs::path manifest = dir / "manifest.json";
    if (!fs::exists(manifest)) return {};
    std::string ortho;
    try {
        ortho = read_manifest(manifest.string()).options.ortho;
    } catch (const Error& e) {
        log::warning(std::string(e.what()) + "; the page shows no ortho");
        return {};
    }
    if (ortho.empty()) return {};
    if (fs::exists(ortho)) return ortho;
    if (fs::exists(dir / ortho)) return (dir / ortho).string();
    log::warning(manifest.string() + ": the run's ortho " + ortho + " is gone; the page shows no ortho (give --ortho)");
    return {};
}

std::string read_bytes(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    if (!in) throw Error(p.string(), "cannot read");
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

// Text inside <script type="application/json">: "</" would end the element.
std::string script_safe(std::string s) {
    for (std::size_t i = 0; (i = s.find("</", i)) != std::string::npos; i += 3) s.replace(i, 2, "<\\/");
    return s;
}

}  // namespace

// The tileset and its glb contents as a script (window.CITYFORGE_TILES), with the
// transform from three.js's view of the (y-up) ECEF content to the page's frame
// (x east, y up, z south; model CRS units minus `origin`), exact at the origin.
std::string tiles_bundle(const std::string& tileset_path, const CrsInfo& crs, const std::array<double, 3>& origin, std::size_t& tiles) {
    const json ts = json::parse(read_bytes(tileset_path), nullptr, false);
    if (ts.is_discarded() || !ts.contains("root")) throw Error(tileset_path, "is not a 3D Tiles tileset (no root tile)");
    json content = json::object();
    const fs::path base = fs::path(tileset_path).parent_path();
    std::vector<const json*> stack{&ts["root"]};
    while (!stack.empty()) {
        const json& t = *stack.back();
        stack.pop_back();
        if (t.contains("content") && t["content"].contains("uri")) {
            const std::string uri = t["content"]["uri"];
            if (!fs::exists(base / uri)) throw Error(tileset_path, "names content " + uri + ", which does not exist");
            content[uri] = base64(read_bytes(base / uri));
            ++tiles;
        }
        if (t.contains("children"))
            for (const json& c : t["children"]) stack.push_back(&c);
    }
    // Origin and 100 units east, north and up, to ECEF (with the vertical datum where PROJ relates it).
    std::vector<double> x{origin[0], origin[0] + 100, origin[0], origin[0]}, y{origin[1], origin[1], origin[1] + 100, origin[1]},
        z{origin[2], origin[2], origin[2], origin[2] + 100};
    const CrsInfo ecef = crs_from_user_input("EPSG:4978", "3D Tiles");
    try {
        transform_points(crs, ecef, x, y, z, tileset_path);
    } catch (const Error&) {
        if (!crs.horizontal_epsg) throw;
        x = {origin[0], origin[0] + 100, origin[0], origin[0]}, y = {origin[1], origin[1], origin[1] + 100, origin[1]};
        z = {origin[2], origin[2], origin[2], origin[2] + 100};
        transform_points(crs_from_user_input("EPSG:" + std::to_string(*crs.horizontal_epsg), tileset_path), ecef, x, y, z, tileset_path);
    }
    // D: local offset (CRS units) -> ECEF offset; A = D^-1.
    double D[3][3];
    for (int c = 0; c < 3; ++c) D[0][c] = (x[c + 1] - x[0]) / 100, D[1][c] = (y[c + 1] - y[0]) / 100, D[2][c] = (z[c + 1] - z[0]) / 100;
    const double det = D[0][0] * (D[1][1] * D[2][2] - D[1][2] * D[2][1]) - D[0][1] * (D[1][0] * D[2][2] - D[1][2] * D[2][0]) +
                       D[0][2] * (D[1][0] * D[2][1] - D[1][1] * D[2][0]);
    if (!(std::abs(det) > 0)) throw Error(tileset_path, "cannot relate the tiles' ECEF frame to the model CRS");
    double A[3][3];
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
            const int r1 = (c + 1) % 3, r2 = (c + 2) % 3, c1 = (r + 1) % 3, c2 = (r + 2) % 3;
            A[r][c] = (D[r1][c1] * D[r2][c2] - D[r1][c2] * D[r2][c1]) / det;  // adjugate / det
        }
    // three world (glTF y-up of ECEF) w -> ECEF P w = (w0, -w2, w1); page frame Q l = (l0, l2, -l1).
    const double P[3][3] = {{1, 0, 0}, {0, 0, -1}, {0, 1, 0}}, Q[3][3] = {{1, 0, 0}, {0, 0, 1}, {0, -1, 0}};
    double QA[3][3] = {}, M[3][3] = {};
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            for (int k = 0; k < 3; ++k) QA[r][c] += Q[r][k] * A[k][c];
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            for (int k = 0; k < 3; ++k) M[r][c] += QA[r][k] * P[k][c];
    json m = json::array();
    for (int r = 0; r < 3; ++r) {
        const double t = -(QA[r][0] * x[0] + QA[r][1] * y[0] + QA[r][2] * z[0]);
        m.push_back(M[r][0]), m.push_back(M[r][1]), m.push_back(M[r][2]), m.push_back(t);
    }
    const json bundle = {{"tileset", ts}, {"content", content}, {"to_page", m}};
    return "// written by cityforge view: the 3D Tiles tileset and its content for the page beside it\nwindow.CITYFORGE_TILES = " + bundle.dump() +
           ";\n";
}

void ViewOptions::validate() const {
    if (ortho_max_px < 64 || ortho_max_px > 8192) throw Error("--ortho-max-px", "must be in 64..8192");
}

namespace {
// The 3D view's binary glTF: its bytes, the origin its vertices are relative
// to (asset.extras.origin; `fallback` when it names none) and how many
// buildings it meshes (its property table). Empty when there is no glb and
// none was asked for (a warning: the page has no 3D view).
struct ViewGlb {
    std::string bytes;
    std::array<double, 3> origin{};
    std::size_t meshed = 0;
};
ViewGlb read_view_glb(const std::string& glb_path, bool asked, const std::string& run_dir, const std::array<double, 3>& fallback) {
    ViewGlb v;
    v.origin = fallback;
    if (!fs::exists(glb_path)) {
        if (asked) throw Error(glb_path, "does not exist");
        log::warning(run_dir + ": no buildings.glb (export with --formats gltf); the page has no 3D view");
        return v;
    }
    v.bytes = read_bytes(glb_path);
    const std::string& glb = v.bytes;
    uint32_t jlen = 0;
    if (glb.size() < 28 || glb.compare(0, 4, "glTF") != 0) throw Error(glb_path, "is not a binary glTF (.glb)");
    std::memcpy(&jlen, glb.data() + 12, 4);
    if (20 + std::size_t(jlen) > glb.size()) throw Error(glb_path, "is truncated");
    const json g = json::parse(glb.substr(20, jlen), nullptr, false);
    if (g.is_discarded()) throw Error(glb_path, "has an unreadable JSON chunk");
    if (g.contains("asset") && g["asset"].contains("extras") && g["asset"]["extras"].contains("origin")) {
        const auto& og = g["asset"]["extras"]["origin"];
        v.origin = {og[0].get<double>(), og[1].get<double>(), og[2].get<double>()};
    }
    const json::json_pointer count("/extensions/EXT_structural_metadata/propertyTables/0/count");
    if (!g.contains(count)) throw Error(glb_path, "has no building property table (EXT_structural_metadata); write it with cityforge export --formats gltf");
    v.meshed = g[count].get<std::size_t>();
    return v;
}

// The audits in the run folder (each subfolder's report.json, in name
// order): their figures for the page, and per building of `table` (by
// feature id) the errors a footprint audit of that table measured.
struct ViewAudits {
    json list = json::array();
    std::map<int64_t, json> of_fid;
};
ViewAudits read_view_audits(const fs::path& dir, const std::string& table) {
    ViewAudits a;
    std::vector<fs::path> reports;
    for (const auto& e : fs::directory_iterator(dir))
        if (e.is_directory() && fs::exists(e.path() / "report.json")) reports.push_back(e.path() / "report.json");
    std::sort(reports.begin(), reports.end());
    for (const fs::path& r : reports) {
        const json j = json::parse(read_bytes(r), nullptr, false);
        if (j.is_discarded() || !j.is_object()) {
            log::warning(r.string() + ": not a JSON report; left out of the page");
            continue;
        }
        const std::string kind = j.value("audit", r.parent_path().filename().string());
        a.list.push_back({{"title", "audit " + kind + " (" + r.parent_path().filename().string() + ")"}, {"figures", audit_figures(j)}});
        const std::string pred = j.contains("predicted") && j["predicted"].is_object() ? j["predicted"].value("path", "") : "";
        if (kind == "footprints" && j.contains("matches") && !pred.empty() && fs::path(pred).filename() == fs::path(table).filename())
            for (const auto& m : j["matches"])
                if (m.contains("predicted_fid"))
                    a.of_fid[m["predicted_fid"].get<int64_t>()] = {{"audit_iou", m.value("iou", json())},
                                                                   {"audit_area_error_pct", m.value("area_error_pct", json())},
                                                                   {"audit_polis", m.value("polis", json())}};
    }
    return a;
}

// The page's buildings: id (cityforge_id, else id, else the feature id),
// status, reason, the other attributes with the audit's errors, flags, LOD
// and the footprint's rings in centimetres relative to `origin`. The
// attribute names holding numbers and text are collected for the colour menu.
json view_buildings(const PolygonLayer& layer, const std::array<double, 3>& origin, const std::map<int64_t, json>& audit_of_fid,
                    std::set<std::string>& numeric_fields, std::set<std::string>& text_fields) {
    int id_f = -1, status_f = -1, reason_f = -1;
    for (std::size_t k = 0; k < layer.field_names.size(); ++k) {
        if (layer.field_names[k] == "cityforge_id") id_f = int(k);
        if (layer.field_names[k] == "status") status_f = int(k);
        if (layer.field_names[k] == "reason") reason_f = int(k);
    }
    if (id_f < 0)
        for (std::size_t k = 0; k < layer.field_names.size(); ++k)
            if (layer.field_names[k] == "id") id_f = int(k);
    json buildings = json::array();
    for (std::size_t i = 0; i < layer.features.size(); ++i) {
        const Feature& f = layer.features[i];
        json b;
        std::string id = std::to_string(layer.fids[i]);
        if (id_f >= 0 && !std::holds_alternative<std::monostate>(f.values[id_f])) id = value_json(f.values[id_f]).is_string()
                                                                                            ? value_json(f.values[id_f]).get<std::string>()
                                                                                            : value_json(f.values[id_f]).dump();
        b["id"] = id;
        b["status"] = status_f >= 0 && std::holds_alternative<std::string>(f.values[status_f]) ? std::get<std::string>(f.values[status_f]) : "ok";
        b["reason"] = reason_f >= 0 && std::holds_alternative<std::string>(f.values[reason_f]) ? std::get<std::string>(f.values[reason_f]) : "";
        std::map<std::string, json> attrs;
        for (std::size_t k = 0; k < layer.field_names.size(); ++k) {
            if (int(k) == id_f || int(k) == status_f || int(k) == reason_f) continue;
            attrs[layer.field_names[k]] = value_json(f.values[k]);
        }
        if (const auto it = audit_of_fid.find(layer.fids[i]); it != audit_of_fid.end())
            for (const auto& [k, v] : it->second.items()) attrs[k] = v;
        json a = json::object();
        for (const auto& [k, v] : attrs) {
            a[k] = v;
            if (v.is_number()) numeric_fields.insert(k);
            else if (v.is_string()) text_fields.insert(k);
        }
        b["attrs"] = a;
        b["flags"] = flags_of(attrs);
        if (attrs.count("lod2_valid") && attrs["lod2_valid"].is_number()) b["lod"] = "2";
        else if (attrs.count("lod1_valid") && attrs["lod1_valid"].is_number()) b["lod"] = "1";
        json parts = json::array();
        for (const Polygon& p : f.geometry) {
            json rings = json::array();
            auto ring = [&](const Ring& r) {
                json pts = json::array();
                for (const MapPoint& q : r) pts.push_back({cm(q.x - origin[0]), cm(q.y - origin[1])});
                rings.push_back(pts);
            };
            ring(p.outer);
            for (const Ring& h : p.holes) ring(h);
            parts.push_back(rings);
        }
        b["footprint"] = parts;
        buildings.push_back(b);
    }
    return buildings;
}

// Colour menu: status first, then the attributes a user compares (when present), then other numbers.
json view_colour_fields(const std::set<std::string>& numeric_fields, const std::set<std::string>& text_fields) {
    json colour_fields = json::array({"status"});
    std::set<std::string> listed{"status"};
    for (const char* k : {"height_m", "roof_type", "fit_iou", "audit_iou", "audit_area_error_pct", "audit_polis", "height_quality", "lod2_rmse_m",
                          "lod2_kind", "fit", "mode", "area_m2"})
        if ((numeric_fields.count(k) || text_fields.count(k)) && listed.insert(k).second) colour_fields.push_back(k);
    for (const std::string& k : numeric_fields)
        if (listed.insert(k).second) colour_fields.push_back(k);
    return colour_fields;
}

// The ortho's quicklook over the buildings' extent (with a margin), warped
// onto their CRS (a lon/lat ortho's run writes UTM), as the page's data.
json view_ortho(const std::string& ortho, const Extent& ext, const std::array<double, 3>& origin, const ViewOptions& o, const CrsInfo& crs) {
    const double w = ext.max_x - ext.min_x, h = ext.max_y - ext.min_y, m = 0.05 * std::max(w, h) + 5.0;
    const Quicklook q = render_quicklook_png(ortho, {ext.min_x - m, ext.min_y - m, ext.max_x + m, ext.max_y + m}, o.ortho_max_px, crs.wkt);
    return {{"src", "data:image/png;base64," + base64(q.png)},
            {"extent", {cm(q.extent.min_x - origin[0]), cm(q.extent.min_y - origin[1]), cm(q.extent.max_x - origin[0]), cm(q.extent.max_y - origin[1])}},
            {"path", ortho}};
}
}  // namespace

ViewReport write_view(const std::string& run_dir, const ViewOptions& o) {
    o.validate();
    const fs::path dir(run_dir);
    if (!fs::is_directory(dir)) throw Error(run_dir, "not a folder (give the output folder of `cityforge run` or `cityforge export`)");
    const std::string table = o.buildings.empty() ? (dir / "buildings.gpkg").string() : o.buildings;
    if (o.buildings.empty() && !fs::exists(table))
        throw Error(run_dir, "no buildings.gpkg here (give the output folder of `cityforge run` or `cityforge export` with gpkg)");
    const std::string out = o.out.empty() ? (dir / "view" / "index.html").string() : o.out;
    if (fs::exists(out) && !o.overwrite) throw Error(out, "exists (use --overwrite to replace it)");

    const PolygonLayer layer = read_polygon_layer(table);
    if (layer.features.empty()) throw Error(table, "has no buildings to show");
    if (layer.crs.empty()) throw Error(table, "has no CRS");
    if (layer.crs.geographic) throw Error(table, "is in a geographic CRS; the viewer needs the model's projected CRS (the GeoPackage output)");

    Extent ext = empty_extent();
    for (const Feature& f : layer.features) include(ext, parts_extent(f.geometry));
    // The glb's origin when there is one (so 2D and 3D share a frame), else the extent's centre.
    const ViewGlb glb = read_view_glb(o.glb.empty() ? (dir / "buildings.glb").string() : o.glb, !o.glb.empty(), run_dir,
                                      {std::round(0.5 * (ext.min_x + ext.max_x)), std::round(0.5 * (ext.min_y + ext.max_y)), 0.0});
    const std::array<double, 3>& origin = glb.origin;
    const ViewAudits audits = read_view_audits(dir, table);
    std::set<std::string> numeric_fields, text_fields;
    const json buildings = view_buildings(layer, origin, audits.of_fid, numeric_fields, text_fields);

    json data;
    data["title"] = "cityforge — " + fs::absolute(dir).lexically_normal().filename().string();
    if (data["title"] == "cityforge — ") data["title"] = "cityforge — " + run_dir;
    data["crs"] = layer.crs.label();
    data["origin"] = origin;
    data["extent"] = {cm(ext.min_x - origin[0]), cm(ext.min_y - origin[1]), cm(ext.max_x - origin[0]), cm(ext.max_y - origin[1])};
    data["buildings"] = buildings;
    data["colour_fields"] = view_colour_fields(numeric_fields, text_fields);
    data["audits"] = audits.list;
    data["ortho"] = nullptr;
    ViewReport rep;
    const std::string ortho = o.ortho.empty() ? run_ortho(dir) : o.ortho;
    if (!ortho.empty()) {
        data["ortho"] = view_ortho(ortho, ext, origin, o, layer.crs);
        rep.ortho = true;
    }

    const std::string_view tmpl = viewer_page_template();
    const std::string placeholder = "<!--CITYFORGE_DATA-->";
    const std::size_t at = tmpl.find(placeholder);
    if (at == std::string_view::npos) throw Error(out, "internal: the viewer template has no data placeholder");
    std::string page;
    page.reserve(tmpl.size() + glb.bytes.size() * 4 / 3 + 1024);
    page.append(tmpl.substr(0, at));
    page += "<script type=\"application/json\" id=\"cityforge-data\">" + script_safe(data.dump()) + "</script>\n";
    // The glb as a string in a script (base64 holds no quote, backslash or '<'):
    // Chromium reads a large inline script about 5x faster than the same text in
    // a non-script data block (10,171 LOD1 buildings, 14.5 MB: 0.4 s against 2.2 s).
    page += "<script id=\"cityforge-glb\">window.CITYFORGE_GLB_BASE64 = \"" + base64(glb.bytes) + "\";</script>\n";
    // The tileset, bundled as a script beside the page.
    const std::string tileset = o.tileset.empty() ? (dir / "3dtiles" / "tileset.json").string() : o.tileset;
    if (!o.tileset.empty() && !fs::exists(tileset)) throw Error(o.tileset, "does not exist");
    if (fs::exists(tileset)) {
        const fs::path bundle = fs::path(out).parent_path() / "tiles.js";
        ensure_directory(bundle.parent_path());
        write_text_file(bundle, tiles_bundle(tileset, layer.crs, origin, rep.tiles));
        rep.tiles_bundle = bundle.string();
        // Named, not loaded: the page loads it when the tileset is first shown.
        page += "<script>window.CITYFORGE_TILES_SRC = \"tiles.js\";</script>\n";
    }
    page.append(tmpl.substr(at + placeholder.size()));
    ensure_directory(fs::path(out).parent_path());
    write_text_file(out, page);
    rep.path = out;
    rep.buildings = buildings.size();
    rep.audits = audits.list.size();
    rep.bytes = page.size();
    rep.meshed = glb.meshed;
    return rep;
}

}  // namespace cityforge
