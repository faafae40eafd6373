#include "crs/crs.hpp"

#include <GeographicLib/Geodesic.hpp>
#include <GeographicLib/PolygonArea.hpp>
#include <algorithm>
#include <cmath>
#include <cpl_conv.h>
#include <cpl_error.h>
#include <memory>
#include <ogr_spatialref.h>

#include "core/error.hpp"
#include "crs/gdal_util.hpp"

namespace cityforge {
namespace {

std::optional<int> authority_code(const OGRSpatialReference& srs, const char* node) {
    const char* auth = srs.GetAuthorityName(node);
    const char* code = srs.GetAuthorityCode(node);
    if (auth && code && EQUAL(auth, "EPSG")) return std::atoi(code);
    return std::nullopt;
}

// Finds the EPSG code of a CRS that carries none (ESRI WKT, for example) by
// asking PROJ for an equivalent entry with high confidence.
std::optional<int> identify_epsg(const OGRSpatialReference& srs) {
    int n = 0;
    int* confidence = nullptr;
    OGRSpatialReferenceH* matches = srs.FindMatches(nullptr, &n, &confidence);
    std::optional<int> found;
    if (matches && n > 0 && confidence[0] >= 90) {
        const auto* m = OGRSpatialReference::FromHandle(matches[0]);
        const char* auth = m->GetAuthorityName(nullptr);
        const char* code = m->GetAuthorityCode(nullptr);
        if (auth && code && EQUAL(auth, "EPSG")) found = std::atoi(code);
    }
    OSRFreeSRSArray(matches);
    CPLFree(confidence);
    return found;
}

CrsInfo describe(OGRSpatialReference& srs) {
    CrsInfo info;
    const char* wkt_options[] = {"FORMAT=WKT2_2019", nullptr};
    char* wkt = nullptr;
    if (srs.exportToWkt(&wkt, wkt_options) != OGRERR_NONE || !wkt) {
        CPLFree(wkt);
        throw Error("cannot export CRS to WKT");
    }
    info.wkt = wkt;
    CPLFree(wkt);
    info.name = srs.GetName() ? srs.GetName() : "";
    info.geographic = srs.IsGeographic();
    const char* unit_name = nullptr;
    if (!info.geographic) {
        info.linear_unit_m = srs.GetLinearUnits(&unit_name);
        info.linear_unit_name = unit_name ? unit_name : "unknown";
    } else {
        info.linear_unit_m = 0.0;
        info.linear_unit_name = "degree";
    }

    info.z_unit_m = info.geographic ? 1.0 : info.linear_unit_m;
    if (srs.IsCompound()) {
        const double vu = srs.GetTargetLinearUnits("VERT_CS");
        if (vu > 0.0) info.z_unit_m = vu;
        info.epsg = authority_code(srs, nullptr);
        if (!info.epsg) info.epsg = identify_epsg(srs);  // e.g. 28992 + 5709 is EPSG:7415
        OGRSpatialReference horizontal(srs);
        horizontal.StripVertical();
        info.horizontal_epsg = authority_code(horizontal, nullptr);
        if (!info.horizontal_epsg) info.horizontal_epsg = identify_epsg(horizontal);
        info.vertical_epsg = authority_code(srs, "VERT_CS");
        const char* vname = srs.GetAttrValue("VERT_CS");
        info.vertical_name = vname ? vname : "";
    } else if (srs.IsVertical()) {
        info.epsg = authority_code(srs, nullptr);
        info.vertical_epsg = info.epsg;
        info.vertical_name = info.name;
    } else {
        info.epsg = authority_code(srs, nullptr);
        if (!info.epsg) info.epsg = identify_epsg(srs);
        info.horizontal_epsg = info.epsg;
    }
    return info;
}

}  // namespace

std::string CrsInfo::label() const {
    if (epsg && !vertical_epsg) return "EPSG:" + std::to_string(*epsg);
    if (horizontal_epsg && vertical_epsg)
        return "EPSG:" + std::to_string(*horizontal_epsg) + "+" + std::to_string(*vertical_epsg);
    if (horizontal_epsg) return "EPSG:" + std::to_string(*horizontal_epsg);
    return name.empty() ? std::string("unknown CRS") : name;
}

std::string CrsInfo::ogc_urn() const {
    if (horizontal_epsg && vertical_epsg)
        return "urn:ogc:def:crs,crs:EPSG::" + std::to_string(*horizontal_epsg) + ",crs:EPSG::" +
               std::to_string(*vertical_epsg);
    if (horizontal_epsg) return "urn:ogc:def:crs:EPSG::" + std::to_string(*horizontal_epsg);
    return {};
}

CrsInfo crs_from_user_input(const std::string& text, const std::string& subject) {
    GdalErrorCapture capture;
    OGRSpatialReference srs;
    if (text.empty() || srs.SetFromUserInput(text.c_str()) != OGRERR_NONE)
        throw Error(subject, "cannot understand CRS '" + text + "'" + capture.suffix());
    return describe(srs);
}

CrsInfo crs_from_ogr(const OGRSpatialReference* srs, const std::string& subject) {
    if (!srs) return {};
    char* wkt = nullptr;
    const char* options[] = {"FORMAT=WKT2_2019", nullptr};
    srs->exportToWkt(&wkt, options);
    const std::string text = wkt ? wkt : "";
    CPLFree(wkt);
    return crs_from_wkt(text, subject);
}

CrsInfo crs_from_wkt(const std::string& wkt, const std::string& subject) {
    if (wkt.empty()) return {};
    GdalErrorCapture capture;
    OGRSpatialReference srs;
    if (srs.importFromWkt(wkt.c_str()) != OGRERR_NONE)
        throw Error(subject, "invalid CRS WKT" + capture.suffix());
    return describe(srs);
}

GroundSampleDistance ground_sample_distance(const CrsInfo& crs, const GeoTransform& t, int width, int height) {
    if (!crs.geographic) {
        const double unit = crs.empty() ? 1.0 : crs.linear_unit_m;
        return {std::abs(t.pixel_width) * unit, std::abs(t.pixel_height) * unit};
    }
    // Geographic: measure one pixel step at the raster centre on the ellipsoid.
    // Axis order follows GDAL's traditional GIS order (x = longitude).
    const MapPoint c = t.pixel_to_map({width / 2.0, height / 2.0});
    const auto& geod = GeographicLib::Geodesic::WGS84();
    double dx = 0.0, dy = 0.0;
    geod.Inverse(c.y, c.x, c.y, c.x + t.pixel_width, dx);
    geod.Inverse(c.y, c.x, c.y + t.pixel_height, c.x, dy);
    return {std::abs(dx), std::abs(dy)};
}

bool same_horizontal_crs(const CrsInfo& a, const CrsInfo& b) {
    if (a.empty() || b.empty()) return a.empty() && b.empty();
    OGRSpatialReference sa, sb;
    sa.importFromWkt(a.wkt.c_str());
    sb.importFromWkt(b.wkt.c_str());
    if (sa.IsCompound()) sa.StripVertical();
    if (sb.IsCompound()) sb.StripVertical();
    const char* options[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES", "CRITERION=EQUIVALENT_EXCEPT_AXIS_ORDER_GEOGCRS", nullptr};
    return sa.IsSame(&sb, options);
}

CrsInfo combine_with_vertical(const CrsInfo& horizontal, const CrsInfo& vertical) {
    if (horizontal.vertical_epsg || !horizontal.horizontal_epsg || !vertical.vertical_epsg) return horizontal;
    return crs_from_user_input("EPSG:" + std::to_string(*horizontal.horizontal_epsg) + "+" + std::to_string(*vertical.vertical_epsg),
                               "combined CRS");
}

void transform_points(const CrsInfo& from, const CrsInfo& to, std::vector<double>& x, std::vector<double>& y,
                      std::vector<double>& z, const std::string& subject) {
    GdalErrorCapture capture;
    OGRSpatialReference a, b;
    a.importFromWkt(from.wkt.c_str());
    b.importFromWkt(to.wkt.c_str());
    a.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    b.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    std::unique_ptr<OGRCoordinateTransformation> ct(OGRCreateCoordinateTransformation(&a, &b));
    if (!ct) throw Error(subject, "no transformation from " + from.label() + " to " + to.label() + capture.suffix());
    const std::size_t chunk = 1 << 16;
    std::vector<int> ok(chunk);
    for (std::size_t s0 = 0; s0 < x.size(); s0 += chunk) {
        const std::size_t n = std::min(chunk, x.size() - s0);
        if (!ct->Transform(static_cast<int>(n), x.data() + s0, y.data() + s0, z.data() + s0, nullptr, ok.data()) ||
            std::find(ok.begin(), ok.begin() + static_cast<std::ptrdiff_t>(n), 0) != ok.begin() + static_cast<std::ptrdiff_t>(n))
            throw Error(subject, "reprojection from " + from.label() + " to " + to.label() + " failed for some points" + capture.suffix());
    }
}

double geodesic_area_m2(const std::vector<std::vector<MapPoint>>& rings, const CrsInfo& crs) {
    if (rings.empty()) return 0.0;
    const CrsInfo wgs84 = crs_from_user_input("EPSG:4326", "geodesic area");
    double total = 0.0;
    for (std::size_t r = 0; r < rings.size(); ++r) {
        std::vector<double> x, y, z;
        for (const MapPoint& p : rings[r]) x.push_back(p.x), y.push_back(p.y), z.push_back(0.0);
        if (!crs.geographic) transform_points(crs, wgs84, x, y, z, "geodesic area");
        GeographicLib::PolygonArea poly(GeographicLib::Geodesic::WGS84());
        for (std::size_t i = 0; i < x.size(); ++i) poly.AddPoint(y[i], x[i]);  // lat, lon
        double perimeter = 0.0, area = 0.0;
        poly.Compute(false, true, perimeter, area);
        total += r == 0 ? std::abs(area) : -std::abs(area);
    }
    return total;
}

bool same_crs(const CrsInfo& a, const CrsInfo& b) {
    if (a.empty() || b.empty()) return a.empty() && b.empty();
    OGRSpatialReference sa, sb;
    sa.importFromWkt(a.wkt.c_str());
    sb.importFromWkt(b.wkt.c_str());
    const char* options[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES", "CRITERION=EQUIVALENT_EXCEPT_AXIS_ORDER_GEOGCRS", nullptr};
    return sa.IsSame(&sb, options);
}

}  // namespace cityforge
