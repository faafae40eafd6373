#pragma once
// Boundary-represented 3-D solids of buildings (one closed shell of planar
// polygons with semantics) and their validity checks. Coordinates are in the
// model's CRS: x, y in the horizontal CRS units, z in the vertical CRS units.
// No GDAL.
#include <array>
#include <optional>
#include <string>
#include <vector>

#include "core/geometry.hpp"

namespace cityforge {

struct Point3 {
    double x = 0.0, y = 0.0, z = 0.0;
    bool operator==(const Point3&) const = default;
};
/// A polygon ring; the first vertex is not repeated at the end.
using Ring3 = std::vector<Point3>;

/// Semantic class of a boundary surface (CityGML / CityJSON names).
enum class SurfaceType { ground, wall, roof };
const char* citygml_name(SurfaceType t);  ///< "GroundSurface", "WallSurface", "RoofSurface"

/// A planar face: outer ring counter-clockwise seen from outside the solid
/// (normal pointing out), inner rings clockwise.
struct Face {
    Ring3 outer;
    std::vector<Ring3> holes;
    SurfaceType type = SurfaceType::wall;
};

/// One closed shell; faces oriented outwards.
struct Solid {
    std::vector<Face> faces;
};

/// A prism over a footprint part (outer ring counter-clockwise, holes
/// clockwise, as orient_polygon leaves them): ground face at z_bottom, roof
/// face at z_top, one vertical wall per ring edge (courtyard walls included).
/// Requires z_top > z_bottom.
Solid extrude_prism(const Polygon& footprint, double z_bottom, double z_top);

/// The face seen from above: its rings' x, y (holes kept).
Polygon face_plan(const Face& face);

/// z of the face's plane at (x, y) when (x, y) lies inside the face's plan;
/// nullopt outside it or for vertical faces.
std::optional<double> face_z_at(const Face& face, double x, double y);

/// face_z_at for many points on one face: its plane, plan and plan extent
/// prepared once (same values as face_z_at).
class FaceHeight {
public:
    explicit FaceHeight(const Face& face);
    std::optional<double> operator()(double x, double y) const;

private:
    bool usable_ = false;
    std::array<double, 3> n_{0, 0, 0};
    double cx_ = 0, cy_ = 0, cz_ = 0;
    Polygon plan_;
    double min_x_ = 0, min_y_ = 0, max_x_ = 0, max_y_ = 0;
};

/// Euclidean 3-D distance from p to a planar face (holes excluded): to its
/// plane where p projects inside it, else to its nearest edge. Same units as
/// the coordinates (x, y and z must share a unit).
double distance_to_face(const Face& face, const Point3& p);

/// Smallest distance_to_face over the solid's faces (roofs, walls, ground).
double distance_to_solid(const Solid& solid, const Point3& p);

/// distance_to_solid for many points against the same solids: each face's
/// plane and rings are prepared once, and a face whose plane or bounding box
/// is already farther than the best distance so far is skipped. Gives the
/// same values as the smallest distance_to_solid over `solids`.
class SolidsDistance {
public:
    explicit SolidsDistance(const std::vector<Solid>& solids);
    /// INFINITY when there is no face.
    double operator()(const Point3& p) const;

    /// One face, prepared (public for distance_to_face, which uses the same arithmetic).
    struct PreparedFace {
        const Face* face = nullptr;
        bool has_plane = false;
        double nx = 0, ny = 0, nz = 0;  ///< unit normal (Newell)
        int drop = 2;                   ///< axis dropped for the inside test (the normal's largest)
        Polygon plan;                   ///< rings on the two kept axes
        double min[3] = {0, 0, 0}, max[3] = {0, 0, 0};  ///< bounding box of the rings
        explicit PreparedFace(const Face& f);
        double distance(const Point3& p) const;
        /// A lower bound of distance(p): the larger of the distance to the plane and to the box.
        double lower_bound(const Point3& p) const;
    };

private:
    std::vector<PreparedFace> faces_;
};

/// Area of a planar face (holes subtracted), CRS units².
double face_area(const Face& face);

/// Signed volume (divergence theorem); positive for an outward-oriented closed
/// shell. CRS units³ (x, y and z units multiplied).
double solid_volume(const Solid& solid);

struct SolidValidityOptions {
    double planarity_tolerance = 0.01;  ///< max distance of a vertex to its face's plane, CRS units
    double snap_tolerance = 1e-6;       ///< vertices closer than this are the same vertex, CRS units
    double min_face_area = 1e-6;        ///< smaller faces are degenerate, CRS units²
};

/// Checks a solid the way val3dity does and returns one message per problem,
/// prefixed with val3dity's error code where one exists: 101 TOO_FEW_POINTS,
/// 102 CONSECUTIVE_POINTS_SAME, 104 RING_SELF_INTERSECTION, 203
/// NON_PLANAR_POLYGON_DISTANCE_PLANE, 301 TOO_FEW_POLYGONS, 302
/// SHELL_NOT_CLOSED, 303 NON_MANIFOLD_CASE, 307 POLYGON_WRONG_ORIENTATION,
/// and DEGENERATE_POLYGON (zero area). Empty = valid. Shell
/// self-intersections between non-adjacent faces (306) are not tested; a
/// 2.5-D solid over a valid footprint cannot have them.
std::vector<std::string> validate_solid(const Solid& solid, const SolidValidityOptions& options = {});

}  // namespace cityforge
