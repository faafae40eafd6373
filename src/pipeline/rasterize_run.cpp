#include "pipeline/rasterize_run.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>

#include "cloud/cloud_rasters.hpp"
#include "cloud/cloud_reader.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"

namespace cityforge {

void RasterizeOptions::validate() const {
    if (grid_raster.empty() && !(gsd_m > 0.0)) throw Error("--gsd", "must be > 0");
    outliers.validate();
    ground.validate();
    if (!(tile_m > 0) || !(overlap_m >= 0)) throw Error("--tile-m", "tiles must be > 0 m and the overlap >= 0 m");
}

RasterizeReport rasterize_run(const std::string& cloud_path, const std::string& out_dir, const RasterizeOptions& o,
                              const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.validate();
    RasterizeReport rep;
    GridSpec grid;
    CrsInfo target;
    if (!o.grid_raster.empty()) {
        const RasterInfo info = read_raster_info(o.grid_raster);
        grid = {info.transform, info.width, info.height};
        target = info.crs;
        // Cells, outlier distances and the ground filter's window are metres
        // (a geographic grid once failed with "outlier_limit_m: must be >= 0").
        if (target.geographic)
            throw Error(o.grid_raster, "the grid raster is in a geographic CRS (" + target.label() +
                                           "); rasterizing needs a projected CRS in metres: reproject it, e.g. gdalwarp -t_srs EPSG:<UTM zone>");
    }
    CloudRasters r;
    CrsInfo out_crs;
    const uint64_t announced = CloudReader(cloud_path).announced_points();
    if (!o.grid_raster.empty() && o.max_points_in_memory > 0 && announced > o.max_points_in_memory) {
        const double unit = target.linear_unit_m;
        OutlierFilterOptions outliers = o.outliers;
        const GeoTransform& gt = grid.transform;
        if (outliers.enabled && !(outliers.max_mean_distance > 0))
            outliers.max_mean_distance =
                sample_cloud(cloud_path, o.cloud_crs, target, o.outliers, gt.pixel_to_map({grid.width / 2.0, grid.height / 2.0})).outlier_limit_m;
        const double px = std::abs(gt.pixel_width) * unit;
        const int tile = std::max(64, static_cast<int>(std::lround(o.tile_m / px))), overlap = static_cast<int>(std::ceil(o.overlap_m / px));
        for (Image<float>* img : {&r.dsm, &r.dtm, &r.ndsm, &r.density}) *img = Image<float>(grid.width, grid.height, 1, NAN);
        const int tiles_x = (grid.width + tile - 1) / tile, tiles_y = (grid.height + tile - 1) / tile;
        rep.tiles = static_cast<std::size_t>(tiles_x) * tiles_y;
        std::size_t done = 0;
        for (int r0 = 0; r0 < grid.height; r0 += tile)
            for (int c0 = 0; c0 < grid.width; c0 += tile) {
                const int cw = std::min(tile, grid.width - c0), ch = std::min(tile, grid.height - r0);
                const int wc = std::max(0, c0 - overlap), wr = std::max(0, r0 - overlap);
                const int ww = std::min(grid.width, c0 + cw + overlap) - wc, wh = std::min(grid.height, r0 + ch + overlap) - wr;
                const MapPoint a = gt.pixel_to_map({double(wc), double(wr)}), b = gt.pixel_to_map({double(wc + ww), double(wr + wh)});
                const Extent window{std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
                const PreparedCloud pc = prepare_cloud(cloud_path, o.cloud_crs, target, outliers, o.ground, &window);
                rep.points += pc.cloud.size(), rep.ground_points += pc.ground_points;
                rep.ground_from_classification = pc.ground_from_classification;
                if (out_crs.empty() && !pc.crs.empty()) out_crs = pc.crs;
                if (pc.cloud.size() == 0) continue;
                const CloudRasters t = rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, GridSpec{gt.window(wc, wr), ww, wh}, unit);
                for (const auto& [dst, src] : {std::pair<Image<float>*, const Image<float>*>{&r.dsm, &t.dsm}, {&r.dtm, &t.dtm}, {&r.ndsm, &t.ndsm},
                                              {&r.density, &t.density}})
                    for (int y = 0; y < ch; ++y)
                        for (int x = 0; x < cw; ++x) dst->at(0, c0 + x, r0 + y) = src->at(0, c0 - wc + x, r0 - wr + y);
                progress(0.9 * double(++done) / double(rep.tiles), "tiles");
            }
        if (out_crs.empty()) throw Error(cloud_path, "no point of the cloud lies on the grid of " + o.grid_raster);
    } else {
        const PreparedCloud pc = prepare_cloud(cloud_path, o.cloud_crs, target, o.outliers, o.ground);
        progress(0.5, "cloud");
        if (o.grid_raster.empty()) grid = grid_over_cloud(pc.cloud, o.gsd_m / pc.crs.linear_unit_m, cloud_path);
        r = rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, grid, pc.crs.linear_unit_m);
        out_crs = pc.crs;
        rep.points = pc.cloud.size(), rep.ground_points = pc.ground_points, rep.ground_from_classification = pc.ground_from_classification;
    }
    progress(0.9, "rasters");
    ensure_directory(out_dir);
    namespace fs = std::filesystem;
    GeoTiffWriteOptions wo;
    wo.nodata = -9999.0;
    auto write = [&](const char* name, const Image<float>& img, const char* what) {
        Image<float> out = img;
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

}  // namespace cityforge
