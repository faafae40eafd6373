#include "pipeline/export_run.hpp"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <functional>
#include <mutex>
#include <optional>
#include <set>

#include "core/atomic_file.hpp"
#include "core/parallel.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "crs/crs.hpp"
#include "io/cityjson_writer.hpp"
#include "io/citygml_writer.hpp"
#include "io/tiles3d_writer.hpp"
#include "io/vector.hpp"
#include "pipeline/roof_textures.hpp"

namespace cityforge {

namespace {
const std::vector<std::string> kFormats{"geojson", "gpkg", "citygml", "cityjson", "cityjsonseq", "3dtiles", "gltf"};
// Attributes we compute; same-named source attributes are replaced (status and reason merged).
// The fields the flat tables (GeoJSON, GeoPackage) add to the source attributes.
const std::vector<FieldDefinition> kOwnFieldDefinitions{
    {"status", FieldType::string},     {"reason", FieldType::string},      {"roof_z", FieldType::real},
    {"lod1_valid", FieldType::integer}, {"lod1_errors", FieldType::string}, {"lod1_volume_m3", FieldType::real},
    {"lod2_valid", FieldType::integer}, {"lod2_errors", FieldType::string}, {"lod2_volume_m3", FieldType::real},
    {"roof_type", FieldType::string},   {"lod13_valid", FieldType::integer}, {"lod22_valid", FieldType::integer},
    {"lod22_parts", FieldType::integer}};
const std::set<std::string> kOwnFields = [] {
    std::set<std::string> s{"cityforge_id"};
    for (const FieldDefinition& f : kOwnFieldDefinitions) s.insert(f.name);
    return s;
}();
bool wants(const std::vector<std::string>& v, const std::string& s) { return std::find(v.begin(), v.end(), s) != v.end(); }
bool wants(const std::vector<int>& v, int s) { return std::find(v.begin(), v.end(), s) != v.end(); }

}  // namespace

const std::set<std::string>& model_output_fields() { return kOwnFields; }

ModelCrs model_crs_of(const CrsInfo& c, const Extent& buildings) {
    ModelCrs m;
    // At the centre of the buildings (Web Mercator's scale varies by 1e-4 over a kilometre at mid latitudes).
    if (!c.geographic) m.ground_scale = ground_scale_factor_at(c, buildings);
    m.label = c.label();
    if (!c.horizontal_epsg && !c.epsg) {
        // No code to name it by (the writers then leave srsName / referenceSystem out): the PROJ string says what it is.
        const std::string proj = proj_string(c);
        if (!proj.empty()) m.label = c.name.empty() || c.name == "unknown" ? proj : c.name + " (" + proj + ")";
    }
    m.horizontal_epsg = c.horizontal_epsg;
    m.vertical_epsg = c.vertical_epsg;
    if (c.vertical_epsg && c.epsg && c.epsg != c.horizontal_epsg) m.compound_epsg = c.epsg;
    m.linear_unit_m = c.linear_unit_m;
    m.z_unit_m = c.z_unit_m;
    return m;
}

namespace {

std::string join(const std::vector<std::string>& v) {
    std::string s;
    for (const std::string& e : v) s += (s.empty() ? "" : "; ") + e;
    return s;
}
}  // namespace

void ExportOptions::validate() const {
    if (formats.empty()) throw Error("--formats", "name at least one format");
    for (const std::string& f : formats)
        if (!wants(kFormats, f)) throw Error("--formats", "unknown format '" + f + "' (geojson, gpkg, citygml, cityjson, cityjsonseq, 3dtiles, gltf)");
    if (lods.empty()) throw Error("--lod", "name at least one level of detail");
    for (int l : lods)
        if (l < 0 || l > 2) throw Error("--lod", "levels of detail are 0, 1 and 2");
    if (geojson_crs != "rfc7946" && geojson_crs != "native") throw Error("--geojson-crs", "must be rfc7946 or native");
    if (!database.empty() && !is_database_name(database)) throw Error("--db", "give a database connection, PG:\"dbname=... [tables=NAME]\"");
    if (!(validity.planarity_tolerance > 0) || !(validity.snap_tolerance > 0)) throw Error("validity", "tolerances must be > 0");
    texture.validate();
}

CityModel build_city_model(const PolygonLayer& layer, const CrsInfo& crs, const ExportOptions& o, const std::string& path) {
    CityModel model;
    model.source = path;
    Extent extent = empty_extent();
    for (const Feature& f : layer.features) include(extent, parts_extent(f.geometry));
    model.crs = model_crs_of(crs, extent);
    auto index_of = [&](const std::string& name) -> int {
        for (std::size_t i = 0; i < layer.field_names.size(); ++i)
            if (layer.field_names[i] == name) return static_cast<int>(i);
        return -1;
    };
    const int id_f = index_of(o.id_field), ground_f = index_of(o.ground_field), height_f = index_of(o.height_field);
    const int status_f = index_of("status"), reason_f = index_of("reason");
    for (int f : {ground_f, height_f})
        if (f >= 0 && layer.field_types[f] == FieldType::string)
            throw Error(path, "field '" + layer.field_names[f] + "' is text; heights must be numeric");
    if (ground_f < 0 && o.warn_missing_heights)
        log::warning(path + ": no field '" + o.ground_field + "'; buildings get no LOD1 (run `cityforge heights` first)");
    if (height_f < 0 && o.warn_missing_heights)
        log::warning(path + ": no field '" + o.height_field + "'; buildings get no LOD1 (run `cityforge heights` first)");
    auto number = [](const AttributeValue& v) -> std::optional<double> {
        if (std::holds_alternative<double>(v)) return std::get<double>(v);
        if (std::holds_alternative<int64_t>(v)) return double(std::get<int64_t>(v));
        return std::nullopt;
    };
    {
        // Fields the model computes itself replace the input's (a warning names them).
        std::string replaced;
        for (const std::string& n : layer.field_names)
            if (kOwnFields.count(n) && n != "status" && n != "reason") replaced += (replaced.empty() ? "" : ", ") + n;
        if (!replaced.empty()) log::warning(path + ": input fields " + replaced + " are replaced by the values computed here");
    }
    for (std::size_t k = 0; k < layer.field_names.size(); ++k)
        if (!kOwnFields.count(layer.field_names[k])) model.attribute_types.emplace_back(layer.field_names[k], layer.field_types[k]);
    std::set<std::string> used;
    model.buildings.reserve(layer.features.size());
    for (std::size_t i = 0; i < layer.features.size(); ++i) {
        const Feature& f = layer.features[i];
        Building b;
        std::string id = std::to_string(layer.fids[i]);
        if (id_f >= 0 && !std::holds_alternative<std::monostate>(f.values[id_f])) {
            const AttributeValue& v = f.values[id_f];
            id = std::holds_alternative<std::string>(v) ? std::get<std::string>(v)
                 : std::holds_alternative<int64_t>(v)   ? std::to_string(std::get<int64_t>(v))
                                                        : std::to_string(std::llround(std::get<double>(v)));
        }
        // Ids must be unique in every format: a repeated id gets a suffix (said in the log).
        std::string unique = id;
        for (int k = 2; !used.insert(unique).second; ++k) unique = id + "_" + std::to_string(k);
        if (unique != id) log::warning(path + ": building id '" + id + "' repeats; written as '" + unique + "'");
        b.id = unique;
        b.footprint = f.geometry;
        if (ground_f >= 0) b.ground_z = number(f.values[ground_f]);
        if (height_f >= 0) b.height_m = number(f.values[height_f]);
        for (std::size_t k = 0; k < layer.field_names.size(); ++k)
            if (!kOwnFields.count(layer.field_names[k])) b.attributes.emplace_back(layer.field_names[k], f.values[k]);
        if (status_f >= 0 && std::holds_alternative<std::string>(f.values[status_f]) && std::get<std::string>(f.values[status_f]) != "ok") {
            b.status = std::get<std::string>(f.values[status_f]);
            if (reason_f >= 0 && std::holds_alternative<std::string>(f.values[reason_f])) b.reason = std::get<std::string>(f.values[reason_f]);
        }
        complete_building(b, model.crs, o.validity);
        model.buildings.push_back(std::move(b));
    }
    return model;
}

ExportReport write_city_model(const CityModel& model, const CrsInfo& crs, const std::string& out_dir, const ExportOptions& o,
                              const Progress& progress) {
    o.validate();
    ensure_directory(out_dir);
    namespace fs = std::filesystem;
    ExportReport rep;
    rep.crs = model.crs.label;
    rep.vertical_known = model.crs.vertical_epsg.has_value();
    rep.buildings = model.buildings.size();
    for (const Building& b : model.buildings) {
        rep.with_lod1 += !b.lod1.empty(), rep.valid_lod1 += !b.lod1.empty() && b.lod1_errors.empty();
        rep.with_lod2 += !b.lod2.empty(), rep.valid_lod2 += !b.lod2.empty() && b.lod2_errors.empty();
        ++rep.status_counts[b.status];
    }
    if (wants(o.lods, 2) && rep.buildings > 0 && rep.with_lod2 == 0)
        log::warning("no building has LOD2 roofs (they are built from a cloud: `cityforge roofs`, or `run`); the LOD2 outputs hold LOD0 and LOD1 only");
    if (model.crs.gml_srs_name().empty() && (wants(o.formats, "citygml") || wants(o.formats, "cityjson") || wants(o.formats, "cityjsonseq")))
        log::warning("the buildings' CRS (" + model.crs.label +
                     ") has no EPSG code: CityGML is written without srsName (its header comment names the CRS), CityJSON without referenceSystem");
    const std::size_t steps = o.formats.size() + (wants(o.formats, "citygml") && wants(o.lods, 2) ? 1 : 0);
    std::size_t done = 0;
    // Each format is one task, written on its own file from the same model:
    // the tasks run in parallel (the bytes of each file do not depend on it);
    // the report and the progress are updated under one lock.
    std::mutex lock;
    std::vector<std::function<void()>> writers;
    auto timed = [&](const std::string& format, const std::string& file, auto write) {
        writers.push_back([&, format, file, write]() {
            {
                std::lock_guard g(lock);
                progress(double(done) / double(steps), format);
            }
            const auto t0 = std::chrono::steady_clock::now();
            const std::string path = (fs::path(out_dir) / file).string();
            write(path);
            std::lock_guard g(lock);
            rep.seconds[format] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            rep.files.emplace(format, path);  // a writer may have named its main file (3dtiles: tileset.json)
            ++done;
        });
    };

    // The flat tables' rows, shared by the GeoJSON and GeoPackage tasks.
    std::vector<FieldDefinition> fields{{"cityforge_id", FieldType::string}};
    std::vector<Feature> features;
    if (wants(o.formats, "geojson") || wants(o.formats, "gpkg") || !o.database.empty()) {
        // Flat tables: the source attributes plus ours, one row per building (failed ones say why).
        std::vector<std::string> names;
        if (!model.buildings.empty())
            for (const auto& [name, value] : model.buildings.front().attributes) names.push_back(name);
        // Field types from the first non-null value of each attribute.
        for (std::size_t k = 0; k < names.size(); ++k) {
            FieldType t = FieldType::string;
            for (const Building& b : model.buildings) {
                const AttributeValue& v = b.attributes[k].second;
                if (std::holds_alternative<std::monostate>(v)) continue;
                t = std::holds_alternative<int64_t>(v) ? FieldType::integer : std::holds_alternative<double>(v) ? FieldType::real : FieldType::string;
                break;
            }
            for (const auto& [name, declared] : model.attribute_types)
                if (name == names[k]) t = declared;
            fields.push_back({names[k], t});
        }
        for (const FieldDefinition& f : kOwnFieldDefinitions) fields.push_back(f);
        const double unit3 = model.crs.volume_unit_m3();
        features.reserve(model.buildings.size());
        for (const Building& b : model.buildings) {
            Feature f;
            f.geometry = b.footprint;
            f.values.push_back(b.id);
            for (const auto& [name, value] : b.attributes) f.values.push_back(value);
            auto opt = [](bool have, AttributeValue v) { return have ? v : AttributeValue(); };
            f.values.push_back(b.status);
            f.values.push_back(opt(!b.reason.empty(), b.reason));
            f.values.push_back(b.roof_z ? AttributeValue(*b.roof_z) : AttributeValue());
            f.values.push_back(opt(!b.lod1.empty(), int64_t(b.lod1_errors.empty())));
            f.values.push_back(opt(!b.lod1_errors.empty(), join(b.lod1_errors)));
            f.values.push_back(opt(!b.lod1.empty(), b.lod1_volume * unit3));
            f.values.push_back(opt(!b.lod2.empty(), int64_t(b.lod2_errors.empty())));
            f.values.push_back(opt(!b.lod2_errors.empty(), join(b.lod2_errors)));
            f.values.push_back(opt(!b.lod2.empty(), b.lod2_volume * unit3));
            f.values.push_back(opt(!b.roof_type.empty(), b.roof_type));
            bool v13 = true, v22 = true;
            for (const RoofPart& p : b.roof_parts) v13 = v13 && p.lod13_errors.empty(), v22 = v22 && p.lod22_errors.empty();
            f.values.push_back(opt(!b.roof_parts.empty(), int64_t(v13)));
            f.values.push_back(opt(!b.roof_parts.empty(), int64_t(v22)));
            f.values.push_back(opt(!b.roof_parts.empty(), int64_t(b.roof_parts.size())));
            features.push_back(std::move(f));
        }
        if (wants(o.formats, "geojson"))
            timed("geojson", "buildings.geojson", [&](const std::string& p) {
                VectorWriteOptions vo;
                vo.driver = "GeoJSON";
                vo.rfc7946 = o.geojson_crs == "rfc7946";
                if (vo.rfc7946) vo.coordinate_precision = 7;
                vo.source = model.source;  // a building that cannot go to lon/lat is named with its input
                vo.id_field = "cityforge_id";
                write_polygon_features(p, crs, fields, features, vo);
            });
        if (wants(o.formats, "gpkg"))
            timed("gpkg", "buildings.gpkg", [&](const std::string& p) {
                VectorWriteOptions vo;
                vo.driver = "GPKG";
                write_polygon_features(p, crs, fields, features, vo);
            });
        if (!o.database.empty()) {
            const auto t0 = std::chrono::steady_clock::now();
            VectorWriteOptions vo;
            vo.driver = "PostgreSQL";
            write_polygon_features(o.database, crs, fields, features, vo);
            rep.seconds["database"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            rep.files["database"] = o.database;
        }
    }
    if (wants(o.formats, "citygml")) {
        if (wants(o.lods, 1) || wants(o.lods, 0))
            timed("citygml_lod1", "buildings_lod1.gml", [&](const std::string& p) { write_citygml(p, model, {1, 3}); });
        if (wants(o.lods, 2)) timed("citygml_lod2", "buildings_lod2.gml", [&](const std::string& p) { write_citygml(p, model, {2, 3}); });
    }
    // Roof textures from the ortho, for CityJSON, glTF and 3D Tiles.
    std::optional<RoofTextureAtlas> atlas;
    if (!o.texture_ortho.empty() && wants(o.lods, 2) &&
        (wants(o.formats, "cityjson") || wants(o.formats, "cityjsonseq") || wants(o.formats, "gltf") || wants(o.formats, "3dtiles"))) {
        atlas = build_roof_texture_atlas(model, o.texture_ortho, o.texture);
        const RoofTextureLayout& l = atlas->layout;
        if (atlas->png.empty()) {
            log::warning(o.texture_ortho + ": no building's LOD2 roofs lie on the ortho; nothing is textured");
            atlas.reset();
        } else {
            const fs::path png = fs::path(out_dir) / "textures" / "roofs.png";
            ensure_directory(png.parent_path().string());
            write_text_file(png, atlas->png);  // atomic; bytes as they are
            rep.files["textures"] = png.string();
            log::info(png.string() + ": roofs of " + std::to_string(l.windows.size()) + " buildings, " + std::to_string(l.atlas_width) + " x " +
                      std::to_string(l.atlas_height) + " px" + (l.outside.empty() ? "" : ", " + std::to_string(l.outside.size()) + " off the ortho") +
                      (l.no_room.empty() ? "" : ", " + std::to_string(l.no_room.size()) + " left out (atlas full)"));
        }
    }
    CityJsonWriteOptions cj;
    cj.lods = o.lods;
    if (atlas) cj.textures = &atlas->layout;
    if (wants(o.formats, "cityjson")) timed("cityjson", "buildings.city.json", [&](const std::string& p) { write_cityjson(p, model, cj); });
    if (wants(o.formats, "cityjsonseq"))
        timed("cityjsonseq", "buildings.city.jsonl", [&](const std::string& p) {
            CityJsonWriteOptions seq = cj;
            seq.sequence = true;
            write_cityjson(p, model, seq);
        });
    if (wants(o.formats, "gltf")) timed("gltf", "buildings.glb", [&](const std::string& p) { write_glb(p, model, wants(o.lods, 2), atlas ? &*atlas : nullptr); });
    if (wants(o.formats, "3dtiles"))
        timed("3dtiles", "3dtiles", [&](const std::string& p) {
            Tiles3dWriteOptions t = o.tiles;
            t.prefer_lod2 = wants(o.lods, 2);
            const Tiles3dWriteReport tr = write_3dtiles(p, model, crs, t, atlas ? &*atlas : nullptr);
            {
                std::lock_guard g(lock);
                rep.files["3dtiles"] = (fs::path(p) / "tileset.json").string();
            }
            log::info(p + ": " + std::to_string(tr.buildings) + " buildings in " + std::to_string(tr.content_tiles) + " tiles (depth " +
                      std::to_string(tr.depth) + ", " + std::to_string(tr.triangles) + " triangles)");
        });
    // Every format is written even when another fails; the first failing
    // format (in the order above) is the error reported.
    parallel_tasks_in_order(writers.size(), 1, [&](std::size_t k) { writers[k](); });
    progress(1.0, "written");
    return rep;
}

ExportReport run_export(const std::string& in_path, const std::string& out_dir, const ExportOptions& o, const Progress& progress) {
    o.validate();
    PolygonLayer layer = read_polygon_layer(in_path, o.layer);
    if (layer.crs.empty()) throw Error(in_path, "buildings have no CRS; city models need one (assign it with ogr2ogr -a_srs)");
    // City models need metres: lon/lat buildings (our own RFC 7946 buildings.geojson, OpenStreetMap
    // extracts) are worked on the UTM zone of their centre, as `run` and `footprints` work a lon/lat ortho.
    if (layer.crs.geographic) {
        const CrsInfo work = working_crs_for_layer(layer, {}, in_path);
        put_layer_on(layer, work, in_path);
        log::info(in_path + ": lon/lat buildings; the city models are written in " + work.label() + " (the UTM zone of their centre)");
    }
    CrsInfo crs = layer.crs;
    if (!o.vertical_crs.empty()) {
        const CrsInfo v = crs_from_user_input(o.vertical_crs, "--vertical-crs");
        if (crs.vertical_epsg && v.vertical_epsg != crs.vertical_epsg && v.epsg != crs.vertical_epsg)
            throw Error("--vertical-crs", "the input already has vertical CRS " + crs.vertical_name + " (EPSG:" + std::to_string(*crs.vertical_epsg) + ")");
        if (!crs.vertical_epsg) crs = combine_with_vertical(crs, v);
    }
    if (!crs.vertical_epsg) log::warning(in_path + ": no vertical CRS; heights are written without a named datum (give --vertical-crs)");
    else if (!crs.epsg || crs.epsg == crs.horizontal_epsg)
        log::warning(in_path + ": " + crs.label() + " has no EPSG compound code; CityJSON's referenceSystem names the horizontal CRS only");
    const CityModel model = build_city_model(layer, crs, o, in_path);
    // glTF and 3D Tiles are meshes of solids: refused before any file is written.
    const bool solids = std::any_of(model.buildings.begin(), model.buildings.end(), [](const Building& b) { return !b.lod1.empty() || !b.lod2.empty(); });
    if (!solids && (wants(o.formats, "gltf") || wants(o.formats, "3dtiles")))
        throw Error(in_path, "no building has a height (fields " + o.ground_field + ", " + o.height_field +
                                 "), so there is no solid for glTF or 3D Tiles; run `cityforge heights` first, or leave gltf and 3dtiles out of --formats");
    return write_city_model(model, crs, out_dir, o, progress);
}

}  // namespace cityforge
