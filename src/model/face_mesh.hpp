#pragma once
// Triangles of the planar faces of building solids, for mesh formats (glTF,
// 3D Tiles) and viewers. Pure geometry, CRS units; no GDAL.
#include <array>
#include <cstdint>
#include <vector>

#include "model/solid.hpp"

namespace cityforge {

/// The face's vertices in ring order: the outer ring, then each hole.
std::vector<Point3> face_vertices(const Face& face);

/// Triangles covering a planar face with holes (constrained Delaunay in the
/// face's plane), as indices into face_vertices(face), each wound like the
/// outer ring (counter-clockwise seen from outside the solid). Faces that
/// cannot be triangulated (fewer than 3 vertices, zero area, crossing rings)
/// give no triangles.
std::vector<std::array<uint32_t, 3>> triangulate_face(const Face& face);

/// Newell normal of a ring (not normalised; its length is twice the area).
std::array<double, 3> newell_normal(const Ring3& ring);

}  // namespace cityforge
