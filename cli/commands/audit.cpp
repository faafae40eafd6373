// cityforge audit ...: accuracy audits (footprints, rectangles, heights, clouds) with CI gates.
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>

#include "commands/commands.hpp"
#include "pipeline/audit_run.hpp"

namespace cityforge::cli {

namespace {

// Every audit: --out DIR and the CI gates.
struct AuditCommon {
    std::string out, below, above;
    const GlobalFlags* flags = nullptr;
};

void add_common(CLI::App* cmd, AuditCommon& c) {
    cmd->add_option("--out", c.out, "Report folder (report.json, report.md, report.html)")->required();
    cmd->add_option("--fail-below", c.below, "Exit with status 4 when a measure is below its minimum, e.g. f1=0.8,iou=0.7");
    cmd->add_option("--fail-above", c.above, "Exit with status 4 when a measure is above its maximum, e.g. mae=0.5");
}

// The gates; first of all, an existing report folder is refused without --overwrite.
std::vector<AuditGate> gates_of(const AuditCommon& c) {
    refuse_existing_output(*c.flags, c.out);
    auto gates = parse_gates(c.below, "--fail-below", true);
    const auto a = parse_gates(c.above, "--fail-above", false);
    gates.insert(gates.end(), a.begin(), a.end());
    return gates;
}

// `v` printed with the printf format `f`, or n/a when it is not defined (NaN:
// a mean over no match).
std::string defined_or_na(double v, const char* f) {
    if (!std::isfinite(v)) return "n/a";
    char buf[64];
    std::snprintf(buf, sizeof buf, f, v);
    return buf;
}

// Exit status 4 when an audit's gates failed (said on stderr), else 0.
int gate_exit(const AuditOutput& out) {
    if (out.gates.passed) return 0;
    std::string why;
    for (const auto& f : out.gates.failed) why += (why.empty() ? "" : ", ") + f;
    std::fprintf(stderr, "cityforge: audit failed its gates: %s\n", why.c_str());
    return 4;
}

void add_footprint_audit(CLI::App& audit, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string pred, ref;
        AuditCommon common;
        FootprintAuditOptions options;
    };
    auto s = std::make_shared<State>();
    auto* cmd = audit.add_subcommand("footprints", "Footprints against reference footprints (SpaceNet matching, PoLiS, ISPRS per-area)");
    cmd->add_option("--pred", s->pred, "Predicted footprints (any OGR polygon layer)")->required();
    cmd->add_option("--ref", s->ref, "Reference footprints")->required();
    cmd->add_option("--iou", s->options.iou_threshold, "IoU threshold of a match")->capture_default_str();
    cmd->add_option("--ortho", s->options.ortho_path, "Raster drawn under the map in report.html (reference CRS)");
    add_common(cmd, s->common);
    s->common.flags = &g;
    cmd->footer("Measures for gates: " + join_words(footprint_audit_measures()));
    out.push_back({cmd, [s]() {
                       FootprintAuditOptions opt = s->options;
                       opt.gates = gates_of(s->common);
                       const FootprintAuditReport r = audit_footprints(s->pred, s->ref, s->common.out, opt);
                       const auto& sc = r.scores;
                       // Means over matches are not defined without a match: n/a.
                       auto over = [&](double v, const char* f) { return sc.true_positives ? defined_or_na(v, f) : std::string("n/a"); };
                       std::printf("precision %.4f recall %.4f F1 %.4f mean IoU %s mean |area error| %s %% mean PoLiS %s (TP %zu of %zu predicted, %zu reference)%s\n",
                                   sc.precision, sc.recall, sc.f1, over(sc.mean_iou, "%.4f").c_str(), over(sc.mean_abs_area_error_pct, "%.2f").c_str(),
                                   over(sc.mean_polis, "%.3f").c_str(), sc.true_positives, sc.predicted, sc.reference,
                                   r.reprojected ? "; prediction reprojected" : "");
                       return gate_exit(r.output);
                   }});
}

void add_rectangle_audit(CLI::App& audit, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string in;
        AuditCommon common;
        RectangleAuditOptions options;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = audit.add_subcommand("rectangles", "Fitted footprints: original vs fitted area per building (the study's Table 5)");
    cmd->add_option("--in", s->in, "Fitted footprints (e.g. from `cityforge footprints`)")->required();
    cmd->add_option("--original", o.original_path, "Original polygons to compare with (matched one to one by IoU)");
    cmd->add_option("--original-area-field", o.original_area_field, "Attribute with the original area in m² (without --original)")
        ->capture_default_str();
    cmd->add_option("--iou", o.iou_threshold, "IoU threshold matching fitted to original polygons")->capture_default_str();
    cmd->add_option("--ortho", o.ortho_path, "Raster drawn under the map in report.html (same CRS)");
    add_common(cmd, s->common);
    s->common.flags = &g;
    cmd->footer("Measures for gates: " + join_words(rectangle_audit_measures()));
    out.push_back({cmd, [s]() {
                       RectangleAuditOptions opt = s->options;
                       opt.gates = gates_of(s->common);
                       const RectangleAuditReport r = audit_rectangles(s->in, s->common.out, opt);
                       std::printf("mean |area error| %s %% max %s %% mean signed %s %% over %zu of %zu footprints\n",
                                   defined_or_na(r.mean_abs_error_pct, "%.3f").c_str(), defined_or_na(r.max_abs_error_pct, "%.3f").c_str(),
                                   defined_or_na(r.mean_error_pct, "%+.3f").c_str(), r.rows.size(), r.fitted);
                       return gate_exit(r.output);
                   }});
}

void add_height_audit(CLI::App& audit, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string pred, ref;
        AuditCommon common;
        HeightAuditOptions options;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = audit.add_subcommand("heights", "Heights of matched footprints against reference heights (MAE, RMSE, bias, max)");
    cmd->add_option("--pred", s->pred, "Predicted footprints with heights")->required();
    cmd->add_option("--ref", s->ref, "Reference footprints with heights")->required();
    cmd->add_option("--pred-field", o.pred_field, "Predicted height attribute")->capture_default_str();
    cmd->add_option("--ref-field", o.ref_field, "Reference height attribute")->required();
    cmd->add_option("--iou", o.iou_threshold, "IoU threshold of a footprint match")->capture_default_str();
    cmd->add_option("--ortho", o.ortho_path, "Raster drawn under the map in report.html (reference CRS)");
    add_common(cmd, s->common);
    s->common.flags = &g;
    cmd->footer("Measures for gates: " + join_words(height_audit_measures()) + " (metres; coverage: share of references with both heights)");
    out.push_back({cmd, [s]() {
                       HeightAuditOptions opt = s->options;
                       opt.gates = gates_of(s->common);
                       const HeightAuditReport r = audit_heights(s->pred, s->ref, s->common.out, opt);
                       std::printf("MAE %s m RMSE %s m bias %s m max %s m over %zu buildings (%zu matched of %zu reference)\n",
                                   defined_or_na(r.mae, "%.3f").c_str(), defined_or_na(r.rmse, "%.3f").c_str(), defined_or_na(r.bias, "%+.3f").c_str(),
                                   defined_or_na(r.max_abs, "%.3f").c_str(), r.with_values, r.matched, r.reference);
                       return gate_exit(r.output);
                   }});
}

void add_cloud_audit(CLI::App& audit, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string pred, ref;
        AuditCommon common;
        CloudAuditOptions options;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = audit.add_subcommand("clouds", "Point cloud against a reference: precision/recall/F-score within tau, chamfer distance");
    cmd->add_option("--pred", s->pred, "Predicted cloud (LAS, PLY, XYZ)")->required();
    cmd->add_option("--ref", s->ref, "Reference cloud")->required();
    cmd->add_option("--tau", o.taus_m, "Distance thresholds in metres")->delimiter(',')->capture_default_str();
    cmd->add_option("--pred-crs", o.pred_crs, "CRS of the predicted cloud if it has none");
    cmd->add_option("--ref-crs", o.ref_crs, "CRS of the reference cloud if it has none");
    add_common(cmd, s->common);
    s->common.flags = &g;
    cmd->footer("Measures for gates: chamfer chamfer_squared mean_pred_to_ref mean_ref_to_pred, and per tau T: precision@T recall@T f@T");
    out.push_back({cmd, [s]() {
                       CloudAuditOptions opt = s->options;
                       opt.gates = gates_of(s->common);
                       const CloudAuditReport r = audit_clouds(s->pred, s->ref, s->common.out, opt);
                       const auto& c = r.comparison;
                       std::printf("chamfer %.4f m (pred->ref %.4f, ref->pred %.4f)", c.chamfer, c.mean_pred_to_ref, c.mean_ref_to_pred);
                       for (const auto& sc : c.scores) std::printf("; tau %.2f m: P %.4f R %.4f F %.4f", sc.tau, sc.precision, sc.recall, sc.f_score);
                       std::printf("\n");
                       return gate_exit(r.output);
                   }});
}

}  // namespace

void add_audit_commands(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    auto* audit = parent.add_subcommand("audit", "Accuracy audits");
    audit->require_subcommand(1);
    add_footprint_audit(*audit, g, out);
    add_rectangle_audit(*audit, g, out);
    add_height_audit(*audit, g, out);
    add_cloud_audit(*audit, g, out);
}

}  // namespace cityforge::cli
