// cityforge info: describe a raster, point cloud or vector file.
#include <iostream>
#include <memory>

#include "commands/commands.hpp"
#include "io/inspect.hpp"

namespace cityforge::cli {

void add_info_command(CLI::App& parent, const GlobalFlags&, CommandList& out) {
    struct State {
        std::string path;
        bool json = false;
        InspectOptions options;
    };
    auto s = std::make_shared<State>();
    auto* cmd = parent.add_subcommand("info", "Describe a raster, point cloud (LAS) or vector file");
    cmd->add_option("file", s->path, "Raster, LAS or vector file")->required();
    cmd->add_flag("--json", s->json, "Print JSON instead of text");
    cmd->add_flag("--stats", s->options.cloud_statistics, "Point clouds: read all points for class counts and bounds");
    cmd->add_option("--crs", s->options.assume_crs, "Assume this CRS (e.g. EPSG:7415) when the file has none");
    out.push_back({cmd, [s]() {
                       const DatasetInfo d = inspect_dataset(s->path, s->options);
                       if (s->json) std::cout << to_json(d).dump(2) << "\n";
                       else std::cout << to_text(d);
                       return 0;
                   }});
}

}  // namespace cityforge::cli
