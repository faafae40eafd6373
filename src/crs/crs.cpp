#include "crs/crs.hpp"

#include <GeographicLib/Geodesic.hpp>
#include <GeographicLib/PolygonArea.hpp>
#include <algorithm>
#include <cmath>
#include <cpl_conv.h>
#include <cpl_error.h>
#include <atomic>
#include <cstring>
#include <gdal_priv.h>
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
        // A compound CRS known by its code whose parts carry none (GeoPackage's WKT2): the parts of the registered one.
        if (info.epsg && (!info.vertical_epsg || !info.horizontal_epsg)) {
            OGRSpatialReference registered;
            if (registered.importFromEPSG(*info.epsg) == OGRERR_NONE && registered.IsCompound()) {
                if (!info.vertical_epsg) info.vertical_epsg = authority_code(registered, "VERT_CS");
                if (!info.horizontal_epsg) {
                    registered.StripVertical();
                    info.horizontal_epsg = authority_code(registered, nullptr);
                }
            }
        }
        // Parts with codes but no code for the whole (GeoTIFF keys 28992 + 5709, a
        // compound whose name PROJ does not match): the registered compound of
        // these parts when PROJ knows one (EPSG:7415), with the same units.
        if (!info.epsg && info.horizontal_epsg && info.vertical_epsg) {
            GdalErrorCapture capture;
            OGRSpatialReference parts;
            const std::string text = "EPSG:" + std::to_string(*info.horizontal_epsg) + "+" + std::to_string(*info.vertical_epsg);
            if (parts.SetFromUserInput(text.c_str()) == OGRERR_NONE) {
                OGRSpatialReference registered;
                if (const auto code = identify_epsg(parts); code && registered.importFromEPSG(*code) == OGRERR_NONE) {
                    CrsInfo whole = describe(registered);
                    if (whole.epsg && whole.horizontal_epsg == info.horizontal_epsg && whole.vertical_epsg == info.vertical_epsg &&
                        whole.linear_unit_m == info.linear_unit_m && whole.z_unit_m == info.z_unit_m)
                        return whole;
                }
            }
        }
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

std::string z_crs_label(const CrsInfo& crs) {
    if (crs.vertical_epsg) return "EPSG:" + std::to_string(*crs.vertical_epsg);
    if (!crs.vertical_name.empty()) return crs.vertical_name;
    if (crs.empty()) return "unknown";
    if (crs.geographic || crs.z_unit_m == 1.0) return "unknown (metre)";
    return "unknown (" + (crs.z_unit_m == crs.linear_unit_m ? crs.linear_unit_name : std::to_string(crs.z_unit_m) + " m") + ")";
}

std::string proj_string(const CrsInfo& crs) {
    if (crs.empty()) return {};
    GdalErrorCapture capture;
    OGRSpatialReference srs;
    if (srs.importFromWkt(crs.wkt.c_str()) != OGRERR_NONE) return {};
    char* text = nullptr;
    std::string out;
    if (srs.exportToProj4(&text) == OGRERR_NONE && text) out = text;
    CPLFree(text);
    while (!out.empty() && out.back() == ' ') out.pop_back();
    return out;
}

CrsInfo crs_from_user_input(const std::string& text, const std::string& subject) {
    GdalErrorCapture capture;
    OGRSpatialReference srs;
    if (text.empty() || srs.SetFromUserInput(text.c_str()) != OGRERR_NONE)
        throw Error(subject, "cannot understand CRS '" + text + "'" + capture.suffix());
    return describe(srs);
}

namespace {

// A classic little-endian TIFF of one 8-bit pixel carrying the GeoTIFF tags,
// so that GDAL's GeoTIFF reader (libgeotiff + its GeoKey -> CRS code) reads
// the keys exactly as it reads a GeoTIFF's.
std::vector<unsigned char> geokey_tiff(const std::vector<uint16_t>& directory, const std::vector<double>& doubles,
                                       const std::string& ascii) {
    struct Entry {
        uint16_t tag, type;
        uint32_t count;
        std::vector<unsigned char> data;  // payload (inline when <= 4 bytes)
    };
    auto shorts = [](std::initializer_list<uint16_t> v) {
        std::vector<unsigned char> d(v.size() * 2);
        std::size_t i = 0;
        for (uint16_t x : v) std::memcpy(d.data() + 2 * i++, &x, 2);
        return d;
    };
    auto raw = [](const void* p, std::size_t n) {
        std::vector<unsigned char> d(n);
        if (n) std::memcpy(d.data(), p, n);
        return d;
    };
    const double scale[3] = {1.0, 1.0, 0.0};
    const double tie[6] = {0.0, 0.0, 0.0, 0.0, 1.0, 0.0};
    std::string text = ascii;
    if (text.empty() || text.back() != '\0') text.push_back('\0');
    std::vector<Entry> entries = {
        {256, 3, 1, shorts({1})},        {257, 3, 1, shorts({1})},  {258, 3, 1, shorts({8})},
        {259, 3, 1, shorts({1})},        {262, 3, 1, shorts({1})},  {273, 4, 1, {}},  // strip offset: patched below
        {277, 3, 1, shorts({1})},        {278, 3, 1, shorts({1})},  {279, 4, 1, raw("\x01\0\0\0", 4)},
        {33550, 12, 3, raw(scale, sizeof scale)}, {33922, 12, 6, raw(tie, sizeof tie)},
        {34735, 3, static_cast<uint32_t>(directory.size()), raw(directory.data(), directory.size() * 2)},
    };
    if (!doubles.empty()) entries.push_back({34736, 12, static_cast<uint32_t>(doubles.size()), raw(doubles.data(), doubles.size() * 8)});
    entries.push_back({34737, 2, static_cast<uint32_t>(text.size()), raw(text.data(), text.size())});
    const uint32_t ifd = 8;
    uint32_t data_pos = ifd + 2 + static_cast<uint32_t>(entries.size()) * 12 + 4;
    std::vector<unsigned char> out(data_pos, 0);
    auto put16 = [&](std::size_t at, uint16_t v) { std::memcpy(out.data() + at, &v, 2); };
    auto put32 = [&](std::size_t at, uint32_t v) { std::memcpy(out.data() + at, &v, 4); };
    out[0] = 'I', out[1] = 'I';
    put16(2, 42);
    put32(4, ifd);
    put16(ifd, static_cast<uint16_t>(entries.size()));
    for (std::size_t i = 0; i < entries.size(); ++i) {
        const std::size_t at = ifd + 2 + i * 12;
        Entry& e = entries[i];
        put16(at, e.tag), put16(at + 2, e.type), put32(at + 4, e.count);
        if (e.tag == 273) continue;
        if (e.data.size() <= 4) {
            std::memcpy(out.data() + at + 8, e.data.data(), e.data.size());
        } else {
            if (out.size() % 2) out.push_back(0);  // word alignment
            put32(at + 8, static_cast<uint32_t>(out.size()));
            out.insert(out.end(), e.data.begin(), e.data.end());
        }
    }
    // The pixel, and the strip offset pointing at it.
    const std::size_t strip_entry = ifd + 2 + 5 * 12;
    put32(strip_entry + 8, static_cast<uint32_t>(out.size()));
    out.push_back(0);
    return out;
}

}  // namespace

CrsInfo crs_from_geokeys(const std::vector<uint16_t>& directory, const std::vector<double>& doubles, const std::string& ascii,
                         const std::string& subject) {
    if (directory.empty()) return {};
    if (directory.size() < 4 || directory.size() < 4 + 4 * static_cast<std::size_t>(directory[3]))
        throw Error(subject, "malformed GeoTIFF key directory (fewer entries than announced)");
    ensure_gdal_registered();
    GdalErrorCapture capture;
    static std::atomic<unsigned> counter{0};
    const std::string name = "/vsimem/cityforge_geokeys_" + std::to_string(counter++) + ".tif";
    std::vector<unsigned char> tiff = geokey_tiff(directory, doubles, ascii);
    VSIFCloseL(VSIFileFromMemBuffer(name.c_str(), tiff.data(), static_cast<vsi_l_offset>(tiff.size()), FALSE));
    // A vertical key (4096) makes a compound CRS, as in gdalinfo with this option.
    CPLSetThreadLocalConfigOption("GTIFF_REPORT_COMPD_CS", "YES");
    std::unique_ptr<GDALDataset> ds(GDALDataset::Open(name.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
    CrsInfo info;
    std::string problem;
    if (!ds) problem = "GeoTIFF keys cannot be read" + capture.suffix();
    else if (const OGRSpatialReference* srs = ds->GetSpatialRef()) {
        OGRSpatialReference copy(*srs);
        info = describe(copy);
    }
    ds.reset();
    CPLSetThreadLocalConfigOption("GTIFF_REPORT_COMPD_CS", nullptr);
    VSIUnlink(name.c_str());
    if (!problem.empty()) throw Error(subject, problem);
    return info;
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

MapPoint to_lon_lat(const CrsInfo& crs, const MapPoint& p) {
    if (crs.geographic) {
        // Our CrsInfo keeps GDAL's traditional GIS order for geographic CRSs: x = longitude.
        return p;
    }
    const CrsInfo wgs84 = crs_from_user_input("EPSG:4326", "WGS 84");
    std::vector<double> x{p.x}, y{p.y}, z{0.0};
    transform_points(crs, wgs84, x, y, z, crs.label());
    return {x[0], y[0]};
}

double ground_scale_factor(const CrsInfo& crs, const GeoTransform& t, int width, int height) {
    if (crs.geographic) return 0.0;
    if (crs.empty()) return 1.0;
    const double unit = crs.linear_unit_m;
    const MapPoint c = t.pixel_to_map({width / 2.0, height / 2.0});
    const MapPoint cx = t.pixel_to_map({width / 2.0 + 1.0, height / 2.0});
    const MapPoint cy = t.pixel_to_map({width / 2.0, height / 2.0 + 1.0});
    double kx = 1.0, ky = 1.0;
    try {
        const MapPoint g = to_lon_lat(crs, c), gx = to_lon_lat(crs, cx), gy = to_lon_lat(crs, cy);
        const auto& geod = GeographicLib::Geodesic::WGS84();
        double dx = 0.0, dy = 0.0;
        geod.Inverse(g.y, g.x, gx.y, gx.x, dx);
        geod.Inverse(g.y, g.x, gy.y, gy.x, dy);
        kx = dx / (std::abs(t.pixel_width) * unit);
        ky = dy / (std::abs(t.pixel_height) * unit);
    } catch (const Error&) {
        return 1.0;  // no transformation to WGS 84 known: nominal units
    }
    const double k = 0.5 * (kx + ky);
    if (!std::isfinite(k) || k <= 0.0 || std::abs(k - 1.0) < 0.002) return 1.0;
    return k;
}

double ground_metres_per_unit(const CrsInfo& crs, const GeoTransform& t, int width, int height) {
    if (crs.geographic) return 0.0;
    return (crs.empty() ? 1.0 : crs.linear_unit_m) * ground_scale_factor(crs, t, width, height);
}

double ground_scale_factor_at(const CrsInfo& crs, const Extent& e) {
    if (crs.geographic) return 0.0;
    if (!(e.min_x <= e.max_x && e.min_y <= e.max_y)) return 1.0;
    const double cx = 0.5 * (e.min_x + e.max_x), cy = 0.5 * (e.min_y + e.max_y);
    return ground_scale_factor(crs, GeoTransform{cx - 0.5, 1.0, cy + 0.5, -1.0}, 1, 1);
}

double ground_metres_per_unit_at(const CrsInfo& crs, const Extent& e) {
    if (crs.geographic) return 0.0;
    return (crs.empty() ? 1.0 : crs.linear_unit_m) * ground_scale_factor_at(crs, e);
}

CrsInfo utm_crs_for(const CrsInfo& crs, const MapPoint& lon_lat) {
    const int zone = std::clamp(static_cast<int>(std::floor((lon_lat.x + 180.0) / 6.0)) + 1, 1, 60);
    const bool north = lon_lat.y >= 0.0;
    // On the CRS's datum when PROJ knows a UTM CRS for it, else WGS 84.
    if (!crs.empty()) {
        GdalErrorCapture capture;
        OGRSpatialReference srs;
        if (srs.importFromWkt(crs.wkt.c_str()) == OGRERR_NONE) {
            OGRSpatialReference utm;
            utm.CopyGeogCSFrom(&srs);
            const char* datum = utm.GetAttrValue("DATUM");
            const bool wgs84 = datum && (EQUAL(datum, "WGS_1984") || EQUAL(datum, "World Geodetic System 1984"));
            if (!wgs84 && utm.SetUTM(zone, north ? TRUE : FALSE) == OGRERR_NONE) {
                CrsInfo info = describe(utm);
                if (info.epsg) return info;
            }
        }
    }
    return crs_from_user_input("EPSG:" + std::to_string((north ? 32600 : 32700) + zone), "UTM zone");
}

GroundSampleDistance ground_sample_distance(const CrsInfo& crs, const GeoTransform& t, int width, int height) {
    if (!crs.geographic) {
        const double unit = ground_metres_per_unit(crs, t, width, height);
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

std::string non_map_crs_kind(const CrsInfo& crs) {
    if (crs.empty()) return {};
    GdalErrorCapture capture;
    OGRSpatialReference srs;
    if (srs.importFromWkt(crs.wkt.c_str()) != OGRERR_NONE) return {};
    if (srs.IsCompound()) srs.StripVertical();
    if (srs.IsGeocentric()) return "geocentric";
    if (srs.IsLocal()) return "local";
    return {};
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
    if (horizontal.empty() || horizontal.vertical_epsg || !horizontal.vertical_name.empty() || !vertical.vertical_epsg) return horizontal;
    if (horizontal.horizontal_epsg)
        return crs_from_user_input("EPSG:" + std::to_string(*horizontal.horizontal_epsg) + "+" + std::to_string(*vertical.vertical_epsg),
                                   "combined CRS");
    // A horizontal CRS without an EPSG code (a custom WKT, e.g. a GeoTIFF's
    // user-defined projection): the compound of its WKT and the vertical CRS.
    GdalErrorCapture capture;
    OGRSpatialReference h, v, compound;
    if (h.importFromWkt(horizontal.wkt.c_str()) != OGRERR_NONE || v.importFromEPSG(*vertical.vertical_epsg) != OGRERR_NONE) return horizontal;
    const std::string name = horizontal.name + " + " + (v.GetName() ? v.GetName() : "EPSG:" + std::to_string(*vertical.vertical_epsg));
    if (compound.SetCompoundCS(name.c_str(), &h, &v) != OGRERR_NONE) return horizontal;
    return describe(compound);
}

namespace {
// What the heights of `crs` refer to: its vertical CRS ("EPSG:5709" or its
// name) when compound, "ellipsoidal heights (NAME)" for a geographic 3D or
// geocentric CRS, empty for a 2-D CRS (heights of no stated reference).
std::string height_reference(const CrsInfo& crs, const OGRSpatialReference& srs) {
    if (srs.IsCompound()) {
        if (crs.vertical_epsg) return "EPSG:" + std::to_string(*crs.vertical_epsg);
        return crs.vertical_name.empty() ? std::string("a vertical CRS") : crs.vertical_name;
    }
    if (srs.IsGeocentric() || (srs.IsGeographic() && srs.GetAxesCount() == 3) || (srs.IsProjected() && srs.GetAxesCount() == 3)) {
        const char* name = srs.GetName();
        return std::string("ellipsoidal heights (") + (name ? name : "unknown datum") + ")";
    }
    return {};
}
}  // namespace

void transform_points(const CrsInfo& from, const CrsInfo& to, std::vector<double>& x, std::vector<double>& y,
                      std::vector<double>& z, const std::string& subject) {
    GdalErrorCapture capture;
    OGRSpatialReference a, b;
    a.importFromWkt(from.wkt.c_str());
    b.importFromWkt(to.wkt.c_str());
    a.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    b.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    // First without PROJ's "ballpark" operations: a ballpark vertical
    // transformation is a no-op (PROJ 9.1 picks it silently when the geoid
    // grid is missing), which would label unchanged heights with the new
    // datum. A ballpark is accepted only when the heights are not at stake.
    OGRCoordinateTransformationOptions strict;
    strict.SetBallparkAllowed(false);
    std::unique_ptr<OGRCoordinateTransformation> ct;
    {
        GdalErrorCapture quiet;
        ct.reset(OGRCreateCoordinateTransformation(&a, &b, strict));
    }
    if (!ct) {
        CPLErrorReset();  // the strict attempt's message is not this call's error
        ct.reset(OGRCreateCoordinateTransformation(&a, &b));
        if (!ct) throw Error(subject, "no transformation from " + from.label() + " to " + to.label() + capture.suffix());
        const std::string from_z = height_reference(from, a), to_z = height_reference(to, b);
        if (!from_z.empty() && !to_z.empty() && from_z != to_z)
            throw Error(subject, "heights cannot be transformed from " + from_z + " to " + to_z +
                                     ": PROJ has no grid for it on this machine and would leave them unchanged (install the grid, "
                                     "e.g. with projsync, or give both the same vertical CRS)");
    }
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
