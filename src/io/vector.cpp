#include "io/vector.hpp"

#include <algorithm>
#include <cmath>
#include <cpl_string.h>
#include <filesystem>
#include <gdal_priv.h>
#include <ogrsf_frmts.h>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "crs/gdal_util.hpp"

namespace cityforge {

VectorInfo read_vector_info(const std::string& path) {
    ensure_gdal_registered();
    if (!std::filesystem::exists(path)) throw Error(path, "file not found");
    GdalErrorCapture capture;
    std::unique_ptr<GDALDataset> ds(GDALDataset::Open(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY));
    if (!ds) throw Error(path, "not a vector dataset OGR can read" + capture.suffix());
    VectorInfo info;
    info.path = path;
    info.driver = ds->GetDriver() ? ds->GetDriver()->GetDescription() : "";
    for (OGRLayer* layer : ds->GetLayers()) {
        VectorLayerInfo li;
        li.name = layer->GetName();
        li.geometry_type = OGRGeometryTypeToName(layer->GetGeomType());
        li.feature_count = layer->GetFeatureCount(TRUE);
        if (const OGRSpatialReference* srs = layer->GetSpatialRef()) {
            char* wkt = nullptr;
            const char* o[] = {"FORMAT=WKT2_2019", nullptr};
            srs->exportToWkt(&wkt, o);
            li.crs = crs_from_wkt(wkt ? wkt : "", path);
            CPLFree(wkt);
        }
        OGREnvelope env;
        if (li.feature_count > 0 && layer->GetExtent(&env, TRUE) == OGRERR_NONE)
            li.extent = Extent{env.MinX, env.MinY, env.MaxX, env.MaxY};
        OGRFeatureDefn* defn = layer->GetLayerDefn();
        for (int i = 0; i < defn->GetFieldCount(); ++i) li.fields.emplace_back(defn->GetFieldDefn(i)->GetNameRef());
        info.layers.push_back(std::move(li));
    }
    return info;
}

double signed_area(const Ring& r) {
    double a = 0.0;
    const std::size_t n = r.size();
    for (std::size_t i = 0; i < n; ++i) {
        const MapPoint& p = r[i];
        const MapPoint& q = r[(i + 1) % n];
        a += p.x * q.y - q.x * p.y;
    }
    return 0.5 * a;
}

double polygon_area(const Polygon& p) {
    double a = std::abs(signed_area(p.outer));
    for (const Ring& h : p.holes) a -= std::abs(signed_area(h));
    return a;
}

void orient_polygon(Polygon& p) {
    if (signed_area(p.outer) < 0) std::reverse(p.outer.begin(), p.outer.end());
    for (Ring& h : p.holes)
        if (signed_area(h) > 0) std::reverse(h.begin(), h.end());
}

namespace {
OGRLinearRing to_ogr(const Ring& r) {
    OGRLinearRing ring;
    for (const MapPoint& p : r) ring.addPoint(p.x, p.y);
    if (!r.empty()) ring.addPoint(r.front().x, r.front().y);
    return ring;
}
}  // namespace

void write_polygon_features(const std::string& path, const CrsInfo& crs, const std::vector<FieldDefinition>& fields,
                            const std::vector<Feature>& features, const VectorWriteOptions& options) {
    ensure_gdal_registered();
    GDALDriver* driver = GetGDALDriverManager()->GetDriverByName(options.driver.c_str());
    if (!driver) throw Error(path, "GDAL has no '" + options.driver + "' driver");
    const std::filesystem::path tmp = temporary_path_for(path);
    discard_file(tmp);
    GdalErrorCapture capture;
    auto fail = [&](const std::string& what) {
        const std::string why = capture.suffix();
        discard_file(tmp);
        throw Error(path, what + why);
    };
    GDALDataset* ds = driver->Create(tmp.c_str(), 0, 0, 0, GDT_Unknown, nullptr);
    if (!ds) fail("cannot create vector file");
    OGRSpatialReference srs;
    if (!crs.empty()) srs.importFromWkt(crs.wkt.c_str());
    srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    CPLStringList lco;
    if (options.driver == "GeoJSON") {
        if (options.rfc7946) lco.SetNameValue("RFC7946", "YES");
        if (options.coordinate_precision > 0)
            lco.SetNameValue("COORDINATE_PRECISION", std::to_string(options.coordinate_precision).c_str());
    }
    OGRLayer* layer = ds->CreateLayer(options.layer.c_str(), crs.empty() ? nullptr : &srs, wkbPolygon, lco.List());
    bool ok = layer != nullptr;
    for (const FieldDefinition& f : fields) {
        if (!ok) break;
        OGRFieldDefn defn(f.name.c_str(), f.type == FieldType::integer ? OFTInteger64
                                          : f.type == FieldType::real  ? OFTReal
                                                                       : OFTString);
        ok = layer->CreateField(&defn) == OGRERR_NONE;
    }
    if (ok && options.driver == "GPKG") ok = layer->StartTransaction() == OGRERR_NONE;
    for (const Feature& feature : features) {
        if (!ok) break;
        OGRFeature f(layer->GetLayerDefn());
        for (std::size_t i = 0; i < fields.size() && i < feature.values.size(); ++i) {
            const AttributeValue& v = feature.values[i];
            const int idx = static_cast<int>(i);
            if (std::holds_alternative<int64_t>(v)) f.SetField(idx, static_cast<GIntBig>(std::get<int64_t>(v)));
            else if (std::holds_alternative<double>(v)) f.SetField(idx, std::get<double>(v));
            else if (std::holds_alternative<std::string>(v)) f.SetField(idx, std::get<std::string>(v).c_str());
            else f.SetFieldNull(idx);
        }
        OGRPolygon poly;
        poly.addRingDirectly(new OGRLinearRing(to_ogr(feature.geometry.outer)));
        for (const Ring& h : feature.geometry.holes) poly.addRingDirectly(new OGRLinearRing(to_ogr(h)));
        f.SetGeometry(&poly);
        ok = layer->CreateFeature(&f) == OGRERR_NONE;
    }
    if (ok && options.driver == "GPKG") ok = layer->CommitTransaction() == OGRERR_NONE;
    GDALClose(ds);
    ok = ok && CPLGetLastErrorType() < CE_Failure;
    if (!ok) fail("writing features failed");
    commit_file(tmp, path);
}

}  // namespace cityforge
