#include "io/tiles3d_writer.hpp"


#include <GeographicLib/Geocentric.hpp>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <tbb/parallel_for.h>
#include <unistd.h>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/memory.hpp"
#include "core/log.hpp"
#include "core/version.hpp"
#include "crs/crs.hpp"
#include "io/gltf_writer.hpp"
#include "model/face_mesh.hpp"
#include "raster/quicklook.hpp"

namespace cityforge {
namespace {

using json = nlohmann::json;
namespace fs = std::filesystem;

// The solids a mesh shows for a building, and their refined LOD name, as the
// CityJSON writer and 3DBAG name them ("1.2": one height per footprint, "2.2": roof planes).
const std::vector<Solid>* mesh_solids(const Building& b, bool prefer_lod2, std::string& lod) {
    if (prefer_lod2 && !b.lod2.empty()) return lod = "2.2", &b.lod2;
    if (!b.lod1.empty()) return lod = "1.2", &b.lod1;
    if (!b.lod2.empty()) return lod = "2.2", &b.lod2;
    return nullptr;
}

std::vector<Face> faces_of(const std::vector<Solid>& solids) {
    std::vector<Face> f;
    for (const Solid& s : solids) f.insert(f.end(), s.faces.begin(), s.faces.end());
    return f;
}

template <typename F>
void for_each_point(std::vector<Face>& faces, F&& fn) {
    for (Face& f : faces) {
        for (Point3& p : f.outer) fn(p);
        for (Ring3& h : f.holes)
            for (Point3& p : h) fn(p);
    }
}

// An oriented box: centre and three half-axis vectors (ECEF metres).
struct Box {
    std::array<double, 3> centre{};
    std::array<std::array<double, 3>, 3> half{};
    json to_json() const {
        return json::array({centre[0], centre[1], centre[2], half[0][0], half[0][1], half[0][2], half[1][0], half[1][1], half[1][2],
                            half[2][0], half[2][1], half[2][2]});
    }
    std::vector<std::array<double, 3>> corners() const {
        std::vector<std::array<double, 3>> c;
        for (int i = 0; i < 8; ++i) {
            std::array<double, 3> p = centre;
            for (int a = 0; a < 3; ++a) {
                const double s = (i >> a) & 1 ? 1.0 : -1.0;
                for (int k = 0; k < 3; ++k) p[k] += s * half[a][k];
            }
            c.push_back(p);
        }
        return c;
    }
};

// Box of points aligned with the local east-north-up frame at their mean.
Box enu_box(const std::vector<std::array<double, 3>>& pts) {
    std::array<double, 3> mean{0, 0, 0};
    for (const auto& p : pts)
        for (int k = 0; k < 3; ++k) mean[k] += p[k];
    for (double& m : mean) m /= double(std::max<std::size_t>(1, pts.size()));
    double lat = 0, lon = 0, h = 0;
    std::vector<double> M(9);  // geocentric = M * (east, north, up), row-major
    GeographicLib::Geocentric::WGS84().Reverse(mean[0], mean[1], mean[2], lat, lon, h, M);
    std::array<double, 3> lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
    for (const auto& p : pts) {
        const double d[3] = {p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]};
        for (int a = 0; a < 3; ++a) {
            const double v = M[0 * 3 + a] * d[0] + M[1 * 3 + a] * d[1] + M[2 * 3 + a] * d[2];  // M^T d
            lo[a] = std::min(lo[a], v), hi[a] = std::max(hi[a], v);
        }
    }
    Box b;
    b.centre = mean;
    for (int a = 0; a < 3; ++a) {
        const double mid = 0.5 * (lo[a] + hi[a]);
        const double half = std::max(0.5 * (hi[a] - lo[a]), 0.01) * 1.000001 + 1e-6;  // never flat, a hair larger
        for (int k = 0; k < 3; ++k) b.centre[k] += M[k * 3 + a] * mid, b.half[a][k] = M[k * 3 + a] * half;
    }
    return b;
}

struct Node {
    int level = 0, x = 0, y = 0;
    double size = 0;                 // square side, model CRS units
    std::vector<std::size_t> items;  // indices into the meshed buildings (leaves only)
    std::vector<Node> children;
    Box box;
    std::string content;             // leaf content uri
};

void split(Node& n, const std::vector<std::array<double, 2>>& centres, double x0, double y0, const Tiles3dWriteOptions& o, int& depth) {
    depth = std::max(depth, n.level);
    if (static_cast<int>(n.items.size()) <= o.max_buildings_per_tile || n.level >= o.max_depth) return;
    const double h = n.size / 2;
    std::array<Node, 4> q;
    for (int k = 0; k < 4; ++k) q[k].level = n.level + 1, q[k].x = 2 * n.x + (k & 1), q[k].y = 2 * n.y + (k >> 1), q[k].size = h;
    for (std::size_t i : n.items) {
        const int cx = centres[i][0] >= x0 + h ? 1 : 0, cy = centres[i][1] >= y0 + h ? 1 : 0;
        q[cy * 2 + cx].items.push_back(i);
    }
    n.items.clear();
    for (int k = 0; k < 4; ++k) {
        if (q[k].items.empty()) continue;
        split(q[k], centres, x0 + (k & 1) * h, y0 + (k >> 1) * h, o, depth);
        n.children.push_back(std::move(q[k]));
    }
}

void collect_leaves(Node& n, std::vector<Node*>& leaves) {
    if (n.children.empty()) leaves.push_back(&n);
    for (Node& c : n.children) collect_leaves(c, leaves);
}

// Internal boxes cover their children's boxes (corners), so each child lies inside its parent.
void internal_boxes(Node& n, std::size_t& tiles) {
    ++tiles;
    if (n.children.empty()) return;
    std::vector<std::array<double, 3>> pts;
    for (Node& c : n.children) {
        internal_boxes(c, tiles);
        for (const auto& p : c.box.corners()) pts.push_back(p);
    }
    n.box = enu_box(pts);
}

json node_json(const Node& n, double unit_m) {
    json j;
    j["boundingVolume"] = {{"box", n.box.to_json()}};
    // Without its children a node shows nothing: its error is a fraction of its size, halving with depth.
    j["geometricError"] = n.children.empty() ? 0.0 : n.size * unit_m / 4.0;
    j["refine"] = "ADD";
    if (!n.content.empty()) j["content"] = {{"uri", n.content}};
    if (!n.children.empty()) {
        j["children"] = json::array();
        for (const Node& c : n.children) j["children"].push_back(node_json(c, unit_m));
    }
    return j;
}

// Writes `bytes` to `path` (a temporary); errors name `shown`, the file the user asked for.
void write_binary(const fs::path& path, const std::string& bytes, const fs::path& shown) {
    std::ofstream f(path, std::ios::binary | std::ios::trunc);
    if (!f) throw Error(shown.string(), "cannot open for writing");
    f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    f.close();
    if (!f) throw Error(shown.string(), "write failed (disk full?)");
}

}  // namespace

void Tiles3dWriteOptions::validate() const {
    if (max_buildings_per_tile < 1) throw Error("3dtiles", "max_buildings_per_tile must be >= 1");
    if (max_depth < 0 || max_depth > 20) throw Error("3dtiles", "max_depth must be in 0..20");
}

Tiles3dWriteReport write_3dtiles(const std::string& dir, const CityModel& model, const CrsInfo& crs, const Tiles3dWriteOptions& o,
                                 const RoofTextureAtlas* textures) {
    o.validate();
    const bool textured = textures && !textures->png.empty();
    if (textured && textures->layout.windows.size() &&
        textures->rgb.size() != std::size_t(textures->layout.atlas_width) * textures->layout.atlas_height * 3)
        throw Error(dir, "internal: the roof texture atlas has no pixels");
    if (crs.empty()) throw Error(dir, "the model has no CRS; 3D Tiles need one to place buildings on the globe");
    // Meshed buildings and their faces in the model CRS.
    std::vector<const Building*> meshed;
    std::vector<std::size_t> model_index;  // of each meshed building in model.buildings
    std::vector<std::string> lods;
    std::vector<std::vector<Face>> faces;
    for (std::size_t bi = 0; bi < model.buildings.size(); ++bi) {
        const Building& b = model.buildings[bi];
        std::string lod;
        if (const auto* s = mesh_solids(b, o.prefer_lod2, lod))
            meshed.push_back(&b), model_index.push_back(bi), lods.push_back(lod), faces.push_back(faces_of(*s));
    }
    if (meshed.empty()) throw Error(dir, "no building has a LOD1 or LOD2 solid (heights missing?); nothing to tile");

    // Every vertex to ECEF.
    std::vector<double> X, Y, Z;
    for (auto& fl : faces) for_each_point(fl, [&](Point3& p) { X.push_back(p.x), Y.push_back(p.y), Z.push_back(p.z); });
    const CrsInfo ecef = crs_from_user_input("EPSG:4978", "3D Tiles");
    {
        std::vector<double> x = X, y = Y, z = Z;
        try {
            transform_points(crs, ecef, x, y, z, dir);
        } catch (const Error& e) {
            if (!crs.vertical_epsg || !crs.horizontal_epsg) throw;
            // PROJ could not relate the vertical datum to the ellipsoid (a geoid grid is missing): the
            // horizontal CRS alone keeps its proper datum transformation, heights count as ellipsoidal.
            log::warning(std::string(e.what()) + "; the tiles take them as ellipsoidal heights");
            x = X, y = Y, z = Z;
            transform_points(crs_from_user_input("EPSG:" + std::to_string(*crs.horizontal_epsg), dir), ecef, x, y, z, dir);
        }
        X.swap(x), Y.swap(y), Z.swap(z);
    }
    std::vector<std::vector<Face>> ecef_faces = faces;
    {
        std::size_t k = 0;
        for (auto& fl : ecef_faces) for_each_point(fl, [&](Point3& p) { p = {X[k], Y[k], Z[k]}, ++k; });
    }

    // Quadtree over footprint centres.
    const auto e = model_extent(model);
    std::vector<std::array<double, 2>> centres;
    for (const Building* b : meshed) {
        const Extent x = parts_extent(b->footprint);
        centres.push_back({0.5 * (x.min_x + x.max_x), 0.5 * (x.min_y + x.max_y)});
    }
    Node root;
    root.size = std::max({e[3] - e[0], e[4] - e[1], 1.0}) * (1 + 1e-9);
    root.items.resize(meshed.size());
    for (std::size_t i = 0; i < meshed.size(); ++i) root.items[i] = i;
    Tiles3dWriteReport rep;
    split(root, centres, e[0], e[1], o, rep.depth);
    std::vector<Node*> leaves;
    collect_leaves(root, leaves);

    const fs::path final_dir(dir);
    const fs::path tmp = final_dir.parent_path() / (final_dir.filename().string() + ".part-" + std::to_string(::getpid()));
    std::error_code ec;
    register_temporary(tmp);  // removed if the process is interrupted
    fs::remove_all(tmp, ec);
    const std::vector<GltfProperty> props = building_properties(model);
    std::vector<std::size_t> triangles(leaves.size());
    try {
        ensure_directory(tmp / "content");
        // One tile per task (a tile is heavy: meshing, its atlas' PNG, the file); each writes only its own leaf.
        tbb::parallel_for(std::size_t(0), leaves.size(), [&](std::size_t li) {
            Node& n = *leaves[li];
            std::vector<std::array<double, 3>> pts;
            for (std::size_t i : n.items)
                for_each_point(ecef_faces[i], [&](Point3& p) { pts.push_back({p.x, p.y, p.z}); });
            n.box = enu_box(pts);
            GlbContent c;
            c.translation = n.box.centre;
            // Roof textures: the tile's own atlas, cut from the model's (only its buildings' windows).
            RoofTextureLayout tile_atlas;
            if (textured) {
                std::vector<std::size_t> in_tile;
                for (std::size_t i : n.items)
                    if (lods[i] == "2.2") in_tile.push_back(model_index[i]);
                tile_atlas = repack_roof_textures(textures->layout, in_tile);
                if (!tile_atlas.windows.empty())
                    c.texture_png = encode_png(copy_roof_texture_pixels(textures->layout, textures->rgb, tile_atlas), tile_atlas.atlas_width,
                                               tile_atlas.atlas_height, 3, dir);
            }
            for (std::size_t i : n.items) {
                if (!c.texture_png.empty())  // from the map x, y
                    c.uv.push_back(lods[i] == "2.2" ? roof_face_uvs(faces[i], tile_atlas, model_index[i])
                                                    : std::vector<std::vector<std::array<float, 2>>>(faces[i].size()));
                c.buildings.push_back(meshed[i]);
                c.lods.push_back(lods[i]);
                std::vector<Face> local = ecef_faces[i];
                for_each_point(local, [&](Point3& p) { p = {p.x - c.translation[0], p.y - c.translation[1], p.z - c.translation[2]}; });
                c.faces.push_back(std::move(local));
            }
            GlbStats st;
            const std::string bytes = encode_glb(c, props, &st);
            triangles[li] = st.triangles;
            n.content = "content/" + std::to_string(n.level) + "_" + std::to_string(n.x) + "_" + std::to_string(n.y) + ".glb";
            write_binary(tmp / n.content, bytes, final_dir / n.content);
        });
        internal_boxes(root, rep.tiles);
        json tileset;
        tileset["asset"] = {{"version", "1.1"}, {"generator", std::string("cityforge ") + version()},
                            {"extras", {{"crs", model.crs.label}, {"source_crs_wkt", crs.wkt}}}};
        const double unit = model.crs.linear_unit_m;
        tileset["geometricError"] = root.size * unit / 2.0;
        tileset["root"] = node_json(root, unit);
        tileset["extras"] = {{"buildings", meshed.size()}, {"title", model.title}};
        std::ofstream f(tmp / "tileset.json");
        f << tileset.dump(1) << '\n';
        f.close();
        if (!f) throw Error((final_dir / "tileset.json").string(), "write failed (disk full?)");
        fs::remove_all(final_dir, ec);
        fs::rename(tmp, final_dir, ec);
        if (ec) throw Error(dir, "cannot rename the finished tileset into place: " + ec.message());
        unregister_temporary(tmp);
    } catch (const OutOfMemory&) {
        fs::remove_all(tmp, ec);
        unregister_temporary(tmp);
        throw;
    } catch (const Error& err) {
        fs::remove_all(tmp, ec);
        unregister_temporary(tmp);
        throw Error(user_named(err.what(), tmp, final_dir));  // the folder the user asked for, never 3dtiles.part-PID
    } catch (...) {
        fs::remove_all(tmp, ec);
        unregister_temporary(tmp);
        throw;
    }
    rep.buildings = meshed.size();
    rep.content_tiles = leaves.size();
    for (std::size_t t : triangles) rep.triangles += t;
    return rep;
}

std::size_t write_glb(const std::string& path, const CityModel& model, bool prefer_lod2, const RoofTextureAtlas* textures) {
    const auto e = model_extent(model);
    GlbContent c;
    const std::array<double, 3> origin{std::round(0.5 * (e[0] + e[3])), std::round(0.5 * (e[1] + e[4])), std::floor(e[2])};
    const bool textured = textures && !textures->png.empty();
    if (textured) c.texture_png = textures->png;
    for (std::size_t bi = 0; bi < model.buildings.size(); ++bi) {
        const Building& b = model.buildings[bi];
        std::string lod;
        const auto* s = mesh_solids(b, prefer_lod2, lod);
        if (!s) continue;
        std::vector<Face> f = faces_of(*s);
        if (textured)  // texture coordinates from the map x, y, before the shift to the local frame
            c.uv.push_back(lod == "2.2" ? roof_face_uvs(f, textures->layout, bi) : std::vector<std::vector<std::array<float, 2>>>(f.size()));
        for_each_point(f, [&](Point3& p) { p = {p.x - origin[0], p.y - origin[1], p.z - origin[2]}; });
        c.buildings.push_back(&b), c.lods.push_back(lod), c.faces.push_back(std::move(f));
    }
    if (c.buildings.empty()) throw Error(path, "no building has a LOD1 or LOD2 solid (heights missing?); nothing to write");
    c.extras = {{"crs", model.crs.label}, {"origin", origin}, {"frame", "x east, -z north, y up; model CRS units minus origin"}};
    if (model.crs.horizontal_epsg) c.extras["horizontal_epsg"] = *model.crs.horizontal_epsg;
    if (model.crs.vertical_epsg) c.extras["vertical_epsg"] = *model.crs.vertical_epsg;
    GlbStats st;
    const std::string bytes = encode_glb(c, building_properties(model), &st);
    const fs::path tmp = temporary_path_for(path);
    try {
        write_binary(tmp, bytes, path);
        commit_file(tmp, path);
    } catch (...) {
        discard_file(tmp);
        throw;
    }
    return st.triangles;
}

}  // namespace cityforge
