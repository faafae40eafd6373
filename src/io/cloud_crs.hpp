#pragma once
// The one CRS resolution for point clouds, used by every command (info,
// heights, footprints, roofs, rasterize, run, audits): the user's CRS, the
// LAS WKT records and GeoTIFF keys, in one documented order of precedence.
#include <string>
#include <vector>

#include "cloud/cloud_reader.hpp"
#include "crs/crs.hpp"

namespace cityforge {

/// A cloud's CRS and where it came from.
struct CloudCrs {
    CrsInfo crs;                        ///< empty when neither the file nor the user gives one
    std::string source;                 ///< e.g. "--cloud-crs", "WKT VLR", "GeoTIFF keys"; empty = none
    std::vector<std::string> warnings;  ///< disagreements and unreadable records (also logged)
};

/// Resolves the CRS of the cloud `reader` opened. Order of precedence:
///  1. `user_crs` (anything crs_from_user_input takes; `user_subject` names it,
///     e.g. "--cloud-crs"): a warning when the file's own CRS differs;
///  2. the OGC WKT of the LASF_Projection 2112 VLR, then of the 2112 EVLR
///     (LAS 1.4), then of libLAS's older "liblas" 2112 VLR;
///  3. the GeoTIFF keys (LASF_Projection 34735 with 34736/34737: projected,
///     geographic, vertical and user-defined CRSs, units), the LAS 1.0-1.3
///     way. WKT comes first whatever the global-encoding WKT bit says: it is
///     complete, where keys are lossy and often written with unit mistakes.
/// The first readable record wins; a record that cannot be parsed is skipped
/// with a warning. Records that give different horizontal CRSs (or different
/// vertical ones) are named in a warning saying which is used. When the
/// chosen CRS has no vertical part and a later record has one, it is added.
/// PLY and XYZ files carry no CRS: only `user_crs`.
CloudCrs resolve_cloud_crs(const CloudReader& reader, const std::string& user_crs,
                           const std::string& user_subject = "--cloud-crs");

/// Opens `path` and resolves its CRS as above.
CloudCrs resolve_cloud_crs(const std::string& path, const std::string& user_crs,
                           const std::string& user_subject = "--cloud-crs");

/// As resolve_cloud_crs, but a cloud without any CRS is an Error naming the
/// file and `user_subject`; a geographic CRS too (heights need metres).
CrsInfo require_cloud_crs(const std::string& path, const std::string& user_crs,
                          const std::string& user_subject = "--cloud-crs");

}  // namespace cityforge
