#include "pipeline/heights_run.hpp"

#include <chrono>
#include <new>

#include "pipeline/cloud_windows.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "cloud/cloud_reader.hpp"
#include <cmath>
#include <map>
#include "core/error.hpp"
#include "core/memory.hpp"
#include "core/log.hpp"
#include "crs/crs.hpp"
#include "io/cloud_crs.hpp"
#include "io/vector.hpp"

namespace cityforge {

namespace {
const char* const kRealFields[] = {"ground_z", "roof_z_min", "roof_z_50p", "roof_z_70p", "roof_z_90p", "roof_z_max", "height_m",
                                   "point_density_m2", "nodata_fraction", "ground_buffer_m"};
}

// The fields heights writes after the source attributes, in output order (one list
// for the output table and for the fields an input may not bring along).
static const std::vector<FieldDefinition>& heights_own_field_definitions() {
    static const std::vector<FieldDefinition> defs = [] {
        std::vector<FieldDefinition> v;
        for (const char* n : kRealFields) v.push_back({n, FieldType::real});
        v.push_back({"n_points_roof", FieldType::integer});
        v.push_back({"n_points_ground", FieldType::integer});
        v.push_back({"height_quality", FieldType::string});
        v.push_back({"ground_method", FieldType::string});
        for (const char* n : {"ground_rmse_m", "ground_slope_deg"}) v.push_back({n, FieldType::real});
        v.push_back({"n_points_ground_outliers", FieldType::integer});
        // 3DBAG's names for the same values (absolute z in the vertical datum; 3DBAG 2 prefixes them with b3_).
        for (const char* n : {"h_maaiveld", "h_dak_min", "h_dak_50p", "h_dak_70p", "h_dak_max"}) v.push_back({n, FieldType::real});
        v.push_back({"z_crs", FieldType::string});
        return v;
    }();
    return defs;
}

const std::vector<std::string>& heights_output_fields() {
    static const std::vector<std::string> names = [] {
        std::vector<std::string> v{"source_fid"};
        for (const FieldDefinition& f : heights_own_field_definitions()) v.push_back(f.name);
        return v;
    }();
    return names;
}

PolygonLayer read_footprints_for_heights(const std::string& path, const std::string& cloud_path, const HeightsRunOptions& o) {
    PolygonLayer footprints = read_polygon_layer(path, o.footprint_layer);
    if (footprints.crs.geographic) {
        // Heights need metres: lon/lat footprints are worked on (and written) in the cloud's
        // projected CRS (its points then need no reprojection), else in their UTM zone.
        const CrsInfo cloud = resolve_cloud_crs(cloud_path, o.cloud_crs).crs;
        const std::string working = !cloud.empty() && !cloud.geographic && cloud.horizontal_epsg ? "EPSG:" + std::to_string(*cloud.horizontal_epsg) : "";
        const CrsInfo on = working_crs_for_layer(footprints, working, path);
        log::warning(path + ": lon/lat footprints (" + footprints.crs.label() + ") worked on and written in " + on.label());
        put_layer_on(footprints, on, path);
    }
    if (footprints.crs.empty()) throw Error(path, "footprints have no CRS (coordinate reference system); give the file one (ogr2ogr -a_srs EPSG:...)");
    std::vector<std::string> ours = heights_output_fields();
    ours.insert(ours.end(), o.later_fields.begin(), o.later_fields.end());
    drop_colliding_fields(footprints, ours, path);
    return footprints;
}

namespace {
// Centre of the footprints' bounding boxes: where the plan's sample is taken.
MapPoint footprints_centre(const std::vector<Extent>& extents) {
    Extent all = empty_extent();
    for (const Extent& e : extents) include(all, e);
    return {0.5 * (all.min_x + all.max_x), 0.5 * (all.min_y + all.max_y)};
}
}  // namespace

HeightsStage compute_heights_stage(const std::string& footprints_path, const std::string& cloud_path, const HeightsRunOptions& o,
                                   const Progress& progress) {
    o.heights.validate();
    PolygonLayer footprints = read_footprints_for_heights(footprints_path, cloud_path, o);
    progress(0.05, "footprints");
    std::vector<Extent> extents;
    for (const Feature& f : footprints.features) extents.push_back(parts_extent(f.geometry));
    // The outlier limit as a windowed run fixes it (cloud_windows.hpp): the same heights either way.
    const CloudPlan plan = plan_cloud(cloud_path, o.cloud_crs, footprints.crs, o.outliers, footprints_centre(extents));
    PreparedCloud cloud = prepare_cloud(cloud_path, o.cloud_crs, footprints.crs, plan.outliers, o.ground);
    check_footprint_overlap(cloud, cloud_path, extents, footprints_path);
    progress(0.5, "ground");
    return compute_heights_stage(std::move(footprints), std::move(cloud), o, progress.sub(0.5, 1.0));
}

HeightsStage compute_heights_stage(PolygonLayer footprints_in, PreparedCloud cloud, const HeightsRunOptions& o, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.heights.validate();
    HeightsStage st;
    HeightsRunReport& rep = st.report;
    st.footprints = std::move(footprints_in);
    const PolygonLayer& footprints = st.footprints;
    st.cloud = std::move(cloud);
    const PreparedCloud& pc = st.cloud;
    rep.points_read = pc.cloud.size();
    rep.reprojected = pc.reprojected;
    rep.removed_statistical = pc.removed_statistical;
    rep.removed_isolated = pc.removed_isolated;
    rep.restored_surface = pc.restored_surface;
    rep.ground_points = pc.ground_points;
    rep.ground_from_classification = pc.ground_from_classification;
    const CrsInfo& cloud_crs = pc.source_crs;
    rep.crs = pc.crs.label();

    HeightOptions ho = o.heights;
    Extent all = empty_extent();
    for (const Feature& f : footprints.features) include(all, parts_extent(f.geometry));
    ho.unit_m = ground_metres_per_unit_at(footprints.crs, all);  // ground metres (Web Mercator: cos(latitude))
    ho.z_unit_m = cloud_crs.z_unit_m;
    std::vector<std::vector<Polygon>> parts;
    parts.reserve(footprints.features.size());
    for (const Feature& f : footprints.features) parts.push_back(f.geometry);
    st.heights = compute_building_heights(pc.cloud, pc.keep, pc.is_ground, parts, ho, progress);
    const std::vector<BuildingHeight>& heights = st.heights;
    rep.buildings = heights.size();

    // Output: the source attributes, then ours.
    PolygonLayer& t = st.table;
    t.crs = pc.crs;
    std::vector<FieldDefinition> fields;
    fields.push_back({"source_fid", FieldType::integer});
    for (std::size_t i = 0; i < footprints.field_names.size(); ++i) fields.push_back({footprints.field_names[i], footprints.field_types[i]});
    for (const FieldDefinition& f : heights_own_field_definitions()) fields.push_back(f);
    for (const FieldDefinition& f : fields) t.field_names.push_back(f.name), t.field_types.push_back(f.type);
    const std::string z_crs = z_crs_label(cloud_crs);
    t.features.reserve(heights.size());
    auto opt = [](const std::optional<double>& v) { return v ? AttributeValue(*v) : AttributeValue(); };
    for (std::size_t i = 0; i < heights.size(); ++i) {
        const BuildingHeight& h = heights[i];
        Feature f;
        f.geometry = footprints.features[i].geometry;
        f.values.push_back(footprints.fids[i]);
        for (const AttributeValue& v : footprints.features[i].values) f.values.push_back(v);
        for (const auto& v : {opt(h.ground_z), opt(h.roof_z_min), opt(h.roof_z_50p), opt(h.roof_z_70p), opt(h.roof_z_90p),
                              opt(h.roof_z_max), opt(h.height_m), AttributeValue(h.point_density_m2),
                              AttributeValue(h.nodata_fraction), AttributeValue(h.ground_buffer_used_m)})
            f.values.push_back(v);
        f.values.push_back(h.n_points_roof);
        f.values.push_back(h.n_points_ground);
        f.values.push_back(h.height_quality);
        f.values.push_back(h.ground_method.empty() ? AttributeValue() : AttributeValue(h.ground_method));
        f.values.push_back(opt(h.ground_rmse_m));
        f.values.push_back(opt(h.ground_slope_deg));
        f.values.push_back(h.n_points_ground_outliers);
        for (const auto& v : {opt(h.ground_z), opt(h.roof_z_min), opt(h.roof_z_50p), opt(h.roof_z_70p), opt(h.roof_z_max)}) f.values.push_back(v);
        f.values.push_back(z_crs);
        ++rep.quality_counts[h.height_quality];
        t.features.push_back(std::move(f));
        t.fids.push_back(footprints.fids[i]);
    }
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return st;
}

namespace {

// Heights of `footprints` with the cloud read window by window (see
// HeightsRunOptions::max_points_in_memory); rows in the footprints' order.
HeightsStage tiled_heights_stage(PolygonLayer footprints, const std::string& footprints_path, const std::string& cloud_path, const HeightsRunOptions& o, const Progress& progress,
                                 std::size_t& tiles_used) {
    std::vector<Extent> ext(footprints.features.size());
    Extent all = empty_extent();
    for (std::size_t i = 0; i < ext.size(); ++i) include(all, ext[i] = parts_extent(footprints.features[i].geometry));
    const double unit = ground_metres_per_unit_at(footprints.crs, all);
    HeightsRunOptions ho = o;
    const CloudPlan plan = plan_cloud(cloud_path, o.cloud_crs, footprints.crs, o.outliers, footprints_centre(ext));  // one limit for every tile
    ho.outliers = plan.outliers;
    // Footprints grouped by the tile holding their bounding-box centre; tiles
    // small enough that a window holds about max_points_in_memory points.
    const double tile = window_tile_edge_m(o.tile_m, o.tile_margin_m, plan.density_m2, o.max_points_in_memory) / unit,
                 margin = o.tile_margin_m / unit;
    std::map<std::pair<int64_t, int64_t>, std::vector<std::size_t>> groups;
    for (std::size_t i = 0; i < ext.size(); ++i)
        groups[{static_cast<int64_t>(std::floor((0.5 * (ext[i].min_x + ext[i].max_x) - all.min_x) / tile)),
                static_cast<int64_t>(std::floor((0.5 * (ext[i].min_y + ext[i].max_y) - all.min_y) / tile))}]
            .push_back(i);
    HeightsStage out;
    out.footprints = footprints;
    std::vector<Feature> rows(footprints.features.size());
    std::vector<BuildingHeight> heights(footprints.features.size());
    std::size_t done = 0;
    bool first = true;
    Extent kept = empty_extent();  // the windows' kept points, for the footprints' check
    for (const auto& [key, members] : groups) {
        Extent w = empty_extent();
        PolygonLayer sub;
        sub.crs = footprints.crs, sub.field_names = footprints.field_names, sub.field_types = footprints.field_types;
        for (std::size_t i : members) {
            include(w, {ext[i].min_x - margin, ext[i].min_y - margin, ext[i].max_x + margin, ext[i].max_y + margin});
            sub.features.push_back(footprints.features[i]);
            sub.fids.push_back(footprints.fids[i]);
        }
        PreparedCloud pc = prepare_cloud(cloud_path, o.cloud_crs, footprints.crs, ho.outliers, ho.ground, &w);
        include(kept, kept_extent(pc));
        HeightsStage st = compute_heights_stage(std::move(sub), std::move(pc), ho);
        if (first) {
            out.table.crs = st.table.crs, out.table.field_names = st.table.field_names, out.table.field_types = st.table.field_types;
            out.report.crs = st.report.crs, out.report.ground_from_classification = st.report.ground_from_classification;
            out.cloud.crs = st.cloud.crs, out.cloud.source_crs = st.cloud.source_crs;
            first = false;
        }
        out.report.points_read += st.report.points_read, out.report.removed_statistical += st.report.removed_statistical;
        out.report.removed_isolated += st.report.removed_isolated, out.report.ground_points += st.report.ground_points;
        out.report.restored_surface += st.report.restored_surface;
        out.report.reprojected = out.report.reprojected || st.report.reprojected;
        for (std::size_t k = 0; k < members.size(); ++k) rows[members[k]] = std::move(st.table.features[k]), heights[members[k]] = std::move(st.heights[k]);
        done += members.size();
        progress(double(done) / double(ext.size()), "tiles");
    }
    tiles_used = groups.size();
    if (out.report.points_read == 0)
        throw Error(cloud_path, "no point of the cloud lies near the footprints of " + footprints_path + " (" + describe_extent(all, footprints.crs) + ")");
    // As held whole (check_footprint_overlap): footprints beyond every kept point are counted in a warning.
    check_footprints_within(kept, footprints.crs, cloud_path, ext, footprints_path);
    out.table.features = std::move(rows);
    out.table.fids = footprints.fids;
    out.heights = std::move(heights);
    for (const BuildingHeight& h : out.heights) ++out.report.quality_counts[h.height_quality];
    out.report.buildings = out.heights.size();
    return out;
}

}  // namespace

namespace {
HeightsRunReport run_heights_unguarded(const std::string& footprints_path, const std::string& cloud_path,
                                       const std::string& output_path, const HeightsRunOptions& o, const Progress& progress);
}  // namespace

HeightsRunReport run_heights(const std::string& footprints_path, const std::string& cloud_path,
                             const std::string& output_path, const HeightsRunOptions& o, const Progress& progress) {
    try {
        return run_heights_unguarded(footprints_path, cloud_path, output_path, o, progress);
    } catch (const std::bad_alloc&) {  // named: a bare "out of memory" does not say which input was too large
        throw OutOfMemory(cloud_path, "the cloud does not fit in memory: read it window by window (--max-points-in-memory, --tile-m)");
    }
}

namespace {
HeightsRunReport run_heights_unguarded(const std::string& footprints_path, const std::string& cloud_path,
                                       const std::string& output_path, const HeightsRunOptions& o, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::string driver = vector_driver_for(output_path);
    o.heights.validate();
    if (!(o.tile_m > 0) || !(o.tile_margin_m >= 4 * o.heights.ground_buffer_m))
        throw Error("--tile-m", "tiles must be > 0 m and their margin at least 4 x the ground buffer");
    HeightsStage st;
    std::size_t tiles = 1;
    // By windows also when the ground filter's grid over the cloud's box would
    // dwarf its points (a corridor across its box): each window's grid covers
    // the footprints of one tile.
    if (read_cloud_by_windows(CloudReader(cloud_path), o.max_points_in_memory, o.ground.cell)) {
        PolygonLayer footprints = read_footprints_for_heights(footprints_path, cloud_path, o);
        st = tiled_heights_stage(std::move(footprints), footprints_path, cloud_path, o, progress.sub(0.0, 0.95), tiles);
    } else {
        st = compute_heights_stage(footprints_path, cloud_path, o, progress.sub(0.0, 0.95));
    }
    HeightsRunReport rep = st.report;
    rep.tiles = tiles;
    rep.output_path = output_path;
    std::vector<FieldDefinition> fields;
    for (std::size_t i = 0; i < st.table.field_names.size(); ++i) fields.push_back({st.table.field_names[i], st.table.field_types[i]});
    VectorWriteOptions wo;
    wo.driver = driver;
    write_polygon_features(output_path, st.table.crs, fields, st.table.features, wo);
    progress(1.0, "written");
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
}
}  // namespace

}  // namespace cityforge
