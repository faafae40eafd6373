#include "pipeline/roofs_run.hpp"

#include <chrono>
#include <tbb/parallel_for.h>

#include "core/error.hpp"
#include "core/log.hpp"
#include "crs/crs.hpp"

namespace cityforge {

void RoofsRunOptions::validate() const {
    heights.heights.validate();
    lod2.validate();
    model.validate();
}

const std::vector<FieldDefinition>& roof_output_fields() {
    static const std::vector<FieldDefinition> fields{
        {"roof_planes", FieldType::integer}, {"roof_slope_deg", FieldType::real},         {"roof_azimuth_deg", FieldType::real},
        {"lod2_rmse_m", FieldType::real},    {"lod2_median_residual_m", FieldType::real}, {"lod2_fallback", FieldType::string},
        {"lod2_plane_settings", FieldType::string}, {"lod2_kind", FieldType::string}};
    return fields;
}

CityModel build_lod2_model(const HeightsStage& st, const CrsInfo& crs, const RoofsRunOptions& o, const std::string& source,
                           RoofsRunReport& rep) {
    CityModel model = build_city_model(st.table, crs, o.model, source);

    const auto t1 = std::chrono::steady_clock::now();
    Lod2Options lo = o.lod2;
    lo.unit_m = model.crs.linear_unit_m * model.crs.ground_scale;  // ground metres per map unit
    lo.z_unit_m = st.cloud.source_crs.z_unit_m;
    const PointCloud& cloud = st.cloud.cloud;
    std::vector<Lod2Result> results(model.buildings.size());
    tbb::parallel_for(std::size_t(0), model.buildings.size(), [&](std::size_t i) {
        const Building& b = model.buildings[i];
        const BuildingHeight& h = st.heights[i];
        // No solid without a height: a building without roof points keeps its footprint only.
        if (!h.ground_z || !h.roof_z_70p || !b.height_m) return;
        std::vector<std::array<double, 3>> pts;
        pts.reserve(h.roof_points.size());
        for (uint32_t k : h.roof_points) pts.push_back({cloud.x[k], cloud.y[k], cloud.z[k]});
        const double flat = *h.roof_z_70p;
        results[i] = reconstruct_lod2(b.footprint, pts, *h.ground_z, flat, lo);
    });
    rep.lod2_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    double rmse_sum = 0;
    for (std::size_t i = 0; i < model.buildings.size(); ++i) {
        Building& b = model.buildings[i];
        const Lod2Result& r = results[i];
        const bool have = !r.solids.empty();
        auto num = [&](double v) { return have ? AttributeValue(v) : AttributeValue(); };
        b.attributes.emplace_back("roof_planes", have ? AttributeValue(int64_t(r.roof_planes)) : AttributeValue());
        b.attributes.emplace_back("roof_slope_deg", num(r.roof_slope_deg));
        b.attributes.emplace_back("roof_azimuth_deg", num(r.roof_azimuth_deg));
        b.attributes.emplace_back("lod2_rmse_m", num(r.rmse_m));
        b.attributes.emplace_back("lod2_median_residual_m", num(r.median_residual_m));
        b.attributes.emplace_back("lod2_fallback", have && r.fallback ? AttributeValue(r.fallback_reason) : AttributeValue());
        b.attributes.emplace_back("lod2_plane_settings", have && !r.fallback ? AttributeValue(r.attempt) : AttributeValue());
        b.attributes.emplace_back("lod2_kind", have ? AttributeValue(std::string(r.fallback ? "LOD1.2 flat roof" : "LOD2.2 roof planes"))
                                                    : AttributeValue());
        if (!have) continue;
        b.lod2 = r.solids;
        b.roof_type = r.roof_type;
        ++rep.roof_types[r.roof_type];
        if (r.fallback) ++rep.fallbacks;
        else ++rep.lod2, rmse_sum += r.rmse_m;
        complete_building(b, model.crs, o.model.validity);
    }
    for (const FieldDefinition& f : roof_output_fields()) model.attribute_types.emplace_back(f.name, f.type);
    rep.mean_rmse_m = rep.lod2 ? rmse_sum / double(rep.lod2) : 0.0;
    return model;
}

RoofsRunReport run_roofs(const std::string& footprints_path, const std::string& cloud_path, const std::string& out_dir,
                         const RoofsRunOptions& o, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.validate();
    RoofsRunReport rep;
    HeightsRunOptions ho = o.heights;
    ho.heights.keep_roof_points = true;
    // The roof attributes written below replace input fields of their names (re-runs).
    for (const FieldDefinition& f : roof_output_fields()) ho.later_fields.push_back(f.name);
    HeightsStage st = compute_heights_stage(footprints_path, cloud_path, ho, progress.sub(0.0, 0.6));
    rep.heights = st.report;
    CrsInfo crs = st.table.crs;
    if (!o.model.vertical_crs.empty() && !crs.vertical_epsg)
        crs = combine_with_vertical(crs, crs_from_user_input(o.model.vertical_crs, "--vertical-crs"));
    const CityModel model = build_lod2_model(st, crs, o, footprints_path, rep);
    progress(0.8, "roofs");
    rep.model = write_city_model(model, crs, out_dir, o.model, progress.sub(0.8, 1.0));
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
}

}  // namespace cityforge
