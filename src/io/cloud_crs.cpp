#include "io/cloud_crs.hpp"

#include <mutex>
#include <set>

#include "core/error.hpp"
#include "core/log.hpp"

namespace cityforge {
namespace {

// Every command resolves a cloud's CRS more than once (tiles, merge): each
// warning is printed once per process.
void warn_once(const std::string& message) {
    static std::mutex mutex;
    static std::set<std::string> seen;
    std::lock_guard<std::mutex> lock(mutex);
    if (seen.insert(message).second) log::warning(message);
}

struct Candidate {
    std::string source;
    CrsInfo crs;
};

// Same CRS for the purpose of a disagreement warning: EPSG codes when both
// are identified, otherwise PROJ's equivalence of the horizontal parts.
bool same_horizontal(const CrsInfo& a, const CrsInfo& b) {
    if (a.horizontal_epsg && b.horizontal_epsg) return *a.horizontal_epsg == *b.horizontal_epsg;
    return same_horizontal_crs(a, b);
}

// The label, and the PROJ definition when the label alone names nothing.
std::string describe_crs(const CrsInfo& c) {
    if (c.epsg || c.horizontal_epsg) return c.label();
    const std::string proj = proj_string(c);
    return c.label() + (proj.empty() ? "" : " (" + proj + ")");
}

bool vertical_disagrees(const CrsInfo& a, const CrsInfo& b) {
    if (a.vertical_epsg && b.vertical_epsg) return *a.vertical_epsg != *b.vertical_epsg;
    if (!a.vertical_name.empty() && !b.vertical_name.empty()) return a.vertical_name != b.vertical_name;
    return false;
}

}  // namespace

CloudCrs resolve_cloud_crs(const CloudReader& reader, const std::string& user_crs, const std::string& user_subject) {
    const std::string& path = reader.path();
    const LasCrsRecords& r = reader.crs_records();
    CloudCrs out;
    auto warn = [&](const std::string& message) {
        out.warnings.push_back(message);
        warn_once(message);
    };
    // The file's records in order of precedence, each parsed on its own.
    std::vector<Candidate> file;
    // A record giving no map CRS (geocentric X/Y/Z, or a local CRS such as
    // keys with a user-defined ProjectedCSTypeGeoKey 65535 and no parameters)
    // georeferences nothing we can place: ignored with a warning.
    auto add = [&](const std::string& source, CrsInfo c) {
        if (c.empty()) return;
        const std::string kind = non_map_crs_kind(c);
        if (!kind.empty()) {
            warn(path + ": " + source + " ignored: a " + kind + " CRS (" + c.label() + "), not a projected or geographic one");
            return;
        }
        file.push_back({source, std::move(c)});
    };
    auto add_wkt = [&](const std::string& source, const std::string& wkt) {
        if (wkt.empty()) return;
        try {
            add(source, crs_from_wkt(wkt, path));
        } catch (const Error& e) {
            warn(path + ": " + source + " ignored: " + e.what());
        }
    };
    auto add_geokeys = [&]() {
        if (r.geokey_directory.empty()) return;
        try {
            add("GeoTIFF keys", crs_from_geokeys(r.geokey_directory, r.geo_double_params, r.geo_ascii_params, path));
        } catch (const Error& e) {
            warn(path + ": GeoTIFF keys ignored: " + e.what());
        }
    };
    // WKT first: it is complete (datum, units, vertical part), where GeoTIFF
    // keys are lossy and often written with unit mistakes (autzen_thin_srs.las
    // has a false easting in metres under a foot unit: 278 km off).
    add_wkt("WKT VLR", r.wkt);
    add_wkt("WKT EVLR", r.evlr_wkt);
    add_wkt("libLAS WKT VLR", r.liblas_wkt);
    add_geokeys();

    if (!user_crs.empty()) {
        out.crs = crs_from_user_input(user_crs, user_subject);
        out.source = user_subject;
        if (!file.empty() && (!same_horizontal(out.crs, file.front().crs) || vertical_disagrees(out.crs, file.front().crs)))
            warn(path + ": " + user_subject + " " + describe_crs(out.crs) + " overrides the file's CRS " + describe_crs(file.front().crs) +
                 " (" + file.front().source + ")");
        return out;
    }
    if (file.empty()) return out;
    out.crs = file.front().crs;
    out.source = file.front().source;
    for (std::size_t i = 1; i < file.size(); ++i) {
        const Candidate& c = file[i];
        if (!same_horizontal(out.crs, c.crs) || vertical_disagrees(out.crs, c.crs))
            warn(path + ": the " + out.source + " says " + describe_crs(out.crs) + " but the " + c.source + " says " + describe_crs(c.crs) +
                 "; using the " + out.source);
    }
    if (out.crs.vertical_name.empty() && !out.crs.geographic) {
        for (std::size_t i = 1; i < file.size(); ++i) {
            const Candidate& c = file[i];
            if (c.crs.vertical_epsg && same_horizontal(out.crs, c.crs)) {
                const CrsInfo combined = combine_with_vertical(out.crs, c.crs);
                if (combined.vertical_epsg) {
                    log::info(path + ": vertical CRS " + c.crs.vertical_name + " from the " + c.source);
                    out.crs = combined;
                    out.source += " + " + c.source;
                }
                break;
            }
        }
    }
    return out;
}

CloudCrs resolve_cloud_crs(const std::string& path, const std::string& user_crs, const std::string& user_subject) {
    return resolve_cloud_crs(CloudReader(path), user_crs, user_subject);
}

CrsInfo require_cloud_crs(const std::string& path, const std::string& user_crs, const std::string& user_subject) {
    CloudCrs c = resolve_cloud_crs(path, user_crs, user_subject);
    if (c.crs.empty())
        throw Error(path, "point cloud has no CRS (no usable WKT or GeoTIFF key record); give it with " + user_subject + " (e.g. EPSG:7415)");
    if (c.crs.geographic) throw Error(path, "point cloud is in a geographic CRS (" + c.crs.label() + "); a projected CRS is needed");
    if (const std::string kind = non_map_crs_kind(c.crs); !kind.empty())
        throw Error(user_subject, "is a " + kind + " CRS (" + c.crs.label() + "); a projected CRS is needed");
    return std::move(c.crs);
}

}  // namespace cityforge
