// cityforge cloud translate IN OUT.las: any cloud we read (LAS, LAZ, COPC, PLY,
// XYZ) to uncompressed LAS, optionally cropped (like pdal translate / las2las).
#include <cstdio>
#include <memory>

#include "cloud/cloud_translate.hpp"
#include "commands/commands.hpp"
#include "core/error.hpp"
#include "crs/crs.hpp"

namespace cityforge::cli {

void add_cloud_translate_command(CLI::App& cloud, const GlobalFlags& g, CommandList& out) {
    struct State {
        CloudTranslateOptions options;
        std::string bounds, crs;
    };
    auto s = std::make_shared<State>();
    auto* cmd = cloud.add_subcommand("translate", "Any cloud (LAS, LAZ, COPC, PLY, XYZ) to uncompressed LAS, optionally cropped");
    cmd->add_option("input", s->options.input, "Input cloud (LAS, LAZ, COPC, PLY, XYZ/CSV)")->required();
    cmd->add_option("output", s->options.output, "Output .las (LAS/LAZ input keeps its header, point format and VLRs)")->required();
    cmd->add_option("--bounds", s->bounds, "Keep only points with xmin <= x <= xmax and ymin <= y <= ymax: xmin,ymin,xmax,ymax (file CRS)");
    cmd->add_option("--crs", s->crs, "PLY/XYZ input: CRS to store in the LAS (e.g. EPSG:7415); LAS/LAZ keep theirs");
    out.push_back({cmd, [s, &g]() {
                       CloudTranslateOptions o = s->options;
                       o.overwrite = g.overwrite;  // the global --overwrite, as for every output
                       if (!s->bounds.empty()) {
                           const auto parts = split_list(s->bounds);
                           std::array<double, 4> b{};
                           if (parts.size() != 4) throw Error("--bounds", "expected xmin,ymin,xmax,ymax, got '" + s->bounds + "'");
                           for (int i = 0; i < 4; ++i) {
                               try {
                                   std::size_t used = 0;
                                   b[i] = std::stod(parts[i], &used);
                                   if (used != parts[i].size()) throw std::invalid_argument("trailing text");
                               } catch (const std::exception&) {
                                   throw Error("--bounds", "'" + parts[i] + "' is not a number");
                               }
                           }
                           o.bounds = b;
                       }
                       if (!s->crs.empty()) o.crs_wkt = crs_from_user_input(s->crs, "--crs").wkt;
                       remove_stale_temporaries_beside(o.output);
                       const CloudTranslateResult r = translate_cloud(o);
                       if (!g.quiet) {
                           std::string skipped;
                           if (r.laz_chunks_skipped > 0)
                               skipped = ", " + std::to_string(r.laz_chunks_skipped) + " of " + std::to_string(r.laz_chunks) +
                                         (r.copc_nodes_skipped ? " COPC nodes outside --bounds not decoded"
                                                               : " LAZ chunks skipped (their XY layer has no point in --bounds)");
                           std::fprintf(stderr, "cityforge: %llu of %llu points%s%s -> %s (point records sha256 %s)\n",
                                        static_cast<unsigned long long>(r.points_written), static_cast<unsigned long long>(r.points_read),
                                        r.decompressed ? ", decompressed from LAZ" : "", skipped.c_str(), o.output.c_str(),
                                        r.points_sha256.c_str());
                       }
                       return 0;
                   }});
}

}  // namespace cityforge::cli
