#include "pipeline/rasterize_run.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>

#include "cloud/cloud_rasters.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"

namespace cityforge {

void RasterizeOptions::validate() const {
    if (grid_raster.empty() && !(gsd_m > 0.0)) throw Error("--gsd", "must be > 0");
    outliers.validate();
    ground.validate();
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
    }
    const PreparedCloud pc = prepare_cloud(cloud_path, o.cloud_crs, target, o.outliers, o.ground);
    progress(0.5, "cloud");
    if (o.grid_raster.empty()) grid = grid_over_cloud(pc.cloud, o.gsd_m / pc.crs.linear_unit_m);
    const CloudRasters r = rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, grid, pc.crs.linear_unit_m);
    progress(0.8, "rasters");
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
        write_geotiff(path, out, grid.transform, pc.crs.wkt, wo);
        return path;
    };
    rep.dsm_path = write("dsm.tif", r.dsm, "DSM: highest point z");
    rep.dtm_path = write("dtm.tif", r.dtm, "DTM: mean ground z, gaps interpolated");
    rep.ndsm_path = write("ndsm.tif", r.ndsm, "nDSM: DSM - DTM");
    rep.density_path = write("density.tif", r.density, "points per square metre");
    rep.width = grid.width, rep.height = grid.height;
    rep.crs = pc.crs.label();
    rep.points = pc.cloud.size();
    rep.ground_points = pc.ground_points;
    rep.ground_from_classification = pc.ground_from_classification;
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress(1.0, "written");
    return rep;
}

}  // namespace cityforge
