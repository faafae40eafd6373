// cityforge audit ...: accuracy audits (footprints, rectangles, heights, clouds) with CI gates.
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/audit_run.hpp"

namespace cityforge::cli {

namespace {

// Every audit: --out DIR and the CI gates.
struct AuditCommon {
    std::string out, below, above;
};

void add_common(CLI::App* cmd, AuditCommon& c) {
    cmd->add_option("--out", c.out, "Report folder (report.json, report.md, report.html)")->required();
    cmd->add_option("--fail-below", c.below, "Exit with status 4 when a measure is below its minimum, e.g. f1=0.8,iou=0.7");
    cmd->add_option("--fail-above", c.above, "Exit with status 4 when a measure is above its maximum, e.g. mae=0.5");
}

std::vector<AuditGate> gates_of(const AuditCommon& c) {
    auto gates = parse_gates(c.below, "--fail-below", true);
    const auto a = parse_gates(c.above, "--fail-above", false);
    gates.insert(gates.end(), a.begin(), a.end());
    return gates;
}

// Exit status 4 when an audit's gates failed (said on stderr), else 0.
int gate_exit(const AuditOutput& out) {
    if (out.gates.passed) return 0;
    std::string why;
    for (const auto& f : out.gates.failed) why += (why.empty() ? "" : ", ") + f;
    std::fprintf(stderr, "cityforge: audit failed its gates: %s\n", why.c_str());
    return 4;
}

void add_footprint_audit(CLI::App& audit, CommandList& out) {
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
    cmd->footer("Measures for gates: " + join_words(footprint_audit_measures()));
    out.push_back({cmd, [s]() {
                       FootprintAuditOptions opt = s->options;
                       opt.gates = gates_of(s->common);
                       const FootprintAuditReport r = audit_footprints(s->pred, s->ref, s->common.out, opt);
                       const auto& sc = r.scores;
                       std::printf("precision %.4f recall %.4f F1 %.4f mean IoU %.4f mean |area error| %.2f %% mean PoLiS %.3f (TP %zu of %zu predicted, %zu reference)%s\n",
                                   sc.precision, sc.recall, sc.f1, sc.mean_iou, sc.mean_abs_area_error_pct, sc.mean_polis, sc.true_positives,
                                   sc.predicted, sc.reference, r.reprojected ? "; prediction reprojected" : "");
                       return gate_exit(r.output);
                   }});
}

void add_rectangle_audit(CLI::App& audit, CommandList& out) {
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
    cmd->footer("Measures for gates: " + join_words(rectangle_audit_measures()));
    out.push_back({cmd, [s]() {
                       RectangleAuditOptions opt = s->options;
                       opt.gates = gates_of(s->common);
                       const RectangleAuditReport r = audit_rectangles(s->in, s->common.out, opt);
                       std::printf("mean |area error| %.3f %% max %.3f %% mean signed %+.3f %% over %zu of %zu footprints\n", r.mean_abs_error_pct,
                                   r.max_abs_error_pct, r.mean_error_pct, r.rows.size(), r.fitted);
                       return gate_exit(r.output);
                   }});
}

void add_height_audit(CLI::App& audit, CommandList& out) {
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
    cmd->footer("Measures for gates: " + join_words(height_audit_measures()) + " (metres; coverage: share of references with both heights)");
    out.push_back({cmd, [s]() {
                       HeightAuditOptions opt = s->options;
                       opt.gates = gates_of(s->common);
                       const HeightAuditReport r = audit_heights(s->pred, s->ref, s->common.out, opt);
                       std::printf("MAE %.3f m RMSE %.3f m bias %+.3f m max %.3f m over %zu buildings (%zu matched of %zu reference)\n", r.mae,
                                   r.rmse, r.bias, r.max_abs, r.with_values, r.matched, r.reference);
                       return gate_exit(r.output);
                   }});
}

void add_cloud_audit(CLI::App& audit, CommandList& out) {
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

void add_audit_commands(CLI::App& parent, const GlobalFlags&, CommandList& out) {
    auto* audit = parent.add_subcommand("audit", "Accuracy audits");
    audit->require_subcommand(1);
    add_footprint_audit(*audit, out);
    add_rectangle_audit(*audit, out);
    add_height_audit(*audit, out);
    add_cloud_audit(*audit, out);
}

}  // namespace cityforge::cli
