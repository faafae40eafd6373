#pragma once
// An independent check of building solids for the tests: CGAL's polygon-mesh
// predicates (Polygon Mesh Processing), not our validate_solid().
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "model/solid.hpp"

namespace cityforge::test {

/// "" when the solid's faces (triangulated in their planes, vertices merged by
/// exact coordinates) form one 2-manifold, consistently oriented polygon mesh
/// that CGAL finds closed, free of self-intersections and outward oriented;
/// else what failed. `volume` gets CGAL's volume of the mesh.
std::string cgal_check_solid(const Solid& solid, double* volume = nullptr);

/// The exterior shells of a CityJSON "Solid" or "CompositeSolid" geometry (with their
/// semantics) as Solids, vertices from the document's `vertices` and `transform`; none for
/// other geometry types.
std::vector<Solid> solids_from_cityjson(const nlohmann::json& geometry, const nlohmann::json& vertices, const nlohmann::json& transform);

}  // namespace cityforge::test
