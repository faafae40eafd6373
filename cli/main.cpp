// The `cityforge` command: sets up the global flags, registers one file's
// subcommands each (cli/commands/*.cpp), runs the chosen one and maps errors
// to exit codes. No algorithm lives here; each subcommand calls one library
// function with a typed options struct.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>
#include <new>

#include "cli_support.hpp"
#include "commands/commands.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "core/memory.hpp"
#include "core/version.hpp"

namespace cf = cityforge;
namespace cli = cityforge::cli;

int main(int argc, char** argv) {
    CLI::App app{"cityforge: building extraction, heights and city models from aerial images and point clouds"};
    app.set_version_flag("--version", std::string("cityforge ") + cf::version());
    app.require_subcommand(1);
    app.fallthrough();  // global flags (--quiet, ...) may also follow the subcommand
    app.failure_message([](const CLI::App*, const CLI::Error& e) {
        return std::string("cityforge: error: ") + e.what() + " (see --help)\n";
    });
    cli::GlobalFlags g;
    app.add_flag("-q,--quiet", g.quiet, "No progress and no messages except errors");
    app.add_flag("-v,--verbose", g.verbose, "More messages on stderr");
    app.add_flag("--progress", g.progress, "Show progress even when stderr is not a terminal");
    app.add_flag("--overwrite", g.overwrite, "Replace existing outputs (refused otherwise)");
    app.footer("Exit status: 0 success, 1 data error (bad or unusable input, output exists, nothing found), 2 usage error, "
               "3 out of memory, 4 an audit gate failed, 5 a partial result (run, merge-tiles: some tiles failed), 70 internal error.");

    cli::CommandList commands;
    cli::add_info_command(app, g, commands);
    cli::add_synth_command(app, g, commands);
    cli::add_segment_command(app, g, commands);
    cli::add_heights_command(app, g, commands);
    cli::add_cloud_commands(app, g, commands);
    cli::add_footprints_command(app, g, commands);
    cli::add_train_command(app, g, commands);
    cli::add_export_command(app, g, commands);
    cli::add_roofs_command(app, g, commands);
    cli::add_run_commands(app, g, commands);
    cli::add_audit_commands(app, g, commands);
    cli::add_view_command(app, g, commands);
    cli::add_photo_commands(app, g, commands);

    // An unknown subcommand is named, with the closest one (CLI11 would only say one is required).
    if (const std::string unknown = cli::unknown_subcommand_message(app, argc, argv); !unknown.empty()) {
        std::fprintf(stderr, "cityforge: error: %s\n", unknown.c_str());
        return 2;
    }
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        // --help and --version exit 0; every usage error exits 2 (not CLI11's own codes).
        return app.exit(e) == 0 ? 0 : 2;
    }
    cf::log::set_level(g.quiet ? cf::log::Level::quiet : g.verbose ? cf::log::Level::debug : cf::log::Level::warning);
    // Ctrl-C, kill and a closed terminal remove the temporaries being written
    // (x.part-PID.ext, 3dtiles.part-PID/), then end the process as the signal asks.
    cf::remove_temporaries_on_signals();

    try {
        for (const cli::Command& c : commands)
            if (c.app->parsed()) {
                const int rc = c.run();
                // Results printed to stdout count as output: a full disk or a
                // closed pipe (`info --json > /dev/full`) is a failed write.
                std::cout.flush();
                if (rc == 0 && (!std::cout || std::fflush(stdout) != 0 || std::ferror(stdout))) {
                    std::fprintf(stderr, "cityforge: error: stdout: write failed (disk full or closed pipe?)\n");
                    return 1;
                }
                return rc;
            }
    } catch (const cf::OutOfMemory& e) {  // names the file and the size
        std::fprintf(stderr, "cityforge: error: %s\n", e.what());
        return 3;
    } catch (const cf::Error& e) {
        std::fprintf(stderr, "cityforge: error: %s\n", e.what());
        return 1;
    } catch (const std::bad_alloc&) {
        std::fprintf(stderr, "cityforge: error: out of memory\n");
        return 3;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "cityforge: internal error: %s\n", e.what());
        return 70;
    }
    return 0;
}
