#include "pipeline/footprints_run.hpp"

#include <chrono>
#include <cmath>
#include <memory>

#include "cloud/cloud_rasters.hpp"
#include "core/error.hpp"
#include "core/grid_fill.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"
#include "heights/building_heights.hpp"
#include "io/vector.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"
#include "segment/boundary_refine.hpp"
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

DetectionMode detection_mode_from_string(const std::string& s) {
    if (s == "auto") return DetectionMode::automatic;
    if (s == "ortho_cloud") return DetectionMode::ortho_cloud;
    if (s == "ortho_only") return DetectionMode::ortho_only;
    if (s == "cloud_only") return DetectionMode::cloud_only;
    throw Error("--mode", "must be auto, ortho_cloud, ortho_only or cloud_only, not '" + s + "'");
}
std::string to_string(DetectionMode m) {
    switch (m) {
        case DetectionMode::automatic: return "auto";
        case DetectionMode::ortho_cloud: return "ortho_cloud";
        case DetectionMode::ortho_only: return "ortho_only";
        case DetectionMode::cloud_only: return "cloud_only";
    }
    return "auto";
}

void FootprintsRunOptions::validate() const {
    if (cloud.empty() && ortho.empty()) throw Error("--cloud", "give a point cloud, an ortho (--ortho) or both");
    if ((mode == DetectionMode::ortho_cloud || mode == DetectionMode::cloud_only) && cloud.empty())
        throw Error("--mode", to_string(mode) + " needs a point cloud (--cloud)");
    if ((mode == DetectionMode::ortho_cloud || mode == DetectionMode::ortho_only) && ortho.empty())
        throw Error("--mode", to_string(mode) + " needs an ortho (--ortho)");
    if (refine_passes < 0 || refine_passes > 20) throw Error("--refine-passes", "must be between 0 and 20");
    if (!(ndsm_band_weight >= 0)) throw Error("--ndsm-weight", "must be >= 0");
    if (!(min_segment_building_share > 0 && min_segment_building_share <= 1)) throw Error("--min-segment-building-share", "must be in (0, 1]");
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

namespace {
// The ortho's bands (nodata pixels marked invalid), as read.
struct OrthoImage {
    Image<float> image;
    std::vector<uint8_t> valid;
};
OrthoImage read_ortho(RasterReader& reader) {
    const RasterInfo& info = reader.info();
    OrthoImage o{reader.read_all<float>(), {}};
    o.valid.assign(o.image.pixel_count(), 1);
    for (int b = 0; b < o.image.bands; ++b)
        if (const auto& nd = info.bands[b].nodata)
            for (std::size_t i = 0; i < o.valid.size(); ++i)
                if (o.image.band_data(b)[i] == static_cast<float>(*nd)) o.valid[i] = 0;
    return o;
}

// Watershed over-segmentation and region merging at one scale of the
// normalised bands, then boundary pixels moved to the segment of the closest
// colour (the first `colour_bands` bands); returns segments 1..count.
Image<uint32_t> segment_image(Image<float> normalised, int colour_bands, const std::vector<uint8_t>& valid, const WatershedOptions& watershed,
                              double scale, int refine_passes, uint32_t& count, const Progress& progress) {
    const Oversegmentation over = watershed_oversegment(normalised, valid, watershed, progress.sub(0.0, 0.6));
    RegionMergingOptions rmo;
    rmo.scales = {scale};
    if (!watershed.band_weights.empty()) rmo.band_weights = watershed.band_weights;
    const RegionMergingResult merged = merge_regions(normalised, over.labels, over.region_count, rmo, progress.sub(0.6, 1.0));
    count = merged.levels[0].regions_after;
    Image<uint32_t> segments = relabel(over.labels, merged.levels[0].label_of_input);
    refine_segment_boundaries(normalised, colour_bands, segments, count, refine_passes);
    return segments;
}
}  // namespace

FootprintsReport run_footprints(const std::string& output_path, const FootprintsRunOptions& o, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.validate();
    const std::string driver = vector_driver_for(output_path);
    FootprintsReport rep;
    DetectionMode mode = o.mode;
    if (mode == DetectionMode::automatic)
        mode = !o.cloud.empty() && !o.ortho.empty() ? DetectionMode::ortho_cloud : !o.cloud.empty() ? DetectionMode::cloud_only : DetectionMode::ortho_only;
    rep.mode = to_string(mode);
    GridSpec grid;
    CrsInfo crs;
    BuildingMask mask;
    Image<float> ndsm;  // empty in ortho-only mode
    double unit = 1.0, z_unit = 1.0;
    std::unique_ptr<RasterReader> ortho;
    if (!o.ortho.empty()) {
        ortho = std::make_unique<RasterReader>(o.ortho);
        const RasterInfo& info = ortho->info();
        grid = {info.transform, info.width, info.height};
        crs = info.crs;
        unit = crs.linear_unit_m;
    }
    BuildingCells cells;
    if (mode != DetectionMode::ortho_only) {
        const PreparedCloud pc = prepare_cloud(o.cloud, o.cloud_crs, ortho ? ortho->info().crs : CrsInfo{}, o.outliers, o.ground);
        crs = pc.crs;
        unit = pc.crs.linear_unit_m, z_unit = pc.crs.z_unit_m;
        if (!ortho) grid = grid_over_cloud(pc.cloud, o.mask.gsd_m / unit);
        progress(0.3, "cloud");
        CloudRasters rasters = rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, grid, unit);
        BuildingMaskOptions mo = o.mask;
        mo.gsd_m = std::abs(grid.transform.pixel_width) * unit;
        mo.min_height_m /= z_unit;
        cells = building_cells(rasters.ndsm, rasters.dsm, rasters.building_share, rasters.vegetation_share, mo);
        ndsm = std::move(rasters.ndsm);
        rep.used_classes = cells.used_classes;
    }
    BuildingMaskOptions mo = o.mask;
    mo.gsd_m = std::abs(grid.transform.pixel_width) * unit;
    mo.split_step_m /= z_unit;
    if (mode == DetectionMode::cloud_only) {
        mask = label_buildings(std::move(cells.cells), grid.width, grid.height, mo);
    } else {
        OrthoImage img = read_ortho(*ortho);
        Image<float> normalised = img.image;
        normalize_bands(normalised, img.valid);
        WatershedOptions wo = o.watershed;
        const int colour_bands = normalised.bands;
        if (mode == DetectionMode::ortho_cloud) {
            // The nDSM joins the image as one more band, so segments follow
            // height edges as well as colour edges.
            Image<float> with_height(normalised.width, normalised.height, normalised.bands + 1, 0.0f);
            std::copy(normalised.data.begin(), normalised.data.end(), with_height.data.begin());
            float* hb = with_height.band_data(normalised.bands);
            const double full = 20.0 / z_unit;
            // Gaps (dark roofs absorb pulses) are filled from around them:
            // a gap read as 0 m would look like ground.
            std::vector<double> filled(ndsm.data.begin(), ndsm.data.end());
            fill_gaps(filled, grid.width, grid.height);
            for (std::size_t i = 0; i < filled.size(); ++i)
                hb[i] = std::isnan(filled[i]) ? 0.0f : static_cast<float>(std::clamp(filled[i] / full, 0.0, 1.0) * 255.0);
            if (wo.band_weights.empty()) wo.band_weights.assign(static_cast<std::size_t>(normalised.bands), 1.0);
            wo.band_weights.resize(static_cast<std::size_t>(normalised.bands), 1.0);
            wo.band_weights.push_back(o.ndsm_band_weight);
            normalised = std::move(with_height);
        }
        const Image<uint32_t> segments = segment_image(std::move(normalised), colour_bands, img.valid, wo, o.segment_scale,
                                                       o.refine_passes, rep.segments, progress.sub(0.35, 0.55));
        std::vector<uint8_t> building;
        if (mode == DetectionMode::ortho_cloud) {
            // A segment is a building when most of its cells with their own
            // evidence are building cells of the cloud (the cloud decides
            // what, the image where); without any evidence, the filled cells
            // vote.
            const std::size_t ns = rep.segments + 1;
            std::vector<uint32_t> total(ns, 0), votes(ns, 0), seen(ns, 0), seen_votes(ns, 0);
            for (std::size_t k = 0; k < segments.data.size(); ++k) {
                const uint32_t sg = segments.data[k];
                ++total[sg], votes[sg] += cells.cells[k];
                if (cells.evidence[k]) ++seen[sg], seen_votes[sg] += cells.cells[k];
            }
            std::vector<uint8_t> is_building(ns, 0);
            for (std::size_t sg = 1; sg < ns; ++sg) {
                const double share = seen[sg] ? static_cast<double>(seen_votes[sg]) / seen[sg]
                                              : total[sg] ? static_cast<double>(votes[sg]) / total[sg] : 0.0;
                is_building[sg] = share >= o.min_segment_building_share;
            }
            building.assign(segments.data.size(), 0);
            for (std::size_t k = 0; k < segments.data.size(); ++k) building[k] = is_building[segments.data[k]];
            if (cells.used_classes) {
                // Classified clouds draw sharper edges than a pixel-quantised
                // image: the share of roof points in a cell places the edge
                // inside the pixel. Pixels along the segments' outline take
                // the cloud's own decision where it has evidence.
                const int w = grid.width, h = grid.height;
                std::vector<uint8_t> refined = building;
                for (int y = 0; y < h; ++y)
                    for (int x = 0; x < w; ++x) {
                        const std::size_t k = static_cast<std::size_t>(y) * w + x;
                        if (!cells.evidence[k]) continue;
                        bool edge = false;
                        for (int dy = -1; dy <= 1 && !edge; ++dy)
                            for (int dx = -1; dx <= 1 && !edge; ++dx) {
                                const int xx = x + dx, yy = y + dy;
                                if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
                                edge = building[static_cast<std::size_t>(yy) * w + xx] != building[k];
                            }
                        if (edge) refined[k] = cells.cells[k];
                    }
                building.swap(refined);
            }
        } else {
            SegmentClassifierOptions co = o.classifier;
            co.gsd_m = ortho->info().gsd.x_m;
            classify_segments(img.image, segments, rep.segments, co, building);
        }
        mask = label_buildings(std::move(building), grid.width, grid.height, mo);
    }
    if (!cells.step_dsm.data.empty()) split_at_height_steps(mask, cells.step_dsm, mo);
    rep.width = grid.width, rep.height = grid.height;
    progress(0.6, "detection");
    FootprintTable table = footprint_table(mask, ndsm, grid.transform, 0, 0, {}, rep.mode, unit, z_unit, crs, o);
    rep.buildings = table.features.size();
    rep.mean_abs_fit_area_error_pct = table.mean_abs_fit_area_error_pct;
    VectorWriteOptions wopt;
    wopt.driver = driver;
    write_polygon_features(output_path, crs, table.fields, table.features, wopt);
    rep.crs = crs.label();
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress(1.0, "written");
    return rep;
}

}  // namespace cityforge
