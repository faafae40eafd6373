#include "pipeline/footprints_run.hpp"

#include <chrono>
#include <cmath>

#include "cloud/cloud_rasters.hpp"
#include "core/error.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"
#include "heights/building_heights.hpp"
#include "io/vector.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"
#include "segment/region_merging.hpp"

namespace cityforge {

FootprintFit footprint_fit_from_string(const std::string& s) {
    if (s == "raw") return FootprintFit::raw;
    if (s == "rectangle") return FootprintFit::rectangle;
    if (s == "recursive") return FootprintFit::recursive;
    if (s == "regularised" || s == "regularized") return FootprintFit::regularised;
    throw Error("--fit", "must be raw, rectangle, recursive or regularised, not '" + s + "'");
}
std::string to_string(FootprintFit f) {
    switch (f) {
        case FootprintFit::raw: return "raw";
        case FootprintFit::rectangle: return "rectangle";
        case FootprintFit::recursive: return "recursive";
        case FootprintFit::regularised: return "regularised";
    }
    return "raw";
}

void FootprintsRunOptions::validate() const {
    if (cloud.empty() && ortho.empty()) throw Error("--cloud", "give a point cloud, an ortho (--ortho) or both");
    if (!(segment_scale > 0)) throw Error("--segment-scale", "must be > 0");
    if (!(simplify_m >= 0.0)) throw Error("--simplify-m", "must be >= 0");
    mask.validate();
}

std::vector<std::vector<Polygon>> vectorize_window(const Image<uint32_t>& labels, const GeoTransform& grid, int col0, int row0) {
    // Traced in pixel units, then placed with integer pixel offsets: every
    // window of a grid gives the very same coordinates for the same pixels.
    std::vector<std::vector<Polygon>> polys = vectorize_all(labels, GeoTransform{0.0, 1.0, 0.0, -1.0});
    auto place = [&](Ring& r) {
        for (MapPoint& q : r) q = grid.pixel_to_map({double(col0) + q.x, double(row0) - q.y});
    };
    for (auto& parts : polys)
        for (Polygon& p : parts) {
            place(p.outer);
            for (Ring& h : p.holes) place(h);
        }
    return polys;
}

FootprintTable footprint_table(const BuildingMask& mask, const Image<float>& ndsm, const GeoTransform& grid, int col0, int row0,
                               const std::vector<int64_t>& ids, const std::string& mode, double unit, double z_unit, const CrsInfo& crs,
                               const FootprintsRunOptions& o) {
    FootprintTable table;
    const auto polygons = vectorize_window(mask.labels, grid, col0, row0);
    // Median nDSM per building, a first height cue for the output.
    std::vector<std::vector<double>> heights(mask.count + 1);
    for (std::size_t k = 0; k < mask.labels.data.size(); ++k)
        if (const uint32_t id = mask.labels.data[k]; id && !ndsm.data.empty() && !std::isnan(ndsm.data[k])) heights[id].push_back(ndsm.data[k]);
    table.fields = {
        {"id", FieldType::integer},           {"mode", FieldType::string},         {"fit", FieldType::string},
        {"status", FieldType::string},        {"reason", FieldType::string},       {"area_m2", FieldType::real},
        {"raw_area_m2", FieldType::real},     {"geodesic_area_m2", FieldType::real}, {"perimeter_m", FieldType::real},
        {"orientation_deg", FieldType::real}, {"fit_area_error_pct", FieldType::real}, {"fit_iou", FieldType::real},
        {"n_vertices", FieldType::integer},   {"height_p50_m", FieldType::real}};
    std::vector<Feature>& features = table.features;
    const std::string& rep_mode = mode;
    const GeoTransform& grid_transform = grid;
    double error_sum = 0.0;
    for (uint32_t id = 1; id <= mask.count; ++id) {
        if (polygons[id].empty()) continue;
        const Polygon raw = simplify_polygon(polygons[id][0], o.simplify_m / unit);
        Feature f;
        std::string status = "ok", reason;
        Polygon out = raw;
        double orientation = 0.0, err = 0.0, iou = 1.0;
        try {
            const OrientedRectangle rect = minimum_area_rectangle(raw);
            orientation = rect.orientation_deg;
            if (o.fit == FootprintFit::rectangle) {
                out = rect.polygon();
                const FitAccuracy acc = fit_accuracy(raw, out);
                err = acc.area_error_pct, iou = acc.iou;
            } else if (o.fit == FootprintFit::regularised) {
                RegularizeOptions go = o.regularize;
                go.merge_offset /= unit, go.min_edge /= unit, go.match_area_max_offset /= unit;
                // Pixel staircases must be straightened before edges can be
                // snapped: simplify with at least 1.5 pixels.
                const double straighten = std::max(o.simplify_m / unit, 1.5 * std::abs(grid_transform.pixel_width));
                out = regularize_polygon(simplify_polygon(polygons[id][0], straighten), rect.orientation_deg, go);
                if (go.match_area_max_offset > 0) out = match_area(out, polygon_area(raw), go.match_area_max_offset);
                const FitAccuracy acc = fit_accuracy(raw, out);
                err = acc.area_error_pct, iou = acc.iou;
            } else if (o.fit == FootprintFit::recursive) {
                RecursiveFitOptions ro = o.recursive;
                ro.min_rectangle_area /= unit * unit;
                ro.match_area_max_offset /= unit;
                const RecursiveFit rf = recursive_rectangle_fit(raw, ro);
                out = rf.polygon;
                err = rf.accuracy.area_error_pct, iou = rf.accuracy.iou;
            }
        } catch (const Error& e) {
            status = "fit_failed", reason = e.what();
        }
        orient_polygon(out);
        std::vector<Ring> rings{out.outer};
        for (const Ring& h : out.holes) rings.push_back(h);
        std::size_t vertices = out.outer.size();
        for (const Ring& h : out.holes) vertices += h.size();
        std::vector<double>& hv = heights[id];
        const std::optional<double> h50 = percentile(hv, 50.0);
        f.geometry = {out};
        f.values = {ids.empty() ? int64_t(features.size() + 1) : ids[id], rep_mode, to_string(o.fit), status, reason,
                    polygon_area(out) * unit * unit, polygon_area(raw) * unit * unit, geodesic_area_m2(rings, crs),
                    polygon_perimeter(out) * unit, orientation, err, iou, int64_t(vertices),
                    h50 ? AttributeValue(*h50 * z_unit) : AttributeValue()};
        error_sum += std::abs(err);
        features.push_back(std::move(f));
    }
    table.mean_abs_fit_area_error_pct = features.empty() ? 0.0 : error_sum / static_cast<double>(features.size());
    return table;
}

FootprintsReport run_footprints(const std::string& output_path, const FootprintsRunOptions& o, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.validate();
    const std::string driver = vector_driver_for(output_path);
    FootprintsReport rep;
    GridSpec grid;
    CrsInfo crs;
    BuildingMask mask;
    Image<float> ndsm;  // empty in ortho-only mode
    double unit = 1.0, z_unit = 1.0;
    if (!o.cloud.empty()) {
        rep.mode = "cloud_only";
        CrsInfo target;
        if (!o.ortho.empty()) {
            const RasterInfo info = read_raster_info(o.ortho);
            grid = {info.transform, info.width, info.height};
            target = info.crs;
        }
        const PreparedCloud pc = prepare_cloud(o.cloud, o.cloud_crs, target, o.outliers, o.ground);
        crs = pc.crs;
        unit = pc.crs.linear_unit_m, z_unit = pc.crs.z_unit_m;
        if (o.ortho.empty()) grid = grid_over_cloud(pc.cloud, o.mask.gsd_m / unit);
        progress(0.4, "cloud");
        CloudRasters rasters = rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, grid, unit);
        BuildingMaskOptions mo = o.mask;
        mo.gsd_m = std::abs(grid.transform.pixel_width) * unit;
        mo.min_height_m /= z_unit;
        mask = detect_buildings(rasters.ndsm, rasters.dsm, rasters.building_share, rasters.vegetation_share, mo);
        ndsm = std::move(rasters.ndsm);
    } else {
        // Ortho-only: watershed + region merging at one scale, then segment rules.
        rep.mode = "ortho_only";
        RasterReader reader(o.ortho);
        const RasterInfo& info = reader.info();
        grid = {info.transform, info.width, info.height};
        crs = info.crs;
        unit = crs.linear_unit_m;
        Image<float> image = reader.read_all<float>();
        std::vector<uint8_t> valid(image.pixel_count(), 1);
        for (int b = 0; b < image.bands; ++b)
            if (const auto& nd = info.bands[b].nodata)
                for (std::size_t i = 0; i < valid.size(); ++i)
                    if (image.band_data(b)[i] == static_cast<float>(*nd)) valid[i] = 0;
        Image<float> normalised = image;
        normalize_bands(normalised, valid);
        const Oversegmentation over = watershed_oversegment(normalised, valid, o.watershed, progress.sub(0.05, 0.3));
        RegionMergingOptions rmo;
        rmo.scales = {o.segment_scale};
        const RegionMergingResult merged = merge_regions(normalised, over.labels, over.region_count, rmo, progress.sub(0.3, 0.4));
        const Image<uint32_t> segments = relabel(over.labels, merged.levels[0].label_of_input);
        SegmentClassifierOptions co = o.classifier;
        co.gsd_m = info.gsd.x_m;
        std::vector<uint8_t> building;
        classify_segments(image, segments, merged.levels[0].regions_after, co, building);
        BuildingMaskOptions mo = o.mask;
        mo.gsd_m = info.gsd.x_m;
        mask = label_buildings(std::move(building), grid.width, grid.height, mo);
    }
    rep.width = grid.width, rep.height = grid.height;
    rep.used_classes = mask.used_classes;
    progress(0.6, "detection");
    FootprintTable table = footprint_table(mask, ndsm, grid.transform, 0, 0, {}, rep.mode, unit, z_unit, crs, o);
    rep.buildings = table.features.size();
    rep.mean_abs_fit_area_error_pct = table.mean_abs_fit_area_error_pct;
    VectorWriteOptions wo;
    wo.driver = driver;
    write_polygon_features(output_path, crs, table.fields, table.features, wo);
    rep.crs = crs.label();
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress(1.0, "written");
    return rep;
}

}  // namespace cityforge
