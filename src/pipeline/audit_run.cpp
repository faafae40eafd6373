#include "pipeline/audit_run.hpp"

#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "crs/crs.hpp"
#include "io/vector.hpp"

namespace cityforge {

void FootprintAuditOptions::validate() const {
    if (!(iou_threshold > 0.0 && iou_threshold <= 1.0)) throw Error("--iou", "must be in (0, 1]");
}

namespace {
std::vector<std::vector<Polygon>> parts_of(const PolygonLayer& layer) {
    std::vector<std::vector<Polygon>> out;
    for (const Feature& f : layer.features) out.push_back(f.geometry);
    return out;
}
}  // namespace

FootprintAuditReport audit_footprints(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                      const FootprintAuditOptions& o) {
    o.validate();
    PolygonLayer pred = read_polygon_layer(pred_path, o.pred_layer);
    const PolygonLayer ref = read_polygon_layer(ref_path, o.ref_layer);
    if (ref.crs.empty()) throw Error(ref_path, "reference footprints have no CRS");
    if (pred.crs.empty()) throw Error(pred_path, "predicted footprints have no CRS");
    if (ref.crs.geographic) throw Error(ref_path, "reference footprints are in a geographic CRS; areas need a projected CRS");
    FootprintAuditReport rep;
    if (!same_horizontal_crs(pred.crs, ref.crs)) {
        // Reproject every vertex of the prediction into the reference CRS.
        for (Feature& f : pred.features)
            for (Polygon& p : f.geometry) {
                auto move = [&](Ring& r) {
                    std::vector<double> x, y, z;
                    for (const MapPoint& q : r) x.push_back(q.x), y.push_back(q.y), z.push_back(0.0);
                    transform_points(pred.crs, ref.crs, x, y, z, pred_path);
                    for (std::size_t i = 0; i < r.size(); ++i) r[i] = {x[i], y[i]};
                };
                move(p.outer);
                for (Ring& h : p.holes) move(h);
            }
        rep.reprojected = true;
    }
    rep.crs = ref.crs.label();
    rep.scores = match_footprints(parts_of(pred), parts_of(ref), o.iou_threshold);
    const FootprintScores& s = rep.scores;

    nlohmann::json j;
    j["audit"] = "footprints";
    j["predicted"] = {{"path", pred_path}, {"count", s.predicted}, {"reprojected", rep.reprojected}};
    j["reference"] = {{"path", ref_path}, {"count", s.reference}, {"crs", rep.crs}};
    j["iou_threshold"] = o.iou_threshold;
    j["totals"] = {{"true_positives", s.true_positives}, {"false_positives", s.predicted - s.true_positives},
                   {"false_negatives", s.reference - s.true_positives}, {"precision", s.precision}, {"recall", s.recall},
                   {"f1", s.f1}, {"mean_iou", s.mean_iou}, {"mean_abs_area_error_pct", s.mean_abs_area_error_pct},
                   {"area_completeness", s.area_completeness}, {"area_correctness", s.area_correctness}, {"area_quality", s.area_quality}};
    nlohmann::json rows = nlohmann::json::array();
    for (const FootprintMatch& m : s.matches)
        rows.push_back({{"reference_fid", ref.fids[m.reference]}, {"predicted_fid", pred.fids[m.predicted]}, {"iou", m.iou},
                        {"area_error_pct", m.area_error_pct}});
    j["matches"] = rows;
    ensure_directory(out_dir);
    namespace fs = std::filesystem;
    rep.json_path = (fs::path(out_dir) / "report.json").string();
    rep.markdown_path = (fs::path(out_dir) / "report.md").string();
    write_text_file(rep.json_path, j.dump(2) + "\n");
    std::ostringstream md;
    md.precision(4);
    md << "# Footprint audit\n\n"
       << "- predicted: `" << pred_path << "` (" << s.predicted << " footprints" << (rep.reprojected ? ", reprojected" : "") << ")\n"
       << "- reference: `" << ref_path << "` (" << s.reference << " footprints, " << rep.crs << ")\n"
       << "- matching: one-to-one, IoU >= " << o.iou_threshold << "\n\n"
       << "| measure | value |\n|---|---|\n"
       << "| true positives | " << s.true_positives << " |\n| precision | " << s.precision << " |\n| recall | " << s.recall
       << " |\n| F1 | " << s.f1 << " |\n| mean IoU | " << s.mean_iou << " |\n| mean abs. area error (%) | " << s.mean_abs_area_error_pct
       << " |\n| per-area completeness | " << s.area_completeness << " |\n| per-area correctness | " << s.area_correctness
       << " |\n| per-area quality | " << s.area_quality << " |\n\n"
       << "## Matches\n\n| reference fid | predicted fid | IoU | area error (%) |\n|---|---|---|---|\n";
    for (const FootprintMatch& m : s.matches)
        md << "| " << ref.fids[m.reference] << " | " << pred.fids[m.predicted] << " | " << m.iou << " | " << m.area_error_pct << " |\n";
    write_text_file(rep.markdown_path, md.str());
    return rep;
}

}  // namespace cityforge
