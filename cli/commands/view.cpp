// cityforge view: the self-contained viewer page of a run or export folder.
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/view_run.hpp"

namespace cityforge::cli {

void add_view_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string dir;
        ViewOptions options;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = parent.add_subcommand("view", "Viewer page of a run (DIR/view/index.html): ortho + footprints, 3D model, attributes; opens from disk");
    cmd->add_option("DIR", s->dir, "Output folder of `cityforge run` or `cityforge export` (buildings.gpkg, buildings.glb)")->required();
    cmd->add_option("--out", o.out, "Page to write (default DIR/view/index.html)");
    cmd->add_option("--buildings", o.buildings, "Building table (default DIR/buildings.gpkg)");
    cmd->add_option("--glb", o.glb, "3D model (default DIR/buildings.glb)");
    cmd->add_option("--tileset", o.tileset, "3D Tiles tileset shown in 3D as well (default DIR/3dtiles/tileset.json; bundled as tiles.js beside the page)");
    cmd->add_option("--ortho", o.ortho, "Raster under the footprints (default: the run's ortho from DIR/manifest.json)");
    cmd->add_option("--ortho-max-px", o.ortho_max_px, "Longer side of the ortho quick-look, pixels")->capture_default_str();
    cmd->add_flag("--overwrite", o.overwrite, "Replace an existing page");
    out.push_back({cmd, [s, &g]() {
                       remove_stale_temporaries_beside(s->options.out.empty() ? s->dir + "/view/index.html" : s->options.out);
                       const ViewReport r = write_view(s->dir, s->options);
                       if (!g.quiet) {
                           std::fprintf(stderr, "cityforge: %zu buildings (%zu in 3D)%s, %zu audit report(s); %.1f MB -> %s\n", r.buildings, r.meshed,
                                        r.ortho ? " over the ortho" : "", r.audits, double(r.bytes) / 1e6, r.path.c_str());
                           if (r.tiles) std::fprintf(stderr, "cityforge: 3D Tiles: %zu content tiles -> %s\n", r.tiles, r.tiles_bundle.c_str());
                       }
                       return 0;
                   }});
}

}  // namespace cityforge::cli
