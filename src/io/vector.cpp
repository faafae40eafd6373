#include "io/vector.hpp"

#include <cstdio>
#include <cstdlib>
#include <ctime>

#include <algorithm>
#include <cmath>
#include <cpl_string.h>
#include <cctype>
#include <filesystem>
#include <set>
#include <gdal_priv.h>
#include <ogrsf_frmts.h>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "crs/gdal_util.hpp"

namespace cityforge {

namespace {
// Why OGR could not open `path`, in words a user can act on.
std::string unreadable_vector(const std::string& path, const std::string& gdal_suffix) {
    namespace fs = std::filesystem;
    std::error_code ec;
    if (fs::is_directory(path, ec)) return "is a directory, not a vector dataset OGR can read";
    if (fs::is_regular_file(path, ec) && fs::file_size(path, ec) == 0 && !ec) return "empty file (0 bytes)";
    std::string name = fs::path(path).filename().string();
    for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    const auto ends = [&](const std::string& tail) { return name.size() >= tail.size() && name.compare(name.size() - tail.size(), tail.size(), tail) == 0; };
    if (ends(".city.json") || ends(".city.jsonl") || ends(".glb") || ends(".gltf"))
        return "a city model (CityJSON / glTF), not a vector layer: give the building table (e.g. the buildings.gpkg or .geojson written beside it)";
    return "not a vector dataset OGR can read" + gdal_suffix;
}
}  // namespace

VectorInfo read_vector_info(const std::string& path) {
    ensure_gdal_registered();
    require_dataset_exists(path);
    GdalErrorCapture capture;
    std::unique_ptr<GDALDataset> ds(GDALDataset::Open(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY));
    if (!ds) throw Error(path, unreadable_vector(path, capture.suffix()));
    VectorInfo info;
    info.path = path;
    info.driver = ds->GetDriver() ? ds->GetDriver()->GetDescription() : "";
    for (OGRLayer* layer : ds->GetLayers()) {
        VectorLayerInfo li;
        li.name = layer->GetName();
        li.geometry_type = OGRGeometryTypeToName(layer->GetGeomType());
        li.feature_count = layer->GetFeatureCount(TRUE);
        li.crs = crs_from_ogr(layer->GetSpatialRef(), path);
        OGREnvelope env;
        if (li.feature_count > 0 && layer->GetExtent(&env, TRUE) == OGRERR_NONE)
            li.extent = Extent{env.MinX, env.MinY, env.MaxX, env.MaxY};
        OGRFeatureDefn* defn = layer->GetLayerDefn();
        for (int i = 0; i < defn->GetFieldCount(); ++i) li.fields.emplace_back(defn->GetFieldDefn(i)->GetNameRef());
        info.layers.push_back(std::move(li));
    }
    return info;
}

namespace {
OGRLinearRing to_ogr(const Ring& r) {
    OGRLinearRing ring;
    for (const MapPoint& p : r) ring.addPoint(p.x, p.y);
    if (!r.empty()) ring.addPoint(r.front().x, r.front().y);
    return ring;
}
}  // namespace

namespace {

// Creates the layer and writes the features; false on the first failure (GDAL's message stays in the capture).
// `null_geometry` (empty, or one flag per feature): features written without geometry.
bool write_layer(GDALDataset* ds, const std::string& name, OGRSpatialReference* srs, const std::vector<FieldDefinition>& fields,
                 const std::vector<Feature>& features, CPLStringList& lco, bool layer_transaction,
                 const std::vector<char>& null_geometry = {}) {
    bool any_multi = false;
    for (const Feature& f : features) any_multi = any_multi || f.geometry.size() > 1;
    OGRLayer* layer = ds->CreateLayer(name.c_str(), srs, any_multi ? wkbMultiPolygon : wkbPolygon, lco.List());
    bool ok = layer != nullptr;
    for (const FieldDefinition& f : fields) {
        if (!ok) break;
        OGRFieldDefn defn(f.name.c_str(), f.type == FieldType::integer ? OFTInteger64
                                          : f.type == FieldType::real  ? OFTReal
                                                                       : OFTString);
        ok = layer->CreateField(&defn) == OGRERR_NONE;
    }
    if (ok && layer_transaction) ok = layer->StartTransaction() == OGRERR_NONE;
    for (std::size_t fi = 0; fi < features.size(); ++fi) {
        if (!ok) break;
        const Feature& feature = features[fi];
        OGRFeature f(layer->GetLayerDefn());
        for (std::size_t i = 0; i < fields.size() && i < feature.values.size(); ++i) {
            const AttributeValue& v = feature.values[i];
            const int idx = static_cast<int>(i);
            if (std::holds_alternative<int64_t>(v)) f.SetField(idx, static_cast<GIntBig>(std::get<int64_t>(v)));
            else if (std::holds_alternative<double>(v)) f.SetField(idx, std::get<double>(v));
            else if (std::holds_alternative<std::string>(v)) f.SetField(idx, std::get<std::string>(v).c_str());
            else f.SetFieldNull(idx);
        }
        if (!null_geometry.empty() && null_geometry[fi]) {
            ok = layer->CreateFeature(&f) == OGRERR_NONE;
            continue;
        }
        OGRMultiPolygon multi;
        for (const Polygon& part : feature.geometry) {
            auto* poly = new OGRPolygon;
            poly->addRingDirectly(new OGRLinearRing(to_ogr(part.outer)));
            for (const Ring& h : part.holes) poly->addRingDirectly(new OGRLinearRing(to_ogr(h)));
            multi.addGeometryDirectly(poly);
        }
        if (feature.geometry.size() == 1) f.SetGeometry(multi.getGeometryRef(0));
        else f.SetGeometry(&multi);
        ok = layer->CreateFeature(&f) == OGRERR_NONE;
    }
    if (ok && layer_transaction) ok = layer->CommitTransaction() == OGRERR_NONE;
    return ok;
}

// RFC 7946 GeoJSON: GDAL moves every feature to WGS 84 lon/lat on write and
// fails the whole file when one vertex cannot be moved (coordinates far
// outside the CRS's area). Each feature is tried here first: one flag per
// feature that cannot be moved (it is then written without geometry), with a
// warning naming the source and the feature. Empty when all can be moved.
std::vector<char> features_without_lon_lat(const std::string& path, const OGRSpatialReference& srs, const CrsInfo& crs,
                                           const std::vector<FieldDefinition>& fields, const std::vector<Feature>& features,
                                           const VectorWriteOptions& options) {
    OGRSpatialReference from(srs), wgs84;
    if (from.IsCompound()) from.StripVertical();
    wgs84.SetWellKnownGeogCS("WGS84");
    from.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    if (from.IsSame(&wgs84)) return {};
    std::unique_ptr<OGRCoordinateTransformation> ct;
    {
        GdalErrorCapture capture;
        ct.reset(OGRCreateCoordinateTransformation(&from, &wgs84));
        if (!ct) throw Error(path, "no transformation from " + crs.label() + " to WGS 84 lon/lat (RFC 7946)" + capture.suffix());
    }
    std::size_t id_index = fields.size();
    for (std::size_t i = 0; i < fields.size(); ++i)
        if (!options.id_field.empty() && fields[i].name == options.id_field) id_index = i;
    auto name_of = [&](std::size_t fi) {
        if (id_index < features[fi].values.size()) {
            const AttributeValue& v = features[fi].values[id_index];
            if (const auto* s = std::get_if<std::string>(&v)) return "'" + *s + "'";
            if (const auto* n = std::get_if<int64_t>(&v)) return std::to_string(*n);
        }
        return "number " + std::to_string(fi + 1);
    };
    const std::string source = options.source.empty() ? path : options.source;
    std::vector<char> null_geometry(features.size(), 0);
    std::size_t failed = 0;
    std::vector<double> x, y, z;
    std::vector<int> ok;
    for (std::size_t fi = 0; fi < features.size(); ++fi) {
        x.clear(), y.clear();
        for (const Polygon& p : features[fi].geometry) {
            for (const MapPoint& q : p.outer) x.push_back(q.x), y.push_back(q.y);
            for (const Ring& h : p.holes)
                for (const MapPoint& q : h) x.push_back(q.x), y.push_back(q.y);
        }
        if (x.empty()) continue;
        const std::vector<double> x0 = x, y0 = y;
        z.assign(x.size(), 0.0);
        ok.assign(x.size(), 0);
        GdalErrorCapture capture;  // PROJ's complaint about the failed points is ours to report
        const bool all = ct->Transform(static_cast<int>(x.size()), x.data(), y.data(), z.data(), nullptr, ok.data());
        std::size_t bad = x.size();
        for (std::size_t i = 0; i < x.size() && bad == x.size(); ++i)
            if (!ok[i] || !std::isfinite(x[i]) || !std::isfinite(y[i]) || std::abs(y[i]) > 90.0) bad = i;
        if (bad == x.size() && !all) bad = 0;
        if (bad == x.size()) continue;
        null_geometry[fi] = 1;
        if (++failed <= 10) {
            char at[96];
            std::snprintf(at, sizeof at, "%.6g, %.6g", x0[bad], y0[bad]);
            log::warning(source + ": feature " + name_of(fi) + ": cannot be moved from " + crs.label() +
                         " to WGS 84 lon/lat for RFC 7946 GeoJSON (a vertex at " + at + "); its row in " + path +
                         " has no geometry");
        }
    }
    if (failed > 10)
        log::warning(source + ": " + std::to_string(failed) + " features in all cannot be moved to WGS 84 lon/lat; their rows in " + path +
                     " have no geometry");
    CPLErrorReset();
    if (!failed) null_geometry.clear();
    return null_geometry;
}

// "PG:dbname=x tables=schema.name" -> the connection without `tables=` and the table named by it (or `fallback`).
std::pair<std::string, std::string> database_and_table(const std::string& path, const std::string& fallback) {
    std::string conn, table = fallback;
    std::size_t i = 0;
    while (i < path.size()) {
        const std::size_t j = std::min(path.find(' ', i), path.size());
        const std::string tok = path.substr(i, j - i);
        if (tok.rfind("tables=", 0) == 0) table = tok.substr(7);
        else if (!tok.empty()) conn += (conn.empty() ? "" : " ") + tok;
        i = j + 1;
    }
    if (table.find(',') != std::string::npos) throw Error(path, "name one table to write (tables=NAME)");
    return {conn, table};
}

// PostGIS: the table is replaced inside one transaction (nothing changes when a write fails); the SRID is the
// horizontal CRS's EPSG code, the vertical CRS goes into a `crs_vertical` column (PostGIS SRIDs are 2-D).
void write_database_layer(const std::string& path, const CrsInfo& crs, std::vector<FieldDefinition> fields, std::vector<Feature> features,
                          const VectorWriteOptions& options) {
    const auto [conn, table] = database_and_table(path, options.layer);
    GdalErrorCapture capture;
    const char* drivers[] = {"PostgreSQL", nullptr};
    std::unique_ptr<GDALDataset> ds(GDALDataset::Open(conn.c_str(), GDAL_OF_VECTOR | GDAL_OF_UPDATE, drivers));
    if (!ds) throw Error(path, "cannot open the database for writing" + capture.suffix());
    OGRSpatialReference srs;
    if (!crs.empty()) {
        srs.importFromWkt(crs.wkt.c_str());
        if (srs.IsCompound()) srs.StripVertical();
        srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    }
    if (crs.vertical_epsg || !crs.vertical_name.empty()) {
        bool present = false;
        for (const FieldDefinition& f : fields) present = present || f.name == "crs_vertical";
        if (!present) {
            const std::string v = crs.vertical_epsg ? "EPSG:" + std::to_string(*crs.vertical_epsg) : crs.vertical_name;
            fields.push_back({"crs_vertical", FieldType::string});
            for (Feature& f : features) f.values.resize(fields.size() - 1), f.values.push_back(v);
        }
    }
    CPLStringList lco;
    lco.SetNameValue("OVERWRITE", "YES");
    lco.SetNameValue("LAUNDER", "NO");
    lco.SetNameValue("GEOMETRY_NAME", "geom");
    lco.SetNameValue("FID", "fid");
    lco.SetNameValue("PRECISION", "NO");
    if (ds->StartTransaction(FALSE) != OGRERR_NONE) throw Error(path, "cannot start a transaction" + capture.suffix());
    bool ok = write_layer(ds.get(), table, crs.empty() ? nullptr : &srs, fields, features, lco, false);
    ok = ok && CPLGetLastErrorType() < CE_Failure;
    if (!ok) {
        const std::string why = capture.suffix();
        ds->RollbackTransaction();
        throw Error(path, "writing table '" + table + "' failed" + why);
    }
    if (ds->CommitTransaction() != OGRERR_NONE) throw Error(path, "committing table '" + table + "' failed" + capture.suffix());
}

}  // namespace

bool is_database_name(const std::string& path) { return path.size() > 3 && (path.compare(0, 3, "PG:") == 0 || path.compare(0, 3, "pg:") == 0); }

void write_polygon_features(const std::string& path, const CrsInfo& crs, const std::vector<FieldDefinition>& fields,
                            const std::vector<Feature>& features, const VectorWriteOptions& options) {
    ensure_gdal_registered();
    if (is_database_name(path)) return write_database_layer(path, crs, fields, features, options);
    GDALDriver* driver = GetGDALDriverManager()->GetDriverByName(options.driver.c_str());
    if (!driver) throw Error(path, "GDAL has no '" + options.driver + "' driver");
    const std::filesystem::path tmp = temporary_path_for(path);
    discard_file(tmp);
    GdalErrorCapture capture;
    auto fail = [&](const std::string& what) {
        // GDAL names the temporary file; the user gave `path`.
        const std::string why = user_named(capture.suffix(), tmp, path);
        discard_file(tmp);
        throw Error(path, what + why);
    };
    // GeoPackages record a last-change time; SOURCE_DATE_EPOCH (the
    // reproducible-builds convention) fixes it so that reruns give the same bytes.
    std::string stamp;
    if (const char* epoch = std::getenv("SOURCE_DATE_EPOCH")) {
        const std::time_t t = static_cast<std::time_t>(std::atoll(epoch));
        std::tm tm{};
        gmtime_r(&t, &tm);
        char buf[32];
        std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
        stamp = buf;
    }
    CPLSetThreadLocalConfigOption("OGR_CURRENT_DATE", stamp.empty() ? nullptr : stamp.c_str());
    GDALDataset* ds = driver->Create(tmp.c_str(), 0, 0, 0, GDT_Unknown, nullptr);
    if (!ds) fail("cannot create vector file");
    OGRSpatialReference srs;
    if (!crs.empty()) srs.importFromWkt(crs.wkt.c_str());
    // A CRS with a registered code (a compound 28992 + 5709 is EPSG:7415) is
    // written under that code, not as a custom definition (GeoPackage srs_id 100000).
    if (crs.epsg && !srs.GetAuthorityCode(nullptr)) {
        OGRSpatialReference coded;
        if (coded.importFromEPSG(*crs.epsg) == OGRERR_NONE) srs = coded;
    }
    srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    CPLStringList lco;
    if (options.driver == "GeoJSON") {
        if (options.rfc7946) lco.SetNameValue("RFC7946", "YES");
        if (options.coordinate_precision > 0)
            lco.SetNameValue("COORDINATE_PRECISION", std::to_string(options.coordinate_precision).c_str());
    }
    std::vector<char> null_geometry;
    if (options.driver == "GeoJSON" && options.rfc7946 && !crs.empty()) {
        try {
            null_geometry = features_without_lon_lat(path, srs, crs, fields, features, options);
        } catch (...) {
            GDALClose(ds);
            discard_file(tmp);
            throw;
        }
        CPLErrorReset();
    }
    const bool ok = write_layer(ds, options.layer, crs.empty() ? nullptr : &srs, fields, features, lco, options.driver == "GPKG", null_geometry);
    GDALClose(ds);
    if (!ok || CPLGetLastErrorType() >= CE_Failure) fail("writing features failed");
    // GDAL 3.6's GDALClose reports no error, and drivers do not check every
    // write: a full disk leaves a silently truncated file. Read it back.
    {
        std::unique_ptr<GDALDataset> back(GDALDataset::Open(tmp.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY));
        OGRLayer* l = back ? (back->GetLayerByName(options.layer.c_str()) ? back->GetLayerByName(options.layer.c_str()) : back->GetLayer(0)) : nullptr;
        const bool complete = l && l->GetFeatureCount(TRUE) == static_cast<GIntBig>(features.size()) && CPLGetLastErrorType() < CE_Failure;
        back.reset();
        if (!complete) fail("write failed (disk full?): the file read back is incomplete");
    }
    commit_file(tmp, path);
}

}  // namespace cityforge

namespace cityforge {

namespace {
Ring from_ogr(const OGRLinearRing* r) {
    Ring out;
    const int n = r->getNumPoints();
    for (int i = 0; i < n; ++i) out.push_back({r->getX(i), r->getY(i)});
    if (out.size() > 1 && out.front().x == out.back().x && out.front().y == out.back().y) out.pop_back();
    return out;
}
Polygon from_ogr(const OGRPolygon* p) {
    Polygon out;
    out.outer = from_ogr(p->getExteriorRing());
    for (int i = 0; i < p->getNumInteriorRings(); ++i) out.holes.push_back(from_ogr(p->getInteriorRing(i)));
    return out;
}
}  // namespace

PolygonLayer read_polygon_layer(const std::string& name, const std::string& layer_arg) {
    ensure_gdal_registered();
    // GDAL's dataset name for one table of a GeoPackage, GPKG:file.gpkg:layer (GDAL 3.6 opens
    // the whole file with it): the layer is taken from the name.
    std::string path = name, layer_name = layer_arg;
    if (name.rfind("GPKG:", 0) == 0) {
        const std::size_t colon = name.rfind(':');
        if (colon > 5 && std::filesystem::is_regular_file(name.substr(5, colon - 5))) {
            path = name.substr(5, colon - 5);
            if (layer_name.empty()) layer_name = name.substr(colon + 1);
        }
    }
    require_dataset_exists(path);
    GdalErrorCapture capture;
    std::unique_ptr<GDALDataset> ds(GDALDataset::Open(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY));
    if (!ds) throw Error(path, unreadable_vector(path, capture.suffix()));
    // The layer: the one named, else the only polygon layer (a GeoPackage may
    // also hold tables without geometry); several are ambiguous, never "the first".
    std::vector<OGRLayer*> polygon_layers;
    std::string names;
    for (int i = 0; i < ds->GetLayerCount(); ++i) {
        OGRLayer* l = ds->GetLayer(i);
        names += (names.empty() ? "" : ", ") + std::string(l->GetName());
        const auto t = wkbFlatten(l->GetGeomType());
        if (t == wkbPolygon || t == wkbMultiPolygon || t == wkbUnknown || t == wkbGeometryCollection) polygon_layers.push_back(l);
    }
    OGRLayer* layer = nullptr;
    if (!layer_name.empty()) {
        layer = ds->GetLayerByName(layer_name.c_str());
        if (!layer) throw Error(path, "has no layer '" + layer_name + "' (layers: " + names + ")");
    } else if (polygon_layers.size() > 1) {
        throw Error(path, "has " + std::to_string(polygon_layers.size()) + " polygon layers (" + names +
                              "); choose one with --layer NAME" +
                              (ds->GetDriver() && EQUAL(ds->GetDriver()->GetDescription(), "GPKG") ? " or the dataset name GPKG:" + path + ":NAME" : std::string()));
    } else {
        layer = !polygon_layers.empty() ? polygon_layers.front() : ds->GetLayerCount() > 0 ? ds->GetLayer(0) : nullptr;
    }
    if (!layer) throw Error(path, "has no layer");
    PolygonLayer out;
    out.crs = crs_from_ogr(layer->GetSpatialRef(), path);
    OGRFeatureDefn* defn = layer->GetLayerDefn();
    for (int i = 0; i < defn->GetFieldCount(); ++i) {
        const OGRFieldDefn* fd = defn->GetFieldDefn(i);
        out.field_names.emplace_back(fd->GetNameRef());
        const OGRFieldType t = fd->GetType();
        // Booleans and other subtypes stay text: their meaning survives a round trip as text.
        out.field_types.push_back(fd->GetSubType() != OFSTNone ? FieldType::string
                                  : (t == OFTInteger || t == OFTInteger64) ? FieldType::integer
                                  : t == OFTReal ? FieldType::real : FieldType::string);
    }
    layer->ResetReading();
    for (auto& f : *layer) {
        const OGRGeometry* g = f->GetGeometryRef();
        const std::string where = path + " feature " + std::to_string(f->GetFID());
        if (!g || g->IsEmpty()) throw Error(where, "has no geometry");
        Feature feature;
        const auto type = wkbFlatten(g->getGeometryType());
        if (type == wkbPolygon) feature.geometry.push_back(from_ogr(g->toPolygon()));
        else if (type == wkbMultiPolygon)
            for (const OGRPolygon* p : *g->toMultiPolygon()) feature.geometry.push_back(from_ogr(p));
        else throw Error(where, std::string("is a ") + OGRGeometryTypeToName(g->getGeometryType()) + ", not a polygon");
        // No CRS puts a place on Earth beyond 1e9 of its units (4e7 m, 1.3e8 ft,
        // 360 degrees): such coordinates are corrupt, and would overflow every
        // grid laid over the footprint (1e300 once ended in a crash).
        auto check_ring = [&](const Ring& ring) {
            for (const MapPoint& q : ring)
                if (!(std::abs(q.x) <= 1e9 && std::abs(q.y) <= 1e9)) {
                    char b[96];
                    std::snprintf(b, sizeof b, "(%.6g, %.6g)", q.x, q.y);
                    throw Error(where, std::string("has a coordinate ") + b + " beyond +-1e9 CRS units: corrupt coordinates?");
                }
        };
        for (const Polygon& p : feature.geometry) {
            check_ring(p.outer);
            for (const Ring& h : p.holes) check_ring(h);
        }
        if (!g->IsValid()) throw Error(where, "is an invalid polygon (self-intersection or bad ring); repair it first, e.g. ogr2ogr -makevalid");
        for (Polygon& p : feature.geometry) orient_polygon(p);
        for (int i = 0; i < defn->GetFieldCount(); ++i) {
            if (!f->IsFieldSetAndNotNull(i)) feature.values.emplace_back();
            else if (out.field_types[i] == FieldType::integer) feature.values.emplace_back(int64_t(f->GetFieldAsInteger64(i)));
            else if (out.field_types[i] == FieldType::real) feature.values.emplace_back(f->GetFieldAsDouble(i));
            else feature.values.emplace_back(std::string(f->GetFieldAsString(i)));
        }
        out.fids.push_back(f->GetFID());
        out.features.push_back(std::move(feature));
    }
    if (out.features.empty()) throw Error(path, "layer holds no polygon");
    return out;
}

std::string vector_driver_for(const std::string& path) {
    if (is_database_name(path)) return "PostgreSQL";
    std::string ext = std::filesystem::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext == ".gpkg") return "GPKG";
    if (ext == ".geojson" || ext == ".json") return "GeoJSON";
    if (ext == ".fgb") return "FlatGeobuf";
    if (ext == ".shp") return "ESRI Shapefile";
    throw Error(path, "unknown vector output format (use .gpkg, .geojson, .fgb, .shp or PG:...)");
}

void reproject_features(std::vector<Feature>& features, const CrsInfo& from, const CrsInfo& to, const std::string& subject) {
    std::vector<double> x, y;
    auto each_ring = [&](auto&& fn) {
        for (Feature& f : features)
            for (Polygon& p : f.geometry) {
                fn(p.outer);
                for (Ring& h : p.holes) fn(h);
            }
    };
    each_ring([&](Ring& r) {
        for (const MapPoint& q : r) x.push_back(q.x), y.push_back(q.y);
    });
    std::vector<double> z(x.size(), 0.0);
    transform_points(from, to, x, y, z, subject);
    std::size_t i = 0;
    each_ring([&](Ring& r) {
        for (MapPoint& q : r) q = {x[i], y[i]}, ++i;
    });
}

namespace {
constexpr const char* kNoLayerCrs = "footprints have no CRS (coordinate reference system); give the file one (ogr2ogr -a_srs EPSG:...)";
}  // namespace

CrsInfo working_crs_for_layer(const PolygonLayer& layer, const std::string& working_crs, const std::string& subject) {
    if (layer.crs.empty()) throw Error(subject, kNoLayerCrs);
    Extent all = empty_extent();
    for (const Feature& f : layer.features) include(all, parts_extent(f.geometry));
    if (layer.crs.geographic && all.min_x <= all.max_x &&
        (all.min_x < -540.0 || all.max_x > 540.0 || all.min_y < -90.0 || all.max_y > 90.0)) {
        char box[160];
        std::snprintf(box, sizeof box, "x %.6g..%.6g, y %.6g..%.6g", all.min_x, all.max_x, all.min_y, all.max_y);
        throw Error(subject, std::string("coordinates (") + box + ") are not longitudes and latitudes, but the CRS is " + layer.crs.label() +
                                 "; are they in a projected CRS? (a GeoJSON without a \"crs\" member is RFC 7946 lon/lat)");
    }
    if (!working_crs.empty()) {
        const CrsInfo w = crs_from_user_input(working_crs, "--working-crs");
        if (w.geographic) throw Error("--working-crs", w.label() + " is geographic; the working CRS must be projected (metres)");
        return w;
    }
    if (!layer.crs.geographic) return layer.crs;
    if (!(all.min_x <= all.max_x)) throw Error(subject, "no footprints to place on a working CRS");
    return utm_crs_for(layer.crs, {0.5 * (all.min_x + all.max_x), 0.5 * (all.min_y + all.max_y)});
}

void put_layer_on(PolygonLayer& layer, const CrsInfo& target, const std::string& subject) {
    if (target.empty() || same_horizontal_crs(layer.crs, target)) return;
    if (layer.crs.empty()) throw Error(subject, kNoLayerCrs);
    log::info(subject + ": footprints in " + layer.crs.label() + " worked on in " + target.label());
    reproject_features(layer.features, layer.crs, target, subject);
    layer.crs = target;
}

std::vector<std::string> drop_colliding_fields(PolygonLayer& layer, const std::vector<std::string>& ours, const std::string& subject,
                                               bool warn) {
    auto lower = [](std::string s) {
        for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        return s;
    };
    std::set<std::string> taken;
    for (const std::string& n : ours) taken.insert(lower(n));
    std::vector<std::size_t> keep;
    std::vector<std::string> dropped;
    for (std::size_t i = 0; i < layer.field_names.size(); ++i) {
        if (taken.count(lower(layer.field_names[i]))) dropped.push_back(layer.field_names[i]);
        else keep.push_back(i);
    }
    if (dropped.empty()) return dropped;
    std::vector<std::string> names;
    std::vector<FieldType> types;
    for (std::size_t i : keep) names.push_back(layer.field_names[i]), types.push_back(layer.field_types[i]);
    for (Feature& f : layer.features) {
        std::vector<AttributeValue> values;
        values.reserve(keep.size());
        for (std::size_t i : keep) values.push_back(std::move(f.values[i]));
        f.values = std::move(values);
    }
    layer.field_names = std::move(names);
    layer.field_types = std::move(types);
    std::string list;
    for (const std::string& n : dropped) list += (list.empty() ? "" : ", ") + n;
    if (warn && !dropped.empty())
        log::warning(subject + ": input field" + (dropped.size() > 1 ? "s " : " ") + list + (dropped.size() > 1 ? " are" : " is") +
                 " replaced by the value" + (dropped.size() > 1 ? "s" : "") + " computed here");
    return dropped;
}

}  // namespace cityforge
