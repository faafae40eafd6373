#include "model/face_mesh.hpp"

#include <CGAL/Constrained_Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_face_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <cmath>
#include <list>

namespace cityforge {
namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Vb = CGAL::Triangulation_vertex_base_with_info_2<uint32_t, K>;
struct FaceInfo {
    int nesting = -1;  ///< even-odd depth from the outside; odd = inside the face
};
using Fbi = CGAL::Triangulation_face_base_with_info_2<FaceInfo, K>;
using Fb = CGAL::Constrained_triangulation_face_base_2<K, Fbi>;
using Tds = CGAL::Triangulation_data_structure_2<Vb, Fb>;
using Cdt = CGAL::Constrained_Delaunay_triangulation_2<K, Tds, CGAL::Exact_predicates_tag>;

// Marks every triangle with its nesting level (CGAL's polygon-with-holes recipe).
void mark_domains(Cdt& cdt) {
    for (auto f = cdt.all_faces_begin(); f != cdt.all_faces_end(); ++f) f->info().nesting = -1;
    std::list<Cdt::Edge> border;
    auto flood = [&](Cdt::Face_handle start, int level) {
        if (start->info().nesting != -1) return;
        std::list<Cdt::Face_handle> queue{start};
        while (!queue.empty()) {
            Cdt::Face_handle fh = queue.front();
            queue.pop_front();
            if (fh->info().nesting != -1) continue;
            fh->info().nesting = level;
            for (int i = 0; i < 3; ++i) {
                Cdt::Edge e(fh, i);
                Cdt::Face_handle n = fh->neighbor(i);
                if (n->info().nesting == -1) {
                    if (cdt.is_constrained(e)) border.push_back(e);
                    else queue.push_back(n);
                }
            }
        }
    };
    flood(cdt.infinite_face(), 0);
    while (!border.empty()) {
        Cdt::Edge e = border.front();
        border.pop_front();
        Cdt::Face_handle n = e.first->neighbor(e.second);
        if (n->info().nesting == -1) flood(n, e.first->info().nesting + 1);
    }
}

}  // namespace

std::vector<Point3> face_vertices(const Face& face) {
    std::vector<Point3> v(face.outer.begin(), face.outer.end());
    for (const Ring3& h : face.holes) v.insert(v.end(), h.begin(), h.end());
    return v;
}

std::array<double, 3> newell_normal(const Ring3& r) {
    std::array<double, 3> n{0, 0, 0};
    if (r.empty()) return n;
    const Point3 o = r[0];  // local origin: projected coordinates lose digits otherwise
    for (std::size_t i = 0; i < r.size(); ++i) {
        const Point3& a = r[i];
        const Point3& b = r[(i + 1) % r.size()];
        const double ay = a.y - o.y, az = a.z - o.z, ax = a.x - o.x;
        const double by = b.y - o.y, bz = b.z - o.z, bx = b.x - o.x;
        n[0] += (ay - by) * (az + bz);
        n[1] += (az - bz) * (ax + bx);
        n[2] += (ax - bx) * (ay + by);
    }
    return n;
}

std::vector<std::array<uint32_t, 3>> triangulate_face(const Face& face) {
    std::vector<std::array<uint32_t, 3>> out;
    if (face.outer.size() < 3) return out;
    const auto n = newell_normal(face.outer);
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!(len > 0)) return out;
    // Drop the dominant axis of the normal: the face projects without folding.
    int drop = 2;
    if (std::abs(n[0]) >= std::abs(n[1]) && std::abs(n[0]) >= std::abs(n[2])) drop = 0;
    else if (std::abs(n[1]) >= std::abs(n[2])) drop = 1;
    const std::vector<Point3> verts = face_vertices(face);
    const Point3 o = verts[0];
    auto project = [&](const Point3& p) {
        const double x = p.x - o.x, y = p.y - o.y, z = p.z - o.z;
        return drop == 0 ? K::Point_2(y, z) : drop == 1 ? K::Point_2(z, x) : K::Point_2(x, y);
    };
    Cdt cdt;
    try {
        uint32_t base = 0;
        auto add_ring = [&](const Ring3& r) {
            std::vector<Cdt::Vertex_handle> vh;
            vh.reserve(r.size());
            for (std::size_t i = 0; i < r.size(); ++i) {
                Cdt::Vertex_handle h = cdt.insert(project(r[i]));
                h->info() = base + static_cast<uint32_t>(i);
                vh.push_back(h);
            }
            for (std::size_t i = 0; i < vh.size(); ++i)
                if (vh[i] != vh[(i + 1) % vh.size()]) cdt.insert_constraint(vh[i], vh[(i + 1) % vh.size()]);
            base += static_cast<uint32_t>(r.size());
        };
        add_ring(face.outer);
        for (const Ring3& h : face.holes) add_ring(h);
    } catch (const std::exception&) {
        return out;  // crossing rings: the face is invalid (validate_solid says why)
    }
    mark_domains(cdt);
    // The projection may mirror the plane: keep the outer ring's winding.
    const double sign = n[drop] > 0 ? 1.0 : -1.0;
    for (auto f = cdt.finite_faces_begin(); f != cdt.finite_faces_end(); ++f) {
        if (f->info().nesting % 2 != 1) continue;
        std::array<uint32_t, 3> t{f->vertex(0)->info(), f->vertex(1)->info(), f->vertex(2)->info()};
        // CGAL's faces are counter-clockwise in the projection.
        if (sign < 0) std::swap(t[1], t[2]);
        out.push_back(t);
    }
    return out;
}

}  // namespace cityforge
