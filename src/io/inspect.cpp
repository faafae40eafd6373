#include "io/inspect.hpp"

#include <algorithm>
#include <cctype>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "core/error.hpp"
#include "crs/gdal_util.hpp"
#include "io/cloud_crs.hpp"

namespace cityforge {
namespace {

bool has_las_signature(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    char sig[4] = {};
    in.read(sig, 4);
    return in.gcount() == 4 && std::memcmp(sig, "LASF", 4) == 0;
}

std::string lower_ext(const std::string& path) {
    std::string e = std::filesystem::path(path).extension().string();
    std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return e;
}

CloudInfo inspect_cloud(const std::string& path, const InspectOptions& options) {
    LasReader reader(path);
    CloudInfo info;
    info.path = path;
    info.header = reader.header();
    if (LazPointSource* laz = reader.laz_source()) {
        info.laz_chunks = laz->chunks().size();
        info.laz_chunk_table = laz->has_chunk_table();
        info.copc = read_copc_hierarchy(reader.file(), info.header);
    }
    {
        CloudCrs resolved = resolve_cloud_crs(CloudReader(path), options.assume_crs, "--crs");
        info.crs = std::move(resolved.crs);
        info.crs_source = std::move(resolved.source);
        info.crs_warnings = std::move(resolved.warnings);
    }
    if (options.cloud_statistics) {
        std::array<double, 6> b{};
        b.fill(std::numeric_limits<double>::infinity());
        for (int k = 3; k < 6; ++k) b[k] = -b[k];
        PointCloud chunk;
        while (true) {
            chunk.clear();
            if (reader.read_chunk(chunk, 1u << 20) == 0) break;
            for (std::size_t i = 0; i < chunk.size(); ++i) {
                ++info.class_counts[chunk.classification[i]];
                const double v[3] = {chunk.x[i], chunk.y[i], chunk.z[i]};
                for (int k = 0; k < 3; ++k) b[k] = std::min(b[k], v[k]), b[k + 3] = std::max(b[k + 3], v[k]);
            }
        }
        if (info.header.point_count > 0) info.measured_bounds = b;
    }
    return info;
}

}  // namespace

namespace {
// City model files cityforge writes (and others write) but does not read.
bool is_city_model_name(const std::string& path) {
    std::string name = std::filesystem::path(path).filename().string();
    for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    const auto ends = [&](const std::string& tail) { return name.size() >= tail.size() && name.compare(name.size() - tail.size(), tail.size(), tail) == 0; };
    return ends(".city.json") || ends(".city.jsonl") || ends(".glb") || ends(".gltf") || ends("tileset.json");
}
}  // namespace

DatasetInfo inspect_dataset(const std::string& path, const InspectOptions& options) {
    require_dataset_exists(path);
    DatasetInfo info;
    const std::string ext = lower_ext(path);
    if (has_las_signature(path)) {
        info.cloud = inspect_cloud(path, options);
        return info;
    }
    const bool vector_ext = ext == ".geojson" || ext == ".json" || ext == ".gpkg" || ext == ".shp" || ext == ".fgb" ||
                            ext == ".gml" || ext == ".kml" || ext == ".sqlite";
    if (!vector_ext) {
        try {
            RasterOpenOptions ro;
            ro.allow_pixel_coordinates = true;  // describe, don't refuse
            ro.assume_crs = options.assume_crs;
            info.raster = read_raster_info(path, ro);
            return info;
        } catch (const Error&) {
            // not a raster: try vector below
        }
    }
    try {
        info.vector = read_vector_info(path);
    } catch (const Error& e) {
        // A folder may be a vector dataset (a Shapefile folder, a .gdb); any other is named as one.
        if (std::filesystem::is_directory(path)) throw Error(path, "is a directory, not a raster, point cloud or vector dataset cityforge can read");
        std::error_code ec;
        if (std::filesystem::is_regular_file(path, ec) && std::filesystem::file_size(path, ec) == 0 && !ec) throw Error(path, "empty file (0 bytes)");
        if (is_city_model_name(path))
            throw Error(path, "a city model (CityJSON / CityGML / glTF): info describes rasters, point clouds and vector layers; "
                              "the model's building table is the buildings.gpkg or .geojson written next to it");
        // A vector extension: OGR's reason (a truncated GeoJSON says so).
        if (vector_ext) throw Error(std::string(e.what()));
        throw Error(path, "not a raster, LAS point cloud or vector file that cityforge can read");
    }
    if (info.vector->layers.empty()) throw Error(path, "vector dataset has no layers");
    return info;
}

nlohmann::json to_json(const CrsInfo& crs) {
    using nlohmann::json;
    if (crs.empty()) return nullptr;
    json j;
    j["name"] = crs.name;
    j["label"] = crs.label();
    j["epsg"] = crs.epsg ? json(*crs.epsg) : json(nullptr);
    j["horizontal_epsg"] = crs.horizontal_epsg ? json(*crs.horizontal_epsg) : json(nullptr);
    j["vertical_epsg"] = crs.vertical_epsg ? json(*crs.vertical_epsg) : json(nullptr);
    j["vertical_name"] = crs.vertical_name.empty() ? json(nullptr) : json(crs.vertical_name);
    j["geographic"] = crs.geographic;
    j["linear_unit"] = crs.linear_unit_name;
    j["linear_unit_m"] = crs.linear_unit_m;
    j["wkt"] = crs.wkt;
    return j;
}

nlohmann::json to_json(const DatasetInfo& info) {
    using nlohmann::json;
    json j;
    if (info.raster) {
        const RasterInfo& r = *info.raster;
        j["kind"] = "raster";
        j["path"] = r.path;
        j["driver"] = r.driver;
        j["width"] = r.width;
        j["height"] = r.height;
        j["block_size"] = {r.block_width, r.block_height};
        j["georeferenced"] = r.georeferenced;
        j["geotransform"] = r.transform.to_gdal();
        j["crs"] = to_json(r.crs);
        j["gsd_m"] = {{"x", r.gsd.x_m}, {"y", r.gsd.y_m}};
        j["extent"] = {{"min_x", r.extent.min_x}, {"min_y", r.extent.min_y}, {"max_x", r.extent.max_x}, {"max_y", r.extent.max_y}};
        json bands = json::array();
        for (const auto& b : r.bands)
            bands.push_back({{"type", to_string(b.type)},
                             {"nodata", b.nodata ? json(*b.nodata) : json(nullptr)},
                             {"color_interpretation", b.color_interpretation},
                             {"description", b.description}});
        j["bands"] = bands;
    } else if (info.cloud) {
        const CloudInfo& c = *info.cloud;
        const LasHeader& h = c.header;
        j["kind"] = "point_cloud";
        j["path"] = c.path;
        j["format"] = "LAS " + std::to_string(h.version_major) + "." + std::to_string(h.version_minor);
        j["point_format"] = h.point_format;
        j["point_record_length"] = h.point_record_length;
        j["point_count"] = h.point_count;
        j["scale"] = h.scale;
        j["offset"] = h.offset;
        j["header_bounds"] = {{"min", h.min}, {"max", h.max}};
        j["has_color"] = h.has_color();
        j["has_gps_time"] = h.has_gps_time();
        j["generating_software"] = h.generating_software;
        j["crs"] = to_json(c.crs);
        j["crs_source"] = c.crs_source.empty() ? nlohmann::json(nullptr) : nlohmann::json(c.crs_source);
        j["crs_warnings"] = c.crs_warnings;
        if (!c.class_counts.empty()) {
            json cc = json::object();
            for (auto [k, v] : c.class_counts) cc[std::to_string(k)] = v;
            j["class_counts"] = cc;
        }
        if (c.measured_bounds) j["measured_bounds"] = *c.measured_bounds;
        if (h.laz) {
            json items = json::array();
            for (const LazItem& it : h.laz->items) items.push_back({{"type", to_string(it)}, {"size", it.size}, {"version", it.version}});
            j["laz"] = {{"compressor", h.laz->compressor_name()},
                        {"coder", h.laz->coder},
                        {"laszip_version", std::to_string(h.laz->version_major) + "." + std::to_string(h.laz->version_minor) + " r" +
                                               std::to_string(h.laz->version_revision)},
                        {"chunk_size", h.laz->variable_chunks() ? json("variable") : json(h.laz->chunk_size)},
                        {"chunks", c.laz_chunks},
                        {"chunk_table", c.laz_chunk_table},
                        {"items", items}};
        }
        if (c.copc) {
            const CopcInfo& ci = c.copc->info;
            j["copc"] = {{"center", {ci.center_x, ci.center_y, ci.center_z}}, {"halfsize", ci.halfsize},
                         {"spacing", ci.spacing}, {"nodes", c.copc->nodes.size()},
                         {"max_level", c.copc->max_level}, {"hierarchy_pages", c.copc->pages},
                         {"gps_time", {ci.gps_time_min, ci.gps_time_max}}};
        }
        if (!c.crs.empty() && !c.crs.geographic) {
            const double area = (h.max[0] - h.min[0]) * (h.max[1] - h.min[1]) * c.crs.linear_unit_m * c.crs.linear_unit_m;
            if (area > 0) j["mean_density_pts_m2"] = static_cast<double>(h.point_count) / area;
        }
    } else if (info.vector) {
        const VectorInfo& v = *info.vector;
        j["kind"] = "vector";
        j["path"] = v.path;
        j["driver"] = v.driver;
        json layers = json::array();
        for (const auto& l : v.layers) {
            json lj{{"name", l.name}, {"geometry_type", l.geometry_type}, {"feature_count", l.feature_count},
                    {"crs", to_json(l.crs)}, {"fields", l.fields}};
            if (l.extent)
                lj["extent"] = {{"min_x", l.extent->min_x}, {"min_y", l.extent->min_y}, {"max_x", l.extent->max_x}, {"max_y", l.extent->max_y}};
            layers.push_back(lj);
        }
        j["layers"] = layers;
    }
    return j;
}

std::string to_text(const DatasetInfo& info) {
    std::ostringstream o;
    o.precision(10);
    auto crs_line = [&](const CrsInfo& c) {
        if (c.empty()) return std::string("none");
        std::string s = c.label() + " (" + c.name + ")";
        if (!c.vertical_name.empty()) s += ", vertical: " + c.vertical_name;
        if (!c.geographic) s += ", unit: " + c.linear_unit_name;
        return s;
    };
    if (info.raster) {
        const RasterInfo& r = *info.raster;
        o << "Raster:    " << r.path << " (" << r.driver << ")\n";
        o << "Size:      " << r.width << " x " << r.height << " pixels, " << r.band_count() << " band(s), blocks "
          << r.block_width << " x " << r.block_height << "\n";
        for (int b = 0; b < r.band_count(); ++b) {
            o << "Band " << b + 1 << ":    " << to_string(r.bands[b].type) << ", " << r.bands[b].color_interpretation;
            if (r.bands[b].nodata) o << ", nodata " << *r.bands[b].nodata;
            o << "\n";
        }
        o << "CRS:       " << (r.georeferenced ? crs_line(r.crs) : std::string("none (pixel coordinates)")) << "\n";
        o << "GSD:       " << r.gsd.x_m << " x " << r.gsd.y_m << " m\n";
        o << "Extent:    " << r.extent.min_x << ", " << r.extent.min_y << " - " << r.extent.max_x << ", " << r.extent.max_y << "\n";
    } else if (info.cloud) {
        const CloudInfo& c = *info.cloud;
        const LasHeader& h = c.header;
        o << "Cloud:     " << c.path << " (LAS " << h.version_major << "." << h.version_minor << ", point format "
          << h.point_format << ", " << h.point_record_length << " bytes/point)\n";
        o << "Points:    " << h.point_count << (h.has_color() ? ", RGB" : "") << (h.has_gps_time() ? ", GPS time" : "") << "\n";
        o << "CRS:       " << crs_line(c.crs) << (c.crs_source.empty() ? "" : " [from the " + c.crs_source + "]") << "\n";
        for (const std::string& w : c.crs_warnings) o << "Warning:   " << w << "\n";
        o << "Bounds:    x " << h.min[0] << " - " << h.max[0] << ", y " << h.min[1] << " - " << h.max[1] << ", z "
          << h.min[2] << " - " << h.max[2] << "\n";
        if (h.laz) {
            o << "LAZ:       compressor " << h.laz->compressor_name() << ", LASzip " << h.laz->version_major << "."
              << h.laz->version_minor << " r" << h.laz->version_revision << ", chunk size "
              << (h.laz->variable_chunks() ? std::string("variable") : std::to_string(h.laz->chunk_size)) << ", " << c.laz_chunks
              << " chunks" << (c.laz_chunk_table ? "" : " (no chunk table)") << "\n";
            o << "Items:     ";
            for (std::size_t i = 0; i < h.laz->items.size(); ++i)
                o << (i ? " + " : "") << to_string(h.laz->items[i]) << " (" << h.laz->items[i].size << " B)";
            o << "\n";
        }
        if (c.copc) {
            const CopcInfo& ci = c.copc->info;
            o << "COPC:      " << c.copc->nodes.size() << " nodes with points, levels 0-" << c.copc->max_level << ", "
              << c.copc->pages << " hierarchy page(s), root cube centre " << ci.center_x << ", " << ci.center_y << ", "
              << ci.center_z << " half size " << ci.halfsize << ", spacing " << ci.spacing << "\n";
        }
        for (auto [k, v] : c.class_counts) o << "Class " << k << ":   " << v << " points\n";
    } else if (info.vector) {
        const VectorInfo& v = *info.vector;
        o << "Vector:    " << v.path << " (" << v.driver << ")\n";
        for (const auto& l : v.layers) {
            o << "Layer:     " << l.name << ", " << l.geometry_type << ", " << l.feature_count << " features\n";
            o << "  CRS:     " << crs_line(l.crs) << "\n";
            if (l.extent)
                o << "  Extent:  " << l.extent->min_x << ", " << l.extent->min_y << " - " << l.extent->max_x << ", " << l.extent->max_y << "\n";
        }
    }
    return o.str();
}

}  // namespace cityforge
