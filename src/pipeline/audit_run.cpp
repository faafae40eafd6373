#include "pipeline/audit_run.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <optional>
#include <tuple>
#include <nlohmann/json.hpp>
#include <sstream>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "crs/crs.hpp"
#include "cloud/cloud_reader.hpp"
#include "io/vector.hpp"

namespace cityforge {

std::vector<std::pair<std::string, double>> parse_gates(const std::string& text, const std::string& option) {
    std::vector<std::pair<std::string, double>> gates;
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, ',')) {
        if (item.empty()) continue;
        const auto eq = item.find('=');
        if (eq == std::string::npos) throw Error(option, "expected NAME=VALUE, got '" + item + "'");
        try {
            gates.emplace_back(item.substr(0, eq), std::stod(item.substr(eq + 1)));
        } catch (const std::exception&) {
            throw Error(option, "bad number in '" + item + "'");
        }
    }
    return gates;
}

void FootprintAuditOptions::validate() const {
    if (!(iou_threshold > 0.0 && iou_threshold <= 1.0)) throw Error("--iou", "must be in (0, 1]");
    static const char* known[] = {"precision", "recall", "f1", "iou", "completeness", "correctness", "quality"};
    for (const auto& [name, value] : fail_below)
        if (std::find(std::begin(known), std::end(known), name) == std::end(known))
            throw Error("--fail-below", "unknown measure '" + name + "' (precision, recall, f1, iou, completeness, correctness, quality)");
}

namespace {
std::vector<std::vector<Polygon>> parts_of(const PolygonLayer& layer) {
    std::vector<std::vector<Polygon>> out;
    for (const Feature& f : layer.features) out.push_back(f.geometry);
    return out;
}
}  // namespace

namespace {
// Reads both layers and brings the prediction into the reference's CRS.
struct LayerPair {
    PolygonLayer pred, ref;
    bool reprojected = false;
};
LayerPair read_pair(const std::string& pred_path, const std::string& ref_path, const std::string& pred_layer, const std::string& ref_layer) {
    LayerPair lp{read_polygon_layer(pred_path, pred_layer), read_polygon_layer(ref_path, ref_layer), false};
    if (lp.ref.crs.empty()) throw Error(ref_path, "reference footprints have no CRS");
    if (lp.pred.crs.empty()) throw Error(pred_path, "predicted footprints have no CRS");
    if (lp.ref.crs.geographic) throw Error(ref_path, "reference footprints are in a geographic CRS; areas need a projected CRS");
    if (!same_horizontal_crs(lp.pred.crs, lp.ref.crs)) {
        for (Feature& f : lp.pred.features)
            for (Polygon& p : f.geometry) {
                auto move = [&](Ring& r) {
                    std::vector<double> x, y, z;
                    for (const MapPoint& q : r) x.push_back(q.x), y.push_back(q.y), z.push_back(0.0);
                    transform_points(lp.pred.crs, lp.ref.crs, x, y, z, pred_path);
                    for (std::size_t i = 0; i < r.size(); ++i) r[i] = {x[i], y[i]};
                };
                move(p.outer);
                for (Ring& h : p.holes) move(h);
            }
        lp.reprojected = true;
    }
    return lp;
}

// Writes DIR/report.json and DIR/report.md (each atomically) and returns their paths.
std::pair<std::string, std::string> write_report(const std::string& out_dir, const nlohmann::json& j, const std::string& markdown) {
    ensure_directory(out_dir);
    namespace fs = std::filesystem;
    const std::string json_path = (fs::path(out_dir) / "report.json").string();
    const std::string md_path = (fs::path(out_dir) / "report.md").string();
    write_text_file(json_path, j.dump(2) + "\n");
    write_text_file(md_path, markdown);
    return {json_path, md_path};
}

int field_index(const PolygonLayer& layer, const std::string& name, const std::string& path) {
    for (std::size_t i = 0; i < layer.field_names.size(); ++i)
        if (layer.field_names[i] == name) return static_cast<int>(i);
    throw Error(path, "has no field '" + name + "'");
}
}  // namespace

FootprintAuditReport audit_footprints(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                      const FootprintAuditOptions& o) {
    o.validate();
    LayerPair lp = read_pair(pred_path, ref_path, o.pred_layer, o.ref_layer);
    const PolygonLayer& pred = lp.pred;
    const PolygonLayer& ref = lp.ref;
    FootprintAuditReport rep;
    rep.reprojected = lp.reprojected;
    rep.crs = ref.crs.label();
    rep.scores = match_footprints(parts_of(pred), parts_of(ref), o.iou_threshold);
    const FootprintScores& s = rep.scores;
    for (const auto& [name, minimum] : o.fail_below) {
        const double v = name == "precision" ? s.precision : name == "recall" ? s.recall : name == "f1" ? s.f1 : name == "iou" ? s.mean_iou
                       : name == "completeness" ? s.area_completeness : name == "correctness" ? s.area_correctness : s.area_quality;
        if (v < minimum) {
            rep.passed = false;
            std::ostringstream msg;
            msg << name << " " << v << " < " << minimum;
            rep.failed.push_back(msg.str());
        }
    }

    nlohmann::json j;
    j["audit"] = "footprints";
    j["predicted"] = {{"path", pred_path}, {"count", s.predicted}, {"reprojected", rep.reprojected}};
    j["reference"] = {{"path", ref_path}, {"count", s.reference}, {"crs", rep.crs}};
    j["iou_threshold"] = o.iou_threshold;
    j["passed"] = rep.passed;
    j["failed_gates"] = rep.failed;
    j["totals"] = {{"true_positives", s.true_positives}, {"false_positives", s.predicted - s.true_positives},
                   {"false_negatives", s.reference - s.true_positives}, {"precision", s.precision}, {"recall", s.recall},
                   {"f1", s.f1}, {"mean_iou", s.mean_iou}, {"mean_abs_area_error_pct", s.mean_abs_area_error_pct},
                   {"area_completeness", s.area_completeness}, {"area_correctness", s.area_correctness}, {"area_quality", s.area_quality}};
    nlohmann::json rows = nlohmann::json::array();
    for (const FootprintMatch& m : s.matches)
        rows.push_back({{"reference_fid", ref.fids[m.reference]}, {"predicted_fid", pred.fids[m.predicted]}, {"iou", m.iou},
                        {"area_error_pct", m.area_error_pct}});
    j["matches"] = rows;
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
    std::tie(rep.json_path, rep.markdown_path) = write_report(out_dir, j, md.str());
    return rep;
}

void HeightAuditOptions::validate() const {
    if (ref_field.empty()) throw Error("--ref-field", "name the reference height attribute");
    if (pred_field.empty()) throw Error("--pred-field", "name the predicted height attribute");
    if (!(iou_threshold > 0.0 && iou_threshold <= 1.0)) throw Error("--iou", "must be in (0, 1]");
}

HeightAuditReport audit_heights(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                const HeightAuditOptions& o) {
    o.validate();
    const LayerPair lp = read_pair(pred_path, ref_path, "", "");
    const int pf = field_index(lp.pred, o.pred_field, pred_path), rf = field_index(lp.ref, o.ref_field, ref_path);
    std::vector<std::vector<Polygon>> p, r;
    for (const Feature& f : lp.pred.features) p.push_back(f.geometry);
    for (const Feature& f : lp.ref.features) r.push_back(f.geometry);
    const FootprintScores scores = match_footprints(p, r, o.iou_threshold);
    HeightAuditReport rep;
    rep.matched = scores.true_positives, rep.reference = r.size();
    auto number = [](const AttributeValue& v) -> std::optional<double> {
        if (!std::holds_alternative<std::string>(v)) return std::nullopt;
        try {
            return std::stod(std::get<std::string>(v));
        } catch (const std::exception&) {
            return std::nullopt;
        }
    };
    double sum = 0, sum_abs = 0, sum2 = 0;
    for (const FootprintMatch& m : scores.matches) {
        const auto pv = number(lp.pred.features[m.predicted].values[pf]);
        const auto rv = number(lp.ref.features[m.reference].values[rf]);
        if (!pv || !rv) continue;
        HeightError e{lp.ref.fids[m.reference], lp.pred.fids[m.predicted], *pv, *rv, *pv - *rv};
        sum += e.error, sum_abs += std::abs(e.error), sum2 += e.error * e.error;
        rep.max_abs = std::max(rep.max_abs, std::abs(e.error));
        rep.rows.push_back(e);
    }
    rep.with_values = rep.rows.size();
    if (!rep.rows.empty()) {
        const double n = double(rep.rows.size());
        rep.mae = sum_abs / n, rep.rmse = std::sqrt(sum2 / n), rep.bias = sum / n;
    }
    nlohmann::json j;
    j["audit"] = "heights";
    j["predicted"] = {{"path", pred_path}, {"field", o.pred_field}, {"reprojected", lp.reprojected}};
    j["reference"] = {{"path", ref_path}, {"field", o.ref_field}, {"count", rep.reference}};
    j["totals"] = {{"matched", rep.matched}, {"with_values", rep.with_values}, {"mae_m", rep.mae}, {"rmse_m", rep.rmse},
                   {"bias_m", rep.bias}, {"max_abs_m", rep.max_abs}};
    nlohmann::json rows = nlohmann::json::array();
    for (const HeightError& e : rep.rows)
        rows.push_back({{"reference_fid", e.reference_fid}, {"predicted_fid", e.predicted_fid}, {"predicted_m", e.predicted},
                        {"reference_m", e.reference}, {"error_m", e.error}});
    j["buildings"] = rows;
    std::ostringstream md;
    md.precision(4);
    md << "# Height audit\n\n- predicted: `" << pred_path << "`, field `" << o.pred_field << "`\n- reference: `" << ref_path << "`, field `"
       << o.ref_field << "` (" << rep.reference << " footprints)\n- " << rep.matched << " footprints matched at IoU >= " << o.iou_threshold
       << ", " << rep.with_values << " with both values\n\n| measure | metres |\n|---|---|\n| MAE | " << rep.mae << " |\n| RMSE | "
       << rep.rmse << " |\n| bias (predicted - reference) | " << rep.bias << " |\n| max abs | " << rep.max_abs
       << " |\n\n| reference fid | predicted | reference | error |\n|---|---|---|---|\n";
    for (const HeightError& e : rep.rows) md << "| " << e.reference_fid << " | " << e.predicted << " | " << e.reference << " | " << e.error << " |\n";
    std::tie(rep.json_path, rep.markdown_path) = write_report(out_dir, j, md.str());
    return rep;
}

CloudAuditReport audit_clouds(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                              const CloudAuditOptions& o) {
    for (double t : o.taus_m)
        if (!(t > 0)) throw Error("--tau", "every tau must be > 0");
    std::string pred_wkt, ref_wkt;
    PointCloud pred = read_point_cloud(pred_path, &pred_wkt);
    const PointCloud ref = read_point_cloud(ref_path, &ref_wkt);
    const CrsInfo pred_crs = !o.pred_crs.empty() ? crs_from_user_input(o.pred_crs, "--pred-crs") : crs_from_wkt(pred_wkt, pred_path);
    const CrsInfo ref_crs = !o.ref_crs.empty() ? crs_from_user_input(o.ref_crs, "--ref-crs") : crs_from_wkt(ref_wkt, ref_path);
    if (pred_crs.empty() != ref_crs.empty())
        throw Error(pred_crs.empty() ? pred_path : ref_path, "point cloud has no CRS while the other has one; give it with --pred-crs/--ref-crs");
    CloudAuditReport rep;
    if (!ref_crs.empty() && !same_horizontal_crs(pred_crs, ref_crs)) {
        transform_points(pred_crs, ref_crs, pred.x, pred.y, pred.z, pred_path);
        rep.reprojected = true;
    }
    rep.crs = ref_crs.empty() ? "none (both clouds without CRS, assumed the same)" : ref_crs.label();
    const double unit = ref_crs.empty() ? 1.0 : ref_crs.linear_unit_m;
    std::vector<double> taus;
    for (double t : o.taus_m) taus.push_back(t / unit);
    rep.comparison = compare_clouds(pred, ref, taus);
    CloudComparison& c = rep.comparison;
    c.mean_pred_to_ref *= unit, c.mean_ref_to_pred *= unit, c.chamfer *= unit, c.chamfer_squared *= unit * unit;
    for (CloudFScore& s : c.scores) s.tau *= unit;

    nlohmann::json j;
    j["audit"] = "clouds";
    j["predicted"] = {{"path", pred_path}, {"points", c.predicted_points}, {"reprojected", rep.reprojected}};
    j["reference"] = {{"path", ref_path}, {"points", c.reference_points}, {"crs", rep.crs}};
    j["distances_m"] = {{"mean_pred_to_ref", c.mean_pred_to_ref}, {"mean_ref_to_pred", c.mean_ref_to_pred},
                        {"chamfer", c.chamfer}, {"chamfer_convention", "mean nearest distance pred->ref + mean ref->pred (metres)"},
                        {"chamfer_squared", c.chamfer_squared},
                        {"chamfer_squared_convention", "mean squared nearest distance both ways, summed (square metres)"}};
    nlohmann::json rows = nlohmann::json::array();
    for (const CloudFScore& s : c.scores) rows.push_back({{"tau_m", s.tau}, {"precision", s.precision}, {"recall", s.recall}, {"f_score", s.f_score}});
    j["f_scores"] = rows;
    std::ostringstream md;
    md.precision(4);
    md << "# Point cloud audit\n\n- predicted: `" << pred_path << "` (" << c.predicted_points << " points" << (rep.reprojected ? ", reprojected" : "")
       << ")\n- reference: `" << ref_path << "` (" << c.reference_points << " points, " << rep.crs << ")\n\n"
       << "| measure | value |\n|---|---|\n| mean distance pred -> ref (m) | " << c.mean_pred_to_ref << " |\n| mean distance ref -> pred (m) | "
       << c.mean_ref_to_pred << " |\n| chamfer (sum of both means, m) | " << c.chamfer << " |\n| chamfer, squared convention (m²) | "
       << c.chamfer_squared << " |\n\n| tau (m) | precision | recall | F-score |\n|---|---|---|---|\n";
    for (const CloudFScore& s : c.scores) md << "| " << s.tau << " | " << s.precision << " | " << s.recall << " | " << s.f_score << " |\n";
    std::tie(rep.json_path, rep.markdown_path) = write_report(out_dir, j, md.str());
    return rep;
}

}  // namespace cityforge
