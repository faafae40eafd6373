#include "pipeline/audit_run.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>

#include "audit/report_html.hpp"
#include "cloud/cloud_reader.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "core/version.hpp"
#include "crs/crs.hpp"
#include "io/cloud_crs.hpp"
#include "io/vector.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/quicklook.hpp"
#include "raster/raster.hpp"

namespace cityforge {

std::vector<std::string> footprint_audit_measures() {
    return {"precision", "recall", "f1", "object_quality", "iou", "completeness", "correctness", "quality", "area_error_pct", "polis"};
}
std::vector<std::string> rectangle_audit_measures() { return {"mean_abs_error_pct", "max_abs_error_pct", "mean_error_pct"}; }
std::vector<std::string> height_audit_measures() { return {"mae", "rmse", "bias", "abs_bias", "max_abs", "coverage"}; }
std::vector<std::string> cloud_audit_measures(const std::vector<double>& taus_m) {
    std::vector<std::string> m{"chamfer", "chamfer_squared", "mean_pred_to_ref", "mean_ref_to_pred"};
    for (double t : taus_m)
        for (const char* k : {"precision@", "recall@", "f@"}) m.push_back(k + format_number(t, 6));
    return m;
}

void FootprintAuditOptions::validate() const {
    if (!(iou_threshold > 0.0 && iou_threshold <= 1.0)) throw Error("--iou", "must be in (0, 1]");
    check_gate_names(gates, footprint_audit_measures());
}
void RectangleAuditOptions::validate() const {
    if (!(iou_threshold > 0.0 && iou_threshold <= 1.0)) throw Error("--iou", "must be in (0, 1]");
    if (original_path.empty() && original_area_field.empty()) throw Error("--original-area-field", "name the original-area attribute or give --original");
    check_gate_names(gates, rectangle_audit_measures());
}
void HeightAuditOptions::validate() const {
    if (ref_field.empty()) throw Error("--ref-field", "name the reference height attribute");
    if (pred_field.empty()) throw Error("--pred-field", "name the predicted height attribute");
    if (!(iou_threshold > 0.0 && iou_threshold <= 1.0)) throw Error("--iou", "must be in (0, 1]");
    check_gate_names(gates, height_audit_measures());
}
void CloudAuditOptions::validate() const {
    if (taus_m.empty()) throw Error("--tau", "give at least one distance threshold");
    for (double t : taus_m)
        if (!(t > 0)) throw Error("--tau", "every tau must be > 0");
    check_gate_names(gates, cloud_audit_measures(taus_m));
}

namespace {

using Parts = std::vector<std::vector<Polygon>>;

Parts parts_of(const PolygonLayer& layer) {
    Parts out;
    out.reserve(layer.features.size());
    for (const Feature& f : layer.features) out.push_back(f.geometry);
    return out;
}


// A Markdown table cell: a '|' in the text (as in "mean |area error|") would end the cell.
std::string md_cell(const std::string& text) {
    std::string out;
    for (char c : text) {
        if (c == '|') out += '\\';
        out += c;
    }
    return out;
}

// Predictions and references side by side in one CRS that do not meet give no measure, only zeros:
// an error naming both files and their extents. An empty side (no feature, no point) is left to the
// measures (nothing predicted is a result).
void require_extents_overlap(const Extent& pred, const Extent& ref, const CrsInfo& crs, const std::string& pred_path,
                             const std::string& ref_path) {
    const auto empty = [](const Extent& e) { return !(e.min_x <= e.max_x && e.min_y <= e.max_y); };
    if (empty(pred) || empty(ref)) return;
    if (pred.max_x < ref.min_x || ref.max_x < pred.min_x || pred.max_y < ref.min_y || ref.max_y < pred.min_y)
        throw Error(pred_path, "does not overlap the reference " + ref_path + ": predicted " + describe_extent(pred, crs) + ", reference " +
                                   describe_extent(ref, crs) + "; nothing to compare");
}

// Reads both layers and brings the prediction into the reference's CRS.
struct LayerPair {
    PolygonLayer pred, ref;
    bool reprojected = false;
};
LayerPair read_pair(const std::string& pred_path, const std::string& ref_path, const std::string& pred_layer, const std::string& ref_layer) {
    LayerPair lp{read_polygon_layer(pred_path, pred_layer), read_polygon_layer(ref_path, ref_layer), false};
    if (lp.ref.crs.empty()) throw Error(ref_path, "reference footprints have no CRS");
    if (lp.pred.crs.empty()) throw Error(pred_path, "predicted footprints have no CRS");
    // Compared in the reference's CRS; lon/lat references (OpenStreetMap) on the prediction's projected
    // CRS, else on their UTM zone: IoU, areas and PoLiS need metres.
    if (lp.ref.crs.geographic)
        put_layer_on(lp.ref, lp.pred.crs.geographic ? working_crs_for_layer(lp.ref, {}, ref_path) : lp.pred.crs, ref_path);
    lp.reprojected = !same_horizontal_crs(lp.pred.crs, lp.ref.crs);
    put_layer_on(lp.pred, lp.ref.crs, pred_path);
    Extent pe = empty_extent(), re = empty_extent();
    for (const Feature& f : lp.pred.features) include(pe, parts_extent(f.geometry));
    for (const Feature& f : lp.ref.features) include(re, parts_extent(f.geometry));
    require_extents_overlap(pe, re, lp.ref.crs, pred_path, ref_path);
    return lp;
}

int field_index(const PolygonLayer& layer, const std::string& name, const std::string& path) {
    for (std::size_t i = 0; i < layer.field_names.size(); ++i)
        if (layer.field_names[i] == name) return static_cast<int>(i);
    throw Error(path, "has no field '" + name + "'");
}

std::optional<double> number(const AttributeValue& v) {
    if (std::holds_alternative<double>(v)) return std::get<double>(v);
    if (std::holds_alternative<int64_t>(v)) return double(std::get<int64_t>(v));
    if (!std::holds_alternative<std::string>(v)) return std::nullopt;
    try {
        std::size_t used = 0;
        const double d = std::stod(std::get<std::string>(v), &used);
        return std::isfinite(d) ? std::optional<double>(d) : std::nullopt;
    } catch (const std::exception&) {
        return std::nullopt;
    }
}

// JSON number, or null for NaN/inf (JSON has no NaN).
nlohmann::json jnum(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

// Evaluates the gates, adds the common members to the JSON and writes
// DIR/report.json, report.md and report.html (each atomically).
AuditOutput finish_report(const std::string& out_dir, nlohmann::json& j, std::string markdown, HtmlReport& html,
                          const std::map<std::string, double>& measures, const std::vector<AuditGate>& gates) {
    AuditOutput out;
    out.measures = measures;
    out.gates = evaluate_gates(gates, measures);
    j["cityforge_version"] = version();
    nlohmann::json m = nlohmann::json::object();
    for (const auto& [k, v] : measures) m[k] = jnum(v);
    j["measures"] = m;
    nlohmann::json g = nlohmann::json::array();
    for (const AuditGate& gate : gates) g.push_back({{"measure", gate.measure}, {"limit", gate.limit}, {"fail_if", gate.minimum ? "below" : "above"}});
    j["gates"] = {{"passed", out.gates.passed}, {"failed", out.gates.failed}, {"gates", g}};

    std::string verdict;
    if (!gates.empty()) {
        verdict = out.gates.passed ? "All gates passed." : "Gates failed: ";
        for (std::size_t i = 0; i < out.gates.failed.size(); ++i) verdict += (i ? ", " : "") + out.gates.failed[i];
        markdown += "\n**" + verdict + "**\n";
        html.heading("Gates");
        html.paragraph(verdict);
    }
    ensure_directory(out_dir);
    namespace fs = std::filesystem;
    out.json_path = (fs::path(out_dir) / "report.json").string();
    out.markdown_path = (fs::path(out_dir) / "report.md").string();
    out.html_path = (fs::path(out_dir) / "report.html").string();
    write_text_file(out.json_path, j.dump(2) + "\n");
    write_text_file(out.markdown_path, markdown);
    write_text_file(out.html_path, html.render());
    return out;
}

// A number for the tables; n/a for a value that is not defined (NaN: a mean over no match).
std::string fmt(double v, int digits = 4) { return std::isfinite(v) ? format_number(v, digits) : std::string("n/a"); }

// Picture of `ortho` under the map, when it shares the reference CRS.
std::optional<MapPicture> background_for(const std::string& ortho, const CrsInfo& crs, const Parts& shapes) {
    if (ortho.empty()) return std::nullopt;
    const RasterInfo info = read_raster_info(ortho);
    if (!same_horizontal_crs(info.crs, crs))
        throw Error(ortho, "ortho CRS (" + info.crs.label() + ") differs from the reference footprints' (" + crs.label() + ")");
    Extent e = empty_extent();
    for (const auto& parts : shapes) include(e, parts_extent(parts));
    if (!(e.max_x > e.min_x)) return std::nullopt;
    const double pad = 0.03 * std::max(e.width(), e.height());
    e.min_x -= pad, e.min_y -= pad, e.max_x += pad, e.max_y += pad;
    const Quicklook q = render_quicklook_png(ortho, e, 1024);
    return MapPicture{q.png, q.extent};
}

}  // namespace

FootprintAuditReport audit_footprints(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                      const FootprintAuditOptions& o) {
    o.validate();
    const LayerPair lp = read_pair(pred_path, ref_path, o.pred_layer, o.ref_layer);
    const PolygonLayer& pred = lp.pred;
    const PolygonLayer& ref = lp.ref;
    FootprintAuditReport rep;
    rep.reprojected = lp.reprojected;
    rep.crs = ref.crs.label();
    const Parts pp = parts_of(pred), rp = parts_of(ref);
    rep.scores = match_footprints(pp, rp, o.iou_threshold);
    const FootprintScores& s = rep.scores;
    std::map<std::string, double> measures{{"precision", s.precision},        {"recall", s.recall},
                                           {"f1", s.f1},                      {"completeness", s.area_completeness},
                                           {"object_quality", s.object_quality},
                                           {"correctness", s.area_correctness}, {"quality", s.area_quality}};
    if (s.true_positives) measures["iou"] = s.mean_iou, measures["area_error_pct"] = s.mean_abs_area_error_pct, measures["polis"] = s.mean_polis;

    nlohmann::json j;
    j["audit"] = "footprints";
    j["predicted"] = {{"path", pred_path}, {"count", s.predicted}, {"reprojected", rep.reprojected}, {"crs", pred.crs.label()}};
    j["reference"] = {{"path", ref_path}, {"count", s.reference}, {"crs", rep.crs}};
    j["iou_threshold"] = o.iou_threshold;
    // Means over matches are not defined without a match: null, "n/a" in the tables.
    const bool matched = s.true_positives > 0;
    auto over_matches = [&](double v) { return matched ? nlohmann::json(v) : nlohmann::json(nullptr); };
    auto fmt_matches = [&](double v) { return matched ? fmt(v) : std::string("n/a"); };
    j["totals"] = {{"true_positives", s.true_positives}, {"false_positives", s.predicted - s.true_positives},
                   {"false_negatives", s.reference - s.true_positives}, {"precision", s.precision}, {"recall", s.recall},
                   {"f1", s.f1}, {"object_quality", s.object_quality}, {"mean_iou", over_matches(s.mean_iou)},
                   {"mean_abs_area_error_pct", over_matches(s.mean_abs_area_error_pct)},
                   {"mean_polis", over_matches(s.mean_polis)}, {"polis_unit", "CRS units (" + std::to_string(ref.crs.linear_unit_m) + " m)"},
                   {"area_completeness", s.area_completeness}, {"area_correctness", s.area_correctness}, {"area_quality", s.area_quality}};
    nlohmann::json rows = nlohmann::json::array();
    std::vector<std::vector<std::string>> table;
    std::vector<double> ious, errs, pred_area, ref_area, iou_of_pred(pp.size(), NAN);
    std::vector<uint8_t> ref_matched(rp.size(), 0);
    for (const FootprintMatch& m : s.matches) {
        rows.push_back({{"reference_fid", ref.fids[m.reference]}, {"predicted_fid", pred.fids[m.predicted]}, {"iou", m.iou},
                        {"area_error_pct", m.area_error_pct}, {"polis", m.polis}});
        table.push_back({std::to_string(ref.fids[m.reference]), std::to_string(pred.fids[m.predicted]), fmt(m.iou), fmt(m.area_error_pct),
                         fmt(m.polis)});
        ious.push_back(m.iou), errs.push_back(m.area_error_pct);
        ref_area.push_back(parts_area(rp[m.reference])), pred_area.push_back(parts_area(pp[m.predicted]));
        iou_of_pred[m.predicted] = m.iou;
        ref_matched[m.reference] = 1;
    }
    j["matches"] = rows;
    nlohmann::json unmatched_ref = nlohmann::json::array(), unmatched_pred = nlohmann::json::array();
    Parts missed;
    for (std::size_t i = 0; i < rp.size(); ++i)
        if (!ref_matched[i]) unmatched_ref.push_back(ref.fids[i]), missed.push_back(rp[i]);
    for (std::size_t i = 0; i < pp.size(); ++i)
        if (std::isnan(iou_of_pred[i])) unmatched_pred.push_back(pred.fids[i]);
    j["false_negative_fids"] = unmatched_ref;
    j["false_positive_fids"] = unmatched_pred;

    const std::vector<std::vector<std::string>> totals{
        {"true positives", std::to_string(s.true_positives)},
        {"false positives", std::to_string(s.predicted - s.true_positives)},
        {"false negatives", std::to_string(s.reference - s.true_positives)},
        {"precision (per-object correctness)", fmt(s.precision)}, {"recall (per-object completeness)", fmt(s.recall)}, {"F1", fmt(s.f1)},
        {"per-object quality", fmt(s.object_quality)}, {"mean IoU", fmt_matches(s.mean_iou)},
        {"mean |area error| (%)", fmt_matches(s.mean_abs_area_error_pct)}, {"mean PoLiS (CRS units)", fmt_matches(s.mean_polis)},
        {"per-area completeness", fmt(s.area_completeness)}, {"per-area correctness", fmt(s.area_correctness)},
        {"per-area quality", fmt(s.area_quality)}};
    std::ostringstream md;
    md << "# Footprint audit\n\n"
       << "- predicted: `" << pred_path << "` (" << s.predicted << " footprints" << (rep.reprojected ? ", reprojected" : "") << ")\n"
       << "- reference: `" << ref_path << "` (" << s.reference << " footprints, " << rep.crs << ")\n"
       << "- matching: one-to-one, IoU >= " << o.iou_threshold << " (greedy by IoU, the SpaceNet rule)\n\n| measure | value |\n|---|---|\n";
    for (const auto& r : totals) md << "| " << md_cell(r[0]) << " | " << md_cell(r[1]) << " |\n";
    md << "\n## Matches\n\n| reference fid | predicted fid | IoU | area error (%) | PoLiS |\n|---|---|---|---|---|\n";
    for (const auto& r : table) md << "| " << md_cell(r[0]) << " | " << md_cell(r[1]) << " | " << md_cell(r[2]) << " | " << md_cell(r[3]) << " | " << md_cell(r[4]) << " |\n";

    HtmlReport html("Footprint audit");
    html.paragraph("Predicted: " + pred_path + " (" + std::to_string(s.predicted) + " footprints" + (rep.reprojected ? ", reprojected" : "") +
                   "). Reference: " + ref_path + " (" + std::to_string(s.reference) + " footprints, " + rep.crs +
                   "). One-to-one matching at IoU >= " + fmt(o.iou_threshold) + ".");
    html.table({"measure", "value"}, totals);
    html.heading("Map");
    const std::optional<MapPicture> bg = background_for(o.ortho_path, ref.crs, rp);
    html.figure(svg_footprint_map(pp, iou_of_pred, o.iou_threshold, 1.0, "IoU", missed, bg ? &*bg : nullptr),
                "Predicted footprints coloured by the IoU of their match; red outlines: false positives; dashed grey: missed references" +
                    std::string(bg ? "; background: " + o.ortho_path : ""));
    html.heading("Distributions");
    html.figure(svg_histogram(ious, "IoU of matches"), "IoU of the matched footprints");
    html.figure(svg_histogram(errs, "area error (%)"), "Area error of the matches, (predicted - reference) / reference");
    html.figure(svg_scatter(ref_area, pred_area, "reference area (CRS units²)", "predicted area"), "Matched areas; dashed: y = x");
    html.heading("Matches");
    html.table({"reference fid", "predicted fid", "IoU", "area error (%)", "PoLiS"}, table);
    rep.output = finish_report(out_dir, j, md.str(), html, measures, o.gates);
    return rep;
}

RectangleAuditReport audit_rectangles(const std::string& fitted_path, const std::string& out_dir, const RectangleAuditOptions& o) {
    o.validate();
    RectangleAuditReport rep;
    std::string crs_label;
    CrsInfo layer_crs;
    Parts fitted_shapes;
    if (!o.original_path.empty()) {
        const LayerPair lp = read_pair(fitted_path, o.original_path, "", "");
        crs_label = lp.ref.crs.label(), layer_crs = lp.ref.crs;
        const Parts fp = parts_of(lp.pred), op = parts_of(lp.ref);
        fitted_shapes = fp;
        rep.fitted = fp.size();
        const FootprintScores s = match_footprints(fp, op, o.iou_threshold);
        for (const FootprintMatch& m : s.matches) {
            const double a0 = parts_area(op[m.reference]), a1 = parts_area(fp[m.predicted]);
            rep.rows.push_back({lp.pred.fids[m.predicted], a0, a1, a1 - a0, a0 > 0 ? (a1 - a0) / a0 * 100.0 : NAN, m.iou});
        }
        std::sort(rep.rows.begin(), rep.rows.end(), [](const RectangleError& a, const RectangleError& b) { return a.fid < b.fid; });
    } else {
        PolygonLayer layer = read_polygon_layer(fitted_path);
        if (layer.crs.empty()) throw Error(fitted_path, "fitted footprints have no CRS");
        put_layer_on(layer, working_crs_for_layer(layer, {}, fitted_path), fitted_path);  // lon/lat: on their UTM zone
        crs_label = layer.crs.label(), layer_crs = layer.crs;
        const int field = field_index(layer, o.original_area_field, fitted_path);
        Extent all = empty_extent();
        for (const Feature& f : layer.features) include(all, parts_extent(f.geometry));
        const double unit = ground_metres_per_unit_at(layer.crs, all), unit2 = unit * unit;  // ground m^2 (Web Mercator too)
        rep.fitted = layer.features.size();
        for (std::size_t i = 0; i < layer.features.size(); ++i) {
            const auto a0 = number(layer.features[i].values[field]);
            if (!a0) continue;  // a footprint without an original area (e.g. a failed fit) has no row
            const double a1 = parts_area(layer.features[i].geometry) * unit2;
            rep.rows.push_back({layer.fids[i], *a0, a1, a1 - *a0, *a0 > 0 ? (a1 - *a0) / *a0 * 100.0 : NAN, -1.0});
            fitted_shapes.push_back(layer.features[i].geometry);
        }
    }
    double sum_abs = 0, sum = 0, sum_abs_m2 = 0;
    std::size_t n = 0;
    for (const RectangleError& r : rep.rows) {
        if (std::isnan(r.error_pct)) continue;
        sum_abs += std::abs(r.error_pct), sum += r.error_pct, sum_abs_m2 += std::abs(r.error_m2), ++n;
        rep.max_abs_error_pct = n == 1 ? std::abs(r.error_pct) : std::max(rep.max_abs_error_pct, std::abs(r.error_pct));
    }
    if (n) rep.mean_abs_error_pct = sum_abs / double(n), rep.mean_error_pct = sum / double(n), rep.mean_abs_error_m2 = sum_abs_m2 / double(n);
    std::map<std::string, double> measures;
    if (n) measures = {{"mean_abs_error_pct", rep.mean_abs_error_pct}, {"max_abs_error_pct", rep.max_abs_error_pct}, {"mean_error_pct", rep.mean_error_pct}};

    nlohmann::json j;
    j["audit"] = "rectangles";
    j["fitted"] = {{"path", fitted_path}, {"count", rep.fitted}, {"crs", crs_label}};
    j["original"] = o.original_path.empty() ? nlohmann::json{{"area_field", o.original_area_field}}
                                            : nlohmann::json{{"path", o.original_path}, {"iou_threshold", o.iou_threshold}};
    j["totals"] = {{"buildings", rep.rows.size()}, {"mean_abs_error_pct", jnum(rep.mean_abs_error_pct)}, {"max_abs_error_pct", jnum(rep.max_abs_error_pct)},
                   {"mean_error_pct", jnum(rep.mean_error_pct)}, {"mean_abs_error_m2", jnum(rep.mean_abs_error_m2)}};
    j["reference_study"] = {{"buildings", 8}, {"min_abs_error_pct", 0.44}, {"max_abs_error_pct", 1.61}, {"mean_abs_error_pct", 0.88}};
    nlohmann::json rows = nlohmann::json::array();
    std::vector<std::vector<std::string>> table;
    std::vector<double> errs, a0s, a1s;
    for (const RectangleError& r : rep.rows) {
        nlohmann::json row{{"fid", r.fid}, {"original_m2", r.original_m2}, {"fitted_m2", r.fitted_m2}, {"error_m2", r.error_m2},
                           {"error_pct", jnum(r.error_pct)}};
        if (r.iou >= 0) row["iou"] = r.iou;
        rows.push_back(row);
        table.push_back({std::to_string(r.fid), fmt(r.original_m2, 6), fmt(r.fitted_m2, 6), fmt(r.error_m2), fmt(r.error_pct),
                         r.iou >= 0 ? fmt(r.iou) : "-"});
        errs.push_back(r.error_pct), a0s.push_back(r.original_m2), a1s.push_back(r.fitted_m2);
    }
    j["buildings"] = rows;
    const std::vector<std::vector<std::string>> totals{{"buildings compared", std::to_string(rep.rows.size())},
                                                       {"mean |area error| (%)", fmt(rep.mean_abs_error_pct)},
                                                       {"max |area error| (%)", fmt(rep.max_abs_error_pct)},
                                                       {"mean signed error (%)", fmt(rep.mean_error_pct)},
                                                       {"mean |area error| (m²)", fmt(rep.mean_abs_error_m2)},
                                                       {"reference study (8 buildings)", "0.44-1.61 %, mean 0.88 %"}};
    std::ostringstream md;
    md << "# Rectangle fit audit\n\n- fitted: `" << fitted_path << "` (" << rep.fitted << " footprints, " << crs_label << ")\n- original: "
       << (o.original_path.empty() ? "attribute `" + o.original_area_field + "`" : "`" + o.original_path + "`") << "\n\n| measure | value |\n|---|---|\n";
    for (const auto& r : totals) md << "| " << md_cell(r[0]) << " | " << md_cell(r[1]) << " |\n";
    md << "\n| fid | original (m²) | fitted (m²) | error (m²) | error (%) | IoU |\n|---|---|---|---|---|---|\n";
    for (const auto& r : table) md << "| " << md_cell(r[0]) << " | " << md_cell(r[1]) << " | " << md_cell(r[2]) << " | " << md_cell(r[3]) << " | " << md_cell(r[4]) << " | " << md_cell(r[5]) << " |\n";
    HtmlReport html("Rectangle fit audit");
    html.paragraph("Fitted: " + fitted_path + " (" + std::to_string(rep.fitted) + " footprints, " + crs_label + "). Original areas from " +
                   (o.original_path.empty() ? "attribute " + o.original_area_field : o.original_path) + ".");
    html.table({"measure", "value"}, totals);
    double emax = 0;
    for (double e : errs)
        if (std::isfinite(e)) emax = std::max(emax, std::abs(e));
    const std::optional<MapPicture> bg = background_for(o.ortho_path, layer_crs, fitted_shapes);
    html.figure(svg_footprint_map(fitted_shapes, errs, -std::max(emax, 1e-6), std::max(emax, 1e-6), "area error (%)", {}, bg ? &*bg : nullptr),
                "Fitted footprints coloured by their area error");
    html.figure(svg_histogram(errs, "area error (%)"), "Fitted minus original area, percent of the original");
    html.figure(svg_scatter(a0s, a1s, "original area (m²)", "fitted area (m²)"), "Dashed: y = x");
    html.table({"fid", "original (m²)", "fitted (m²)", "error (m²)", "error (%)", "IoU"}, table);
    rep.output = finish_report(out_dir, j, md.str(), html, measures, o.gates);
    return rep;
}

HeightAuditReport audit_heights(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                const HeightAuditOptions& o) {
    o.validate();
    const LayerPair lp = read_pair(pred_path, ref_path, "", "");
    const int pf = field_index(lp.pred, o.pred_field, pred_path), rf = field_index(lp.ref, o.ref_field, ref_path);
    const Parts p = parts_of(lp.pred), r = parts_of(lp.ref);
    const FootprintScores scores = match_footprints(p, r, o.iou_threshold);
    // Written by `cityforge heights`: how each ground was found, and its fit residual.
    auto optional_field = [&](const std::string& name) {
        const auto& names = lp.pred.field_names;
        const auto it = std::find(names.begin(), names.end(), name);
        return it == names.end() ? -1 : static_cast<int>(it - names.begin());
    };
    const int gmf = optional_field("ground_method"), grf = optional_field("ground_rmse_m");
    HeightAuditReport rep;
    rep.matched = scores.true_positives, rep.reference = r.size();
    double sum = 0, sum_abs = 0, sum2 = 0;
    std::vector<double> err_of_ref(r.size(), NAN);
    for (const FootprintMatch& m : scores.matches) {
        const auto pv = number(lp.pred.features[m.predicted].values[pf]);
        const auto rv = number(lp.ref.features[m.reference].values[rf]);
        if (!pv || !rv) continue;
        HeightError e{lp.ref.fids[m.reference], lp.pred.fids[m.predicted], *pv, *rv, *pv - *rv, {}, {}};
        if (gmf >= 0) {
            const AttributeValue& v = lp.pred.features[m.predicted].values[gmf];
            e.ground_method = std::holds_alternative<std::string>(v) ? std::get<std::string>(v) : "none";
            HeightErrorGroup& g = rep.by_ground_method[e.ground_method];
            ++g.count, g.mae += std::abs(e.error), g.bias += e.error;
        }
        if (grf >= 0) {
            e.ground_rmse_m = number(lp.pred.features[m.predicted].values[grf]);
            if (gmf >= 0 && e.ground_rmse_m) rep.by_ground_method[e.ground_method].mean_ground_rmse_m += *e.ground_rmse_m;
        }
        sum += e.error, sum_abs += std::abs(e.error), sum2 += e.error * e.error;
        rep.max_abs = rep.rows.empty() ? std::abs(e.error) : std::max(rep.max_abs, std::abs(e.error));
        rep.rows.push_back(e);
        err_of_ref[m.reference] = e.error;
    }
    rep.with_values = rep.rows.size();
    for (auto& [method, g] : rep.by_ground_method)
        if (g.count) g.mae /= double(g.count), g.bias /= double(g.count), g.mean_ground_rmse_m /= double(g.count);
    std::map<std::string, double> measures{{"coverage", r.empty() ? 0.0 : double(rep.with_values) / double(r.size())}};
    if (!rep.rows.empty()) {
        const double n = double(rep.rows.size());
        rep.mae = sum_abs / n, rep.rmse = std::sqrt(sum2 / n), rep.bias = sum / n;
        measures.insert({{"mae", rep.mae}, {"rmse", rep.rmse}, {"bias", rep.bias}, {"abs_bias", std::abs(rep.bias)}, {"max_abs", rep.max_abs}});
    }
    nlohmann::json j;
    j["audit"] = "heights";
    j["predicted"] = {{"path", pred_path}, {"field", o.pred_field}, {"reprojected", lp.reprojected}, {"crs", lp.pred.crs.label()}};
    j["reference"] = {{"path", ref_path}, {"field", o.ref_field}, {"count", rep.reference}, {"crs", lp.ref.crs.label()}};
    j["iou_threshold"] = o.iou_threshold;
    j["totals"] = {{"matched", rep.matched}, {"with_values", rep.with_values}, {"mae_m", jnum(rep.mae)}, {"rmse_m", jnum(rep.rmse)},
                   {"bias_m", jnum(rep.bias)}, {"max_abs_m", jnum(rep.max_abs)}};
    j["reference_study"] = {{"buildings", 10}, {"mae_m", 0.80}, {"max_abs_m", 1.77}};
    if (gmf >= 0) {
        nlohmann::json g = nlohmann::json::object();
        for (const auto& [method, v] : rep.by_ground_method)
            g[method] = {{"buildings", v.count}, {"mae_m", v.mae}, {"bias_m", v.bias}, {"mean_ground_rmse_m", v.mean_ground_rmse_m}};
        j["by_ground_method"] = g;
    }
    nlohmann::json rows = nlohmann::json::array();
    std::vector<std::vector<std::string>> table;
    std::vector<double> errs, pv, rv;
    for (const HeightError& e : rep.rows) {
        nlohmann::json row{{"reference_fid", e.reference_fid}, {"predicted_fid", e.predicted_fid}, {"predicted_m", e.predicted},
                           {"reference_m", e.reference}, {"error_m", e.error}};
        if (gmf >= 0) row["ground_method"] = e.ground_method;
        if (grf >= 0) row["ground_rmse_m"] = e.ground_rmse_m ? nlohmann::json(*e.ground_rmse_m) : nlohmann::json(nullptr);
        rows.push_back(std::move(row));
        table.push_back({std::to_string(e.reference_fid), std::to_string(e.predicted_fid), fmt(e.predicted), fmt(e.reference), fmt(e.error),
                         e.ground_method.empty() ? "-" : e.ground_method, e.ground_rmse_m ? fmt(*e.ground_rmse_m) : "-"});
        errs.push_back(e.error), pv.push_back(e.predicted), rv.push_back(e.reference);
    }
    j["buildings"] = rows;
    std::vector<std::vector<std::string>> totals{
        {"footprints matched", std::to_string(rep.matched) + " of " + std::to_string(rep.reference)},
        {"with both heights", std::to_string(rep.with_values)}, {"MAE (m)", fmt(rep.mae)}, {"RMSE (m)", fmt(rep.rmse)},
        {"bias, predicted - reference (m)", fmt(rep.bias)}, {"max |error| (m)", fmt(rep.max_abs)},
        {"reference study (10 buildings)", "MAE 0.80 m, max 1.77 m"}};
    for (const auto& [method, g] : rep.by_ground_method)
        totals.push_back({"ground " + method, std::to_string(g.count) + " buildings, MAE " + fmt(g.mae) + " m, bias " + fmt(g.bias) +
                                                   " m, mean ground fit RMSE " + fmt(g.mean_ground_rmse_m) + " m"});
    std::ostringstream md;
    md << "# Height audit\n\n- predicted: `" << pred_path << "`, field `" << o.pred_field << "`" << (lp.reprojected ? " (reprojected)" : "")
       << "\n- reference: `" << ref_path << "`, field `" << o.ref_field << "` (" << rep.reference << " footprints, " << lp.ref.crs.label()
       << ")\n- footprints matched one to one at IoU >= " << o.iou_threshold << "\n\n| measure | value |\n|---|---|\n";
    for (const auto& t : totals) md << "| " << md_cell(t[0]) << " | " << md_cell(t[1]) << " |\n";
    md << "\n| reference fid | predicted fid | predicted (m) | reference (m) | error (m) | ground method | ground RMSE (m) |\n|---|---|---|---|---|---|---|\n";
    for (const auto& t : table)
        md << "| " << md_cell(t[0]) << " | " << md_cell(t[1]) << " | " << md_cell(t[2]) << " | " << md_cell(t[3]) << " | " << md_cell(t[4])
           << " | " << md_cell(t[5]) << " | " << md_cell(t[6]) << " |\n";
    HtmlReport html("Height audit");
    html.paragraph("Predicted: " + pred_path + ", field " + o.pred_field + ". Reference: " + ref_path + ", field " + o.ref_field + " (" +
                   lp.ref.crs.label() + "). Footprints matched one to one at IoU >= " + fmt(o.iou_threshold) + ".");
    html.table({"measure", "value"}, totals);
    double emax = 0;
    for (double e : errs) emax = std::max(emax, std::abs(e));
    const std::optional<MapPicture> bg = background_for(o.ortho_path, lp.ref.crs, r);
    html.figure(svg_footprint_map(r, err_of_ref, -std::max(emax, 1e-6), std::max(emax, 1e-6), "height error (m)", {}, bg ? &*bg : nullptr),
                "Reference footprints coloured by height error (predicted - reference); red outline: no matched height");
    html.figure(svg_histogram(errs, "height error (m)"), "Predicted minus reference height");
    html.figure(svg_scatter(rv, pv, "reference height (m)", "predicted height (m)"), "Dashed: y = x");
    html.table({"reference fid", "predicted fid", "predicted (m)", "reference (m)", "error (m)", "ground method", "ground RMSE (m)"}, table);
    rep.output = finish_report(out_dir, j, md.str(), html, measures, o.gates);
    return rep;
}

CloudAuditReport audit_clouds(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                              const CloudAuditOptions& o) {
    o.validate();
    PointCloud pred = read_point_cloud(pred_path);
    const PointCloud ref = read_point_cloud(ref_path);
    const CrsInfo pred_crs = resolve_cloud_crs(pred_path, o.pred_crs, "--pred-crs").crs;
    const CrsInfo ref_crs = resolve_cloud_crs(ref_path, o.ref_crs, "--ref-crs").crs;
    if (pred_crs.empty() != ref_crs.empty())
        throw Error(pred_crs.empty() ? pred_path : ref_path, "point cloud has no CRS while the other has one; give it with --pred-crs/--ref-crs");
    CloudAuditReport rep;
    if (!ref_crs.empty() && !same_horizontal_crs(pred_crs, ref_crs)) {
        log::info("reprojecting " + pred_path + " from " + pred_crs.label() + " to " + ref_crs.label());
        transform_points(pred_crs, ref_crs, pred.x, pred.y, pred.z, pred_path);
        rep.reprojected = true;
    }
    rep.crs = ref_crs.empty() ? "none (both clouds without CRS, assumed the same)" : ref_crs.label();
    {
        const auto xy_extent = [](const PointCloud& c) {
            Extent e = empty_extent();
            for (std::size_t i = 0; i < c.x.size(); ++i)
                e.min_x = std::min(e.min_x, c.x[i]), e.max_x = std::max(e.max_x, c.x[i]), e.min_y = std::min(e.min_y, c.y[i]),
                e.max_y = std::max(e.max_y, c.y[i]);
            return e;
        };
        require_extents_overlap(xy_extent(pred), xy_extent(ref), ref_crs, pred_path, ref_path);
    }
    const double unit = ref_crs.empty() ? 1.0 : ref_crs.linear_unit_m;
    std::vector<double> taus;
    for (double t : o.taus_m) taus.push_back(t / unit);
    rep.comparison = compare_clouds(pred, ref, taus);
    CloudComparison& c = rep.comparison;
    c.mean_pred_to_ref *= unit, c.mean_ref_to_pred *= unit, c.chamfer *= unit, c.chamfer_squared *= unit * unit;
    c.median_pred_to_ref *= unit, c.p95_pred_to_ref *= unit, c.median_ref_to_pred *= unit, c.p95_ref_to_pred *= unit;
    c.histogram_max *= unit;
    for (std::size_t i = 0; i < c.scores.size(); ++i) c.scores[i].tau = o.taus_m[i];
    std::map<std::string, double> measures{{"chamfer", c.chamfer}, {"chamfer_squared", c.chamfer_squared},
                                           {"mean_pred_to_ref", c.mean_pred_to_ref}, {"mean_ref_to_pred", c.mean_ref_to_pred}};
    for (const CloudFScore& s : c.scores) {
        const std::string t = format_number(s.tau, 6);
        measures["precision@" + t] = s.precision, measures["recall@" + t] = s.recall, measures["f@" + t] = s.f_score;
    }

    nlohmann::json j;
    j["audit"] = "clouds";
    j["predicted"] = {{"path", pred_path}, {"points", c.predicted_points}, {"reprojected", rep.reprojected}};
    j["reference"] = {{"path", ref_path}, {"points", c.reference_points}, {"crs", rep.crs}};
    j["distances_m"] = {{"mean_pred_to_ref", c.mean_pred_to_ref}, {"mean_ref_to_pred", c.mean_ref_to_pred},
                        {"median_pred_to_ref", c.median_pred_to_ref}, {"p95_pred_to_ref", c.p95_pred_to_ref},
                        {"median_ref_to_pred", c.median_ref_to_pred}, {"p95_ref_to_pred", c.p95_ref_to_pred},
                        {"chamfer", c.chamfer}, {"chamfer_convention", "mean nearest distance pred->ref + mean ref->pred (metres)"},
                        {"chamfer_squared", c.chamfer_squared},
                        {"chamfer_squared_convention", "mean squared nearest distance both ways, summed (square metres)"}};
    j["totals"] = {{"chamfer_m", c.chamfer}, {"chamfer_squared_m2", c.chamfer_squared}, {"mean_pred_to_ref_m", c.mean_pred_to_ref},
                   {"mean_ref_to_pred_m", c.mean_ref_to_pred}};
    nlohmann::json rows = nlohmann::json::array();
    std::vector<std::vector<std::string>> ftable;
    for (const CloudFScore& s : c.scores) {
        rows.push_back({{"tau_m", s.tau}, {"precision", s.precision}, {"recall", s.recall}, {"f_score", s.f_score}});
        ftable.push_back({fmt(s.tau), fmt(s.precision), fmt(s.recall), fmt(s.f_score)});
    }
    j["f_scores"] = rows;
    j["histogram"] = {{"max_m", c.histogram_max}, {"bins", c.histogram_pred_to_ref.size()}, {"pred_to_ref", c.histogram_pred_to_ref},
                      {"ref_to_pred", c.histogram_ref_to_pred}, {"note", "equal bins on [0, max_m); the last bin also counts farther points"}};
    const std::vector<std::vector<std::string>> totals{
        {"mean distance pred -> ref (m)", fmt(c.mean_pred_to_ref)}, {"median / p95 pred -> ref (m)", fmt(c.median_pred_to_ref) + " / " + fmt(c.p95_pred_to_ref)},
        {"mean distance ref -> pred (m)", fmt(c.mean_ref_to_pred)}, {"median / p95 ref -> pred (m)", fmt(c.median_ref_to_pred) + " / " + fmt(c.p95_ref_to_pred)},
        {"chamfer, sum of both means (m)", fmt(c.chamfer)}, {"chamfer, squared convention (m²)", fmt(c.chamfer_squared)}};
    std::ostringstream md;
    md << "# Point cloud audit\n\n- predicted: `" << pred_path << "` (" << c.predicted_points << " points" << (rep.reprojected ? ", reprojected" : "")
       << ")\n- reference: `" << ref_path << "` (" << c.reference_points << " points, " << rep.crs << ")\n\n| measure | value |\n|---|---|\n";
    for (const auto& t : totals) md << "| " << md_cell(t[0]) << " | " << md_cell(t[1]) << " |\n";
    md << "\n| tau (m) | precision | recall | F-score |\n|---|---|---|---|\n";
    for (const auto& t : ftable) md << "| " << md_cell(t[0]) << " | " << md_cell(t[1]) << " | " << md_cell(t[2]) << " | " << md_cell(t[3]) << " |\n";
    HtmlReport html("Point cloud audit");
    html.paragraph("Predicted: " + pred_path + " (" + std::to_string(c.predicted_points) + " points" + (rep.reprojected ? ", reprojected" : "") +
                   "). Reference: " + ref_path + " (" + std::to_string(c.reference_points) + " points, " + rep.crs + ").");
    html.table({"measure", "value"}, totals);
    html.table({"tau (m)", "precision", "recall", "F-score"}, ftable);
    auto as_double = [](const std::vector<uint64_t>& h) { return std::vector<double>(h.begin(), h.end()); };
    html.figure(svg_bar_chart(0.0, c.histogram_max, as_double(c.histogram_pred_to_ref), "nearest distance, predicted -> reference (m)", "points"),
                "Accuracy side: distance of each predicted point to the reference (last bar: farther)");
    html.figure(svg_bar_chart(0.0, c.histogram_max, as_double(c.histogram_ref_to_pred), "nearest distance, reference -> predicted (m)", "points"),
                "Completeness side: distance of each reference point to the prediction (last bar: farther)");
    rep.output = finish_report(out_dir, j, md.str(), html, measures, o.gates);
    return rep;
}

}  // namespace cityforge
