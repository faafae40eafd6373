// The `cityforge` command: parses options, sets up logging and progress, calls
// one library function per subcommand and maps errors to exit codes. No
// algorithm lives here.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>
#include <optional>
#include <string>

#include "core/error.hpp"
#include "core/log.hpp"
#include "core/progress.hpp"
#include "io/inspect.hpp"
#include "synth/synth.hpp"

#ifndef CITYFORGE_VERSION
#define CITYFORGE_VERSION "0.0.0"
#endif

namespace cf = cityforge;

namespace {

struct GlobalFlags {
    bool quiet = false;
    bool verbose = false;
    bool progress = false;  // force progress even when stderr is not a terminal
};

cf::Progress make_progress(const GlobalFlags& g) {
    if (g.quiet) return {};
    return cf::Progress(cf::make_terminal_progress(g.progress));
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"cityforge: building extraction, heights and city models from aerial images and point clouds"};
    app.set_version_flag("--version", std::string("cityforge ") + CITYFORGE_VERSION);
    app.require_subcommand(1);
    app.fallthrough();  // global flags (--quiet, ...) may also follow the subcommand
    app.failure_message([](const CLI::App*, const CLI::Error& e) {
        return std::string("cityforge: error: ") + e.what() + " (see --help)\n";
    });
    GlobalFlags g;
    app.add_flag("-q,--quiet", g.quiet, "No progress and no messages except errors");
    app.add_flag("-v,--verbose", g.verbose, "More messages on stderr");
    app.add_flag("--progress", g.progress, "Show progress even when stderr is not a terminal");

    // info ------------------------------------------------------------------
    auto* info = app.add_subcommand("info", "Describe a raster, point cloud (LAS) or vector file");
    std::string info_path;
    bool info_json = false;
    cf::InspectOptions inspect_options;
    info->add_option("file", info_path, "Raster, LAS or vector file")->required();
    info->add_flag("--json", info_json, "Print JSON instead of text");
    info->add_flag("--stats", inspect_options.cloud_statistics, "Point clouds: read all points for class counts and bounds");
    info->add_option("--crs", inspect_options.assume_crs, "Assume this CRS (e.g. EPSG:7415) when the file has none");

    // synth -----------------------------------------------------------------
    auto* synth = app.add_subcommand("synth", "Generate a synthetic town with exact ground truth");
    std::string synth_out;
    cf::SynthOptions synth_options;
    std::string cloud_mode = "lidar";
    std::vector<double> origin;
    synth->add_option("--out", synth_out, "Output folder")->required();
    synth->add_option("--size-m", synth_options.size_m, "Scene edge length in metres")->capture_default_str();
    synth->add_option("--gsd", synth_options.gsd_m, "Ortho ground sample distance in metres")->capture_default_str();
    synth->add_option("--seed", synth_options.seed, "Random seed (same seed, same bytes)")->capture_default_str();
    synth->add_option("--epsg", synth_options.epsg, "Projected CRS (metres) of the outputs")->capture_default_str();
    synth->add_option("--origin", origin, "Lower-left corner X Y in the CRS")->expected(2);
    synth->add_option("--cloud-density", synth_options.cloud_density_m2, "Points per m2 (0 = no cloud)")->capture_default_str();
    synth->add_option("--cloud-mode", cloud_mode, "lidar or photo (dense image matching: noisier, gaps)")
        ->check(CLI::IsMember({"lidar", "photo"}))
        ->capture_default_str();

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        return app.exit(e);
    }
    cf::log::set_level(g.quiet ? cf::log::Level::quiet : g.verbose ? cf::log::Level::debug : cf::log::Level::warning);

    try {
        if (*info) {
            const cf::DatasetInfo d = cf::inspect_dataset(info_path, inspect_options);
            if (info_json) std::cout << cf::to_json(d).dump(2) << "\n";
            else std::cout << cf::to_text(d);
        } else if (*synth) {
            if (origin.size() == 2) synth_options.origin_x = origin[0], synth_options.origin_y = origin[1];
            synth_options.cloud_mode = cf::cloud_mode_from_string(cloud_mode);
            const cf::SynthResult r = cf::write_synthetic_town(synth_out, synth_options, make_progress(g));
            if (!g.quiet)
                std::fprintf(stderr, "cityforge: synth wrote %s (%d x %d px, %d buildings, %d trees, %llu points) in %.1f s\n",
                             synth_out.c_str(), r.width, r.height, r.buildings, r.trees,
                             static_cast<unsigned long long>(r.points), r.seconds);
        }
    } catch (const cf::Error& e) {
        std::fprintf(stderr, "cityforge: error: %s\n", e.what());
        return 1;
    } catch (const std::bad_alloc&) {
        std::fprintf(stderr, "cityforge: error: out of memory\n");
        return 3;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "cityforge: internal error: %s\n", e.what());
        return 2;
    }
    return 0;
}
