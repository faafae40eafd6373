#include "model/cgal_solid_check.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_mesh_processing/orientation.h>
#include <CGAL/Polygon_mesh_processing/polygon_soup_to_polygon_mesh.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/boost/graph/helpers.h>
#include <map>

#include "model/face_mesh.hpp"

namespace cityforge::test {

namespace PMP = CGAL::Polygon_mesh_processing;
using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Mesh = CGAL::Surface_mesh<K::Point_3>;

std::string cgal_check_solid(const Solid& solid, double* volume) {
    std::vector<K::Point_3> points;
    std::map<std::array<double, 3>, std::size_t> index;
    std::vector<std::vector<std::size_t>> triangles;
    for (const Face& f : solid.faces) {
        const std::vector<Point3> v = face_vertices(f);
        std::vector<std::size_t> id;
        for (const Point3& p : v) {
            const auto [it, fresh] = index.emplace(std::array<double, 3>{p.x, p.y, p.z}, points.size());
            if (fresh) points.emplace_back(p.x, p.y, p.z);
            id.push_back(it->second);
        }
        const auto tris = triangulate_face(f);
        if (tris.empty()) return "a face has no triangles";
        for (const auto& t : tris) triangles.push_back({id[t[0]], id[t[1]], id[t[2]]});
    }
    if (!PMP::is_polygon_soup_a_polygon_mesh(triangles)) return "not a 2-manifold, consistently oriented polygon mesh";
    Mesh mesh;
    PMP::polygon_soup_to_polygon_mesh(points, triangles, mesh);
    if (!CGAL::is_closed(mesh)) return "not closed";
    if (PMP::does_self_intersect(mesh)) return "self-intersecting";
    if (!PMP::is_outward_oriented(mesh)) return "not outward oriented";
    if (volume) *volume = PMP::volume(mesh);
    return {};
}

namespace {
Solid shell_solid(const nlohmann::json& shell, const nlohmann::json& values, const nlohmann::json& surfaces, const nlohmann::json& vertices,
                  const nlohmann::json& t) {
    Solid s;
    auto point = [&](std::size_t i) {
        const auto& v = vertices.at(i);
        return Point3{v[0].get<double>() * t["scale"][0].get<double>() + t["translate"][0].get<double>(),
                      v[1].get<double>() * t["scale"][1].get<double>() + t["translate"][1].get<double>(),
                      v[2].get<double>() * t["scale"][2].get<double>() + t["translate"][2].get<double>()};
    };
    for (std::size_t f = 0; f < shell.size(); ++f) {
        Face face;
        for (std::size_t r = 0; r < shell[f].size(); ++r) {
            Ring3 ring;
            for (const auto& i : shell[f][r]) ring.push_back(point(i.get<std::size_t>()));
            if (r == 0) face.outer = ring;
            else face.holes.push_back(ring);
        }
        const std::string type = surfaces.at(values.at(f).get<std::size_t>()).at("type");
        face.type = type == "RoofSurface" ? SurfaceType::roof : type == "GroundSurface" ? SurfaceType::ground : SurfaceType::wall;
        s.faces.push_back(std::move(face));
    }
    return s;
}
}  // namespace

std::vector<Solid> solids_from_cityjson(const nlohmann::json& g, const nlohmann::json& vertices, const nlohmann::json& t) {
    std::vector<Solid> out;
    if (g.at("type") != "Solid" && g.at("type") != "CompositeSolid" && g.at("type") != "MultiSolid") return out;
    const auto& b = g.at("boundaries");
    const auto& v = g.at("semantics").at("values");
    if (g.at("type") == "Solid") out.push_back(shell_solid(b.at(0), v.at(0), g.at("semantics").at("surfaces"), vertices, t));
    else if (g.at("type") == "CompositeSolid" || g.at("type") == "MultiSolid")
        for (std::size_t k = 0; k < b.size(); ++k) out.push_back(shell_solid(b[k].at(0), v.at(k).at(0), g.at("semantics").at("surfaces"), vertices, t));
    return out;
}

}  // namespace cityforge::test
