// Accuracy on varied synthetic towns: writes a town with `cityforge synth`'s
// library call (any SceneVariation, sun, density, noise), then measures on its
// exact truth
//   heights  - ground_z against the truth base, flat-roof height_m (MAE, bias)
//   roofs    - roof-type accuracy per family, LOD2 RMSE, fallbacks, valid solids
//   outlines - footprints from ortho + cloud against the truth (F1, IoU, area error)
// Figures are printed; nothing is asserted (tests guard the targets).
//
//   build/bin/bench_accuracy [key=value ...]
//   keys: size seed density sigma sun_az sun_el slope undulation dark trees
//         ground_like terraced oblique round families(0/1) centroid(0/1)
//         stages=heights,roofs,outlines dir=PATH ground=plane|percentile seams(0/1) classes(0/1: an unclassified cloud) crown(sigma m, 0 = off)
//         peel(rings) crown_fill(cells, -1 = off)
#include "bench_main.hpp"
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>

#include "core/error.hpp"
#include "io/vector.hpp"
#include "pipeline/audit_run.hpp"
#include "pipeline/footprints_run.hpp"
#include "pipeline/heights_run.hpp"
#include "pipeline/roofs_run.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {

double field(const PolygonLayer& l, std::size_t i, const std::string& name) {
    const auto it = std::find(l.field_names.begin(), l.field_names.end(), name);
    if (it == l.field_names.end()) throw Error("truth", "no field " + name);
    const AttributeValue& v = l.features[i].values[static_cast<std::size_t>(it - l.field_names.begin())];
    if (std::holds_alternative<double>(v)) return std::get<double>(v);
    if (std::holds_alternative<int64_t>(v)) return double(std::get<int64_t>(v));
    return NAN;
}

std::string text(const PolygonLayer& l, std::size_t i, const std::string& name) {
    const auto it = std::find(l.field_names.begin(), l.field_names.end(), name);
    const AttributeValue& v = l.features[i].values[static_cast<std::size_t>(it - l.field_names.begin())];
    return std::holds_alternative<std::string>(v) ? std::get<std::string>(v) : "";
}

double median(std::vector<double> v) {
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

}  // namespace

static int run_bench(int argc, char** argv) {
    std::map<std::string, std::string> kv{{"size", "400"}, {"seed", "11"}, {"stages", "heights,roofs,outlines"}, {"dir", "/tmp/bench_accuracy"}};
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        const auto eq = a.find('=');
        if (eq == std::string::npos) throw Error(a, "arguments are key=value");
        kv[a.substr(0, eq)] = a.substr(eq + 1);
    }
    static const char* const known[] = {"centroid", "classes", "crown", "crown_fill", "dark", "density", "dir", "families", "ground",
                                        "ground_like", "oblique", "outliers", "peel", "round", "seams", "seed", "sigma", "size",
                                        "slope", "stages", "sun_az", "sun_el", "terraced", "trees", "undulation", "verbose", "worst"};
    for (const auto& [k, v] : kv)
        if (std::find_if(std::begin(known), std::end(known), [&](const char* n) { return k == n; }) == std::end(known))
            throw Error(k, "unknown key (see --help)");
    auto num = [&](const std::string& k, double def) { return kv.count(k) ? cityforge::bench::parse_number(kv.at(k).c_str(), k.c_str()) : def; };
    SynthOptions so;
    so.size_m = num("size", 400);
    so.seed = static_cast<uint64_t>(num("seed", 11));
    so.cloud_density_m2 = num("density", 8.0);
    so.lidar_sigma_m = num("sigma", 0.03);
    so.sun_azimuth_deg = num("sun_az", 135.0);
    so.sun_elevation_deg = num("sun_el", 48.0);
    synth::SceneVariation& v = so.variation;
    v.terrain_slope_max = num("slope", v.terrain_slope_max);
    v.terrain_undulation_m = num("undulation", v.terrain_undulation_m);
    v.dark_roof_share = num("dark", v.dark_roof_share);
    v.tree_touch_share = num("trees", v.tree_touch_share);
    v.ground_like_roof_share = num("ground_like", 0.0);
    v.terraced_block_share = num("terraced", 0.0);
    v.oblique_share = num("oblique", 0.0);
    v.round_share = num("round", 0.0);
    v.all_roof_families = num("families", 0) != 0;
    v.base_at_area_centroid = num("centroid", 0) != 0;
    const std::string dir = kv.at("dir");
    std::filesystem::remove_all(dir);
    const SynthResult s = write_synthetic_town(dir, so);
    std::printf("town %s: %.0f m, seed %llu, %d buildings, %llu points\n", dir.c_str(), so.size_m, (unsigned long long)so.seed, s.buildings,
                (unsigned long long)s.points);
    const PolygonLayer truth = read_polygon_layer(s.truth_path, "");
    const std::string stages = kv.at("stages");

    if (stages.find("heights") != std::string::npos || stages.find("roofs") != std::string::npos) {
        HeightsRunOptions ho;
        ho.heights.keep_roof_points = true;
        if (kv.count("ground")) ho.heights.ground_method = ground_method_from_string(kv.at("ground"), "ground");
        const HeightsStage st = compute_heights_stage(s.truth_path, s.cloud_path, ho);
        double gabs = 0, gbias = 0, habs = 0, hbias = 0;
        int gn = 0, hn = 0;
        std::map<std::string, int> methods;
        for (std::size_t i = 0; i < st.heights.size(); ++i) {
            const BuildingHeight& h = st.heights[i];
            ++methods[h.ground_method.empty() ? "none" : h.ground_method];
            if (h.ground_z) {
                const double e = *h.ground_z - field(truth, i, "ground_z_m");
                gabs += std::abs(e), gbias += e, ++gn;
            }
            if (text(truth, i, "roof_type") == "flat" && h.height_m) {
                const double e = *h.height_m - field(truth, i, "eave_height_m");
                habs += std::abs(e), hbias += e, ++hn;
            }
        }
        std::printf("heights: ground MAE %.3f m bias %+.3f m over %d; flat-roof height_m MAE %.3f m bias %+.3f m over %d; methods", gabs / gn,
                    gbias / gn, gn, hn ? habs / hn : NAN, hn ? hbias / hn : NAN, hn);
        for (const auto& [m, c] : methods) std::printf(" %s %d", m.c_str(), c);
        std::printf("\n");
        if (stages.find("roofs") != std::string::npos) {
            RoofsRunOptions ro;
            ro.heights = ho;
            RoofsRunReport rep;
            const CityModel model = build_lod2_model(st, st.table.crs, ro, s.truth_path, rep);
            std::map<std::string, std::pair<int, int>> per;
            std::map<std::string, int> confusion;
            std::vector<double> rmse;
            int correct = 0, valid = 0;
            for (std::size_t i = 0; i < model.buildings.size(); ++i) {
                const Building& b = model.buildings[i];
                const std::string t = text(truth, i, "roof_type");
                auto& p = per[t];
                ++p.second;
                if (b.roof_type == t) ++correct, ++p.first;
                else ++confusion[t + "->" + (b.roof_type.empty() ? "none" : b.roof_type)];
                const bool ok = !b.lod2.empty() && b.lod2_errors.empty();
                valid += ok;
                if (kv.count("verbose") && (!ok || b.roof_type != t)) {
                    std::string fb;
                    for (const auto& [k, a] : b.attributes) {
                        if (k == "lod2_fallback" && std::holds_alternative<std::string>(a)) fb = std::get<std::string>(a);
                        if ((k == "roof_planes" || k == "roof_slope_deg" || k == "n_points_roof") && !std::holds_alternative<std::monostate>(a))
                            fb += " " + k + "=" + (std::holds_alternative<double>(a) ? std::to_string(std::get<double>(a)) : std::to_string(std::get<int64_t>(a)));
                    }
                    std::printf("  id %lld %s/%s -> %s%s%s%s\n", (long long)field(truth, i, "id"), text(truth, i, "shape").c_str(), t.c_str(),
                                b.roof_type.c_str(), fb.empty() ? "" : (" fallback: " + fb).c_str(), ok ? "" : " INVALID ",
                                b.lod2_errors.empty() ? "" : b.lod2_errors.front().c_str());
                }
                for (const auto& [k, a] : b.attributes)
                    if (k == "lod2_rmse_m" && std::holds_alternative<double>(a)) rmse.push_back(std::get<double>(a));
            }
            std::printf("roofs: type accuracy %.3f (", double(correct) / double(model.buildings.size()));
            for (const auto& [k, p] : per) std::printf(" %s %d/%d", k.c_str(), p.first, p.second);
            std::printf(" ); wrong:");
            for (const auto& [k, c] : confusion) std::printf(" %s %d", k.c_str(), c);
            std::printf("; LOD2 %zu, fallbacks %zu, valid %d/%zu, RMSE median %.3f m mean %.3f m\n", rep.lod2, rep.fallbacks, valid,
                        model.buildings.size(), median(rmse), rep.mean_rmse_m);
        }
    }
    if (stages.find("outlines") != std::string::npos) {
        FootprintsRunOptions fo;
        fo.ortho = s.ortho_path;
        fo.cloud = s.cloud_path;
        fo.seams.enabled = num("seams", 1) != 0;  // terraces split at roof seams (seams=0 turns it off)
        if (kv.count("classes")) fo.mask.use_classes = num("classes", 1) != 0 ? 1 : 0;  // classes=0: an unclassified cloud
        fo.segmentation.max_crown_plane_sigma_m = num("crown", fo.segmentation.max_crown_plane_sigma_m);  // crown=0 turns the crown cue off
        fo.segmentation.cloud_peel_rings = static_cast<int>(num("peel", fo.segmentation.cloud_peel_rings));
        fo.mask.crown_fill_rectangle_cells = static_cast<int>(num("crown_fill", fo.mask.crown_fill_rectangle_cells));
        fo.outliers.enabled = num("outliers", 1) != 0;
        const std::string out = dir + "/footprints.gpkg";
        const FootprintsReport fr = run_footprints(out, fo);
        FootprintAuditOptions ao;
        const FootprintAuditReport ar = audit_footprints(out, s.truth_path, dir + "/audit_footprints", ao);
        const FootprintScores& sc = ar.scores;
        std::printf("outlines (%s): F1 %.3f (TP %zu, pred %zu, ref %zu), mean IoU %.3f, mean |area error| %.2f %%, %.1f s\n", fr.mode.c_str(),
                    sc.f1, sc.true_positives, sc.predicted, sc.reference, sc.mean_iou, sc.mean_abs_area_error_pct, fr.seconds);
        // The worst matches: which truth buildings fail.
        std::vector<FootprintMatch> m = sc.matches;
        std::sort(m.begin(), m.end(), [](const FootprintMatch& a, const FootprintMatch& b) { return a.iou < b.iou; });
        double bias = 0.0;
        for (const FootprintMatch& x : m) bias += x.area_error_pct;
        std::printf("  mean signed area error %+.2f %% over %zu matches\n", m.empty() ? 0.0 : bias / double(m.size()), m.size());
        std::printf("  worst:");
        for (std::size_t k = 0; k < std::min<std::size_t>(kv.count("worst") ? std::size_t(num("worst", 6)) : 6, m.size()); ++k)
            std::printf(" id %lld %s/%s IoU %.2f err %+.1f%%;", (long long)field(truth, m[k].reference, "id"), text(truth, m[k].reference, "shape").c_str(),
                        text(truth, m[k].reference, "roof_type").c_str(), m[k].iou, m[k].area_error_pct);
        std::printf("\n");
    }
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_accuracy", "bench_accuracy [key=value ...]  (keys: size seed density sigma sun_az sun_el slope undulation dark trees ground_like terraced oblique families round centroid classes crown peel crown_fill outliers seams stages ground verbose worst dir)", run_bench);
}
