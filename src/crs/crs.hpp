#pragma once
// Coordinate reference systems: parsing, identification (EPSG codes of the
// horizontal and vertical parts), units and ground sample distance in metres.
// Wraps GDAL/OGR + PROJ; the algorithm modules never include this header.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/geo_transform.hpp"

class OGRSpatialReference;

namespace cityforge {

/// What we know of a CRS. `wkt` is empty when the data carried no CRS.
struct CrsInfo {
    std::string wkt;                       ///< WKT2_2019 (empty = unknown CRS)
    std::string name;                      ///< e.g. "WGS 84 / UTM zone 50N"
    std::optional<int> horizontal_epsg;    ///< EPSG of the horizontal (projected/geographic) part
    std::optional<int> vertical_epsg;      ///< EPSG of the vertical part, when compound
    std::optional<int> epsg;               ///< EPSG of the whole CRS (e.g. 7415 for RD New + NAP)
    std::string vertical_name;             ///< e.g. "NAP height"; empty if none
    bool geographic = false;               ///< axes are degrees of latitude/longitude
    double linear_unit_m = 1.0;            ///< metres per horizontal CRS unit (0.3048 for int. feet)
    std::string linear_unit_name = "metre";
    double z_unit_m = 1.0;                 ///< metres per z unit (vertical CRS unit, else the linear unit)

    bool empty() const { return wkt.empty(); }
    /// "EPSG:32650", "EPSG:28992+5709" or the CRS name when no code is known.
    std::string label() const;
    /// OGC URN for GML srsName: "urn:ogc:def:crs:EPSG::32650" or, with a vertical
    /// part, "urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709". Empty if no EPSG code.
    std::string ogc_urn() const;
};

/// The PROJ string of a CRS ("+proj=lcc +lat_1=43 ... +units=ft"), for
/// messages that must tell two unnamed CRSs apart; empty when PROJ has none.
std::string proj_string(const CrsInfo& crs);

/// What kind of CRS `crs` is when it does not georeference map coordinates:
/// "geocentric" (ECEF X/Y/Z) or "local" (an engineering CRS, e.g. what GDAL
/// makes of a user-defined ProjectedCSTypeGeoKey 65535 without parameters).
/// Empty for a projected or geographic (lon/lat) CRS, compound or not.
std::string non_map_crs_kind(const CrsInfo& crs);

/// What the z values of data in `crs` are: "EPSG:5709" (the vertical CRS's
/// code), else the vertical CRS's name, else "unknown (UNIT)" with the unit
/// of z ("unknown (foot)" for Autzen): never the horizontal CRS's name.
std::string z_crs_label(const CrsInfo& crs);

/// Parses anything GDAL's SetFromUserInput accepts ("EPSG:7415", WKT, PROJ
/// string). `subject` names where the text came from, for the error message.
CrsInfo crs_from_user_input(const std::string& text, const std::string& subject);

/// Parses a WKT (1 or 2, ESRI flavour included). Empty input gives an empty CrsInfo.
CrsInfo crs_from_wkt(const std::string& wkt, const std::string& subject);

/// Interprets GeoTIFF keys (the GeoKeyDirectory as raw unsigned shorts, the
/// GeoDoubleParams and GeoAsciiParams they point into), as stored in a
/// GeoTIFF or in a LAS file's LASF_Projection 34735/34736/34737 records:
/// EPSG codes of projected (3072), geographic (2048) and vertical (4096)
/// CRSs, user-defined (32767) CRSs built from their projection, datum and
/// parameter keys, and linear / vertical units (3076, 4099). GDAL's GeoTIFF
/// reader (libgeotiff) does the interpretation, so the result is what
/// gdalinfo reports for a GeoTIFF with these keys; a vertical key gives a
/// compound CRS. Empty result when the keys hold no CRS; throws Error naming
/// `subject` when they are malformed.
CrsInfo crs_from_geokeys(const std::vector<uint16_t>& directory, const std::vector<double>& doubles,
                         const std::string& ascii, const std::string& subject);

/// Describes an OGR spatial reference (e.g. a layer's or a dataset's);
/// nullptr gives an empty CrsInfo.
CrsInfo crs_from_ogr(const OGRSpatialReference* srs, const std::string& subject);

/// Ground sample distance in metres of a pixel at the raster's centre, along
/// x and y. Projected CRSs scale by the linear unit (feet included);
/// geographic CRSs use geodesic distances on the ellipsoid (GeographicLib).
struct GroundSampleDistance {
    double x_m = 0.0;
    double y_m = 0.0;
};
/// Projected CRSs with strong scale distortion (Web Mercator: 1/cos(latitude))
/// give true ground distances through ground_scale_factor.
GroundSampleDistance ground_sample_distance(const CrsInfo& crs, const GeoTransform& transform, int width,
                                            int height);

/// Scale of a projected CRS at the raster centre: ground metres per metre of
/// the CRS's grid, measured geodesically over one pixel step along x and y
/// (1/cos(latitude) in Web Mercator, 1.13 at 27.6 deg). Exactly 1.0 when
/// within 0.2 % of 1 (UTM, national grids: their nominal GSD is kept) and
/// for a CRS without a horizontal part; 0 for a geographic CRS.
double ground_scale_factor(const CrsInfo& crs, const GeoTransform& transform, int width, int height);

/// Ground metres per CRS unit at the raster centre: the linear unit (0.3048
/// for international feet) times ground_scale_factor; 0 for a geographic CRS.
/// Lengths in metres divide by it to become CRS units; areas in CRS units
/// multiply by its square to become ground m^2.
double ground_metres_per_unit(const CrsInfo& crs, const GeoTransform& transform, int width, int height);

/// ground_scale_factor at the centre of `extent` (map units of `crs`), over one
/// map unit: for vector data (footprints, models) in a distorting CRS. 1 for an
/// empty extent or a CRS without a horizontal part; 0 for a geographic CRS.
double ground_scale_factor_at(const CrsInfo& crs, const Extent& extent);

/// Ground metres per map unit at the centre of `extent`: linear unit times
/// ground_scale_factor_at (0 for a geographic CRS).
double ground_metres_per_unit_at(const CrsInfo& crs, const Extent& extent);

/// Longitude and latitude (degrees, WGS 84) of a point in `crs`.
MapPoint to_lon_lat(const CrsInfo& crs, const MapPoint& p);

/// The UTM zone holding `lon_lat` (degrees) on the geodetic datum of `crs`:
/// EPSG:326zz / 327zz for WGS 84 (and for a CRS whose datum has no UTM
/// code), e.g. the working CRS of a lon/lat raster.
CrsInfo utm_crs_for(const CrsInfo& crs, const MapPoint& lon_lat);

/// True when the horizontal parts are the same CRS (vertical parts ignored).
bool same_horizontal_crs(const CrsInfo& a, const CrsInfo& b);

/// Horizontal CRS of `horizontal` combined with the vertical CRS of
/// `vertical` when `vertical` has a vertical EPSG code and `horizontal` has
/// no vertical part: by codes when `horizontal` has one (28992 + 5709 ->
/// EPSG:7415), else a compound of its WKT (a custom projection) and the
/// vertical CRS; otherwise `horizontal` unchanged.
CrsInfo combine_with_vertical(const CrsInfo& horizontal, const CrsInfo& vertical);

/// Transforms points in place from `from` to `to` (horizontal, and vertical
/// where PROJ knows both vertical datums). Throws Error naming `subject` when
/// PROJ has no transformation or a point fails, and when both CRSs state what
/// their heights refer to (a vertical CRS, or ellipsoidal heights of a 3-D
/// CRS), the two differ and PROJ could only relate them by a "ballpark"
/// operation: without the geoid grid PROJ would leave heights unchanged and
/// label them with the other datum. A horizontal-only ballpark is accepted.
void transform_points(const CrsInfo& from, const CrsInfo& to, std::vector<double>& x, std::vector<double>& y,
                      std::vector<double>& z, const std::string& subject);

/// Area on the WGS84 ellipsoid (GeographicLib) of a polygon given in `crs`,
/// square metres. Vertices are transformed to geographic coordinates first.
double geodesic_area_m2(const std::vector<std::vector<MapPoint>>& rings_outer_first, const CrsInfo& crs);

/// True when both describe the same CRS (horizontal and vertical), ignoring
/// axis-order and naming differences.
bool same_crs(const CrsInfo& a, const CrsInfo& b);

}  // namespace cityforge
