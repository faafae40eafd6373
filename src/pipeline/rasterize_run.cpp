#include "pipeline/rasterize_run.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <new>

#include "cloud/cloud_rasters.hpp"
#include "cloud/cloud_reader.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "core/memory.hpp"
#include "io/cloud_crs.hpp"
#include "pipeline/cloud_windows.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"

namespace cityforge {

void RasterizeOptions::validate() const {
    if (grid_raster.empty() && !(gsd_m > 0.0)) throw Error("--gsd", "must be > 0");
    outliers.validate();
    ground.validate();
    if (!(tile_m > 0) || !(overlap_m >= 0)) throw Error("--tile-m", "tiles must be > 0 m and the overlap >= 0 m");
}

namespace {
RasterizeReport rasterize_run_unguarded(const std::string& cloud_path, const std::string& out_dir, const RasterizeOptions& o,
                                        const Progress& progress);
}  // namespace

RasterizeReport rasterize_run(const std::string& cloud_path, const std::string& out_dir, const RasterizeOptions& o,
                              const Progress& progress) {
    try {
        return rasterize_run_unguarded(cloud_path, out_dir, o, progress);
    } catch (const std::bad_alloc&) {  // named: a bare "out of memory" does not say which input was too large
        throw OutOfMemory(cloud_path, "the cloud or its rasters do not fit in memory: read it window by window (--max-points-in-memory, "
                                      "--tile-m), use a coarser --gsd or crop it");
    }
}

namespace {
RasterizeReport rasterize_run_unguarded(const std::string& cloud_path, const std::string& out_dir, const RasterizeOptions& o,
                                        const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.validate();
    RasterizeReport rep;
    GridSpec grid;
    CrsInfo target;
    double unit = 0.0;  // ground metres per grid unit (Web Mercator: its scale at the grid's centre)
    if (!o.grid_raster.empty()) {
        // Cells, outlier distances and the ground filter's window are metres: a lon/lat grid
        // raster is read on its working grid (the UTM zone of its centre), as `footprints` reads it.
        RasterOpenOptions ro;
        ro.project_geographic = true;
        const RasterInfo info = read_raster_info(o.grid_raster, ro);
        if (info.warped)
            log::warning(o.grid_raster + ": a " + info.source_crs.label() + " grid; the rasters are written on its working grid in " + info.crs.label());
        grid = {info.transform, info.width, info.height};
        target = info.crs;
        unit = info.metres_per_unit;
    }
    CloudRasters r;
    CrsInfo out_crs;
    // By the point count only: the rasters cover the whole box anyway.
    const bool windows = read_cloud_by_windows(CloudReader(cloud_path), o.max_points_in_memory, 0.0);
    // Decisions on the whole cloud, made before it is read and alike in both
    // paths (cloud_windows.hpp): the grid over every point, the outlier limit
    // and the density measured on the central 400 m.
    const CrsInfo source = require_cloud_crs(cloud_path, o.cloud_crs);
    if (o.grid_raster.empty()) {
        if (source.geographic) throw Error(cloud_path, "the cloud is in a geographic CRS (" + source.label() + "); rasterizing needs metres: give --grid or --cloud-crs");
        const Extent bounds = cloud_point_bounds(cloud_path);
        unit = ground_metres_per_unit_at(source, bounds);
        grid = grid_over_extent(bounds, o.gsd_m / unit, 0, cloud_path);
    }
    const GeoTransform& gt = grid.transform;
    if (!o.grid_raster.empty()) {  // a grid the cloud does not reach gives no raster, not empty ones
        const MapPoint a = gt.pixel_to_map({0.0, 0.0}), b = gt.pixel_to_map({double(grid.width), double(grid.height)});
        const Extent g{std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
        const Extent c = cloud_bounds_in(cloud_path, o.cloud_crs, target);
        if (c.max_x < g.min_x || c.min_x > g.max_x || c.max_y < g.min_y || c.min_y > g.max_y)
            throw Error(cloud_path, "does not overlap " + o.grid_raster + ": cloud " + describe_extent(c, target) + ", " +
                                        std::filesystem::path(o.grid_raster).filename().string() + " " + describe_extent(g, target));
    }
    const CloudPlan plan = plan_cloud(cloud_path, o.cloud_crs, target, o.outliers, gt.pixel_to_map({grid.width / 2.0, grid.height / 2.0}));
    if (windows) {
        const double px = std::abs(gt.pixel_width) * unit;
        const double tile_m = window_tile_edge_m(o.tile_m, o.overlap_m, plan.density_m2, o.max_points_in_memory);
        const int tile = std::max(64, static_cast<int>(std::lround(tile_m / px))), overlap = static_cast<int>(std::ceil(o.overlap_m / px));
        WindowedRasters w = rasterize_cloud_by_windows(cloud_path, o.cloud_crs, target, grid, unit, plan.outliers, o.ground, tile, overlap,
                                                       progress.sub(0.0, 0.9));
        if (w.core_points == 0) throw Error(cloud_path, "no point of the cloud lies on the grid" + (o.grid_raster.empty() ? std::string() : " of " + o.grid_raster));
        r = std::move(w.rasters);
        out_crs = w.crs;
        rep.tiles = w.windows;
        rep.points = w.points, rep.ground_points = w.ground_points, rep.ground_from_classification = w.ground_from_classification;
    } else {
        const PreparedCloud pc = prepare_cloud(cloud_path, o.cloud_crs, target, plan.outliers, o.ground);
        progress(0.5, "cloud");
        r = rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, grid, unit);
        out_crs = pc.crs;
        rep.points = pc.cloud.size(), rep.ground_points = pc.ground_points, rep.ground_from_classification = pc.ground_from_classification;
    }
    progress(0.9, "rasters");
    ensure_directory(out_dir);
    namespace fs = std::filesystem;
    GeoTiffWriteOptions wo;
    wo.nodata = -9999.0;
    auto write = [&](const char* name, Image<float>& out, const char* what) {  // in place: no copy of a large grid
        for (float& v : out.data)
            if (std::isnan(v)) v = -9999.0f;
        wo.band_descriptions = {what};
        const std::string path = (fs::path(out_dir) / name).string();
        write_geotiff(path, out, grid.transform, out_crs.wkt, wo);
        return path;
    };
    rep.dsm_path = write("dsm.tif", r.dsm, "DSM: highest point z");
    rep.dtm_path = write("dtm.tif", r.dtm, "DTM: mean ground z, gaps interpolated");
    rep.ndsm_path = write("ndsm.tif", r.ndsm, "nDSM: DSM - DTM");
    rep.density_path = write("density.tif", r.density, "points per square metre");
    rep.width = grid.width, rep.height = grid.height;
    rep.crs = out_crs.label();
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress(1.0, "written");
    return rep;
}

}  // namespace

}  // namespace cityforge
