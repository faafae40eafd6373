// Shared pieces of the `cityforge` command: global flags, the registry of
// subcommands and small parsers of option text. No algorithm lives here.
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/progress.hpp"
#include "crs/crs.hpp"

namespace cityforge::cli {

// Flags every subcommand accepts (before or after the subcommand's name).
struct GlobalFlags {
    bool quiet = false;     // nothing on stderr but errors
    bool verbose = false;   // debug messages
    bool progress = false;  // progress even when stderr is not a terminal
    bool overwrite = false; // replace existing outputs
};

// Refuses an existing output (a file, or a folder that is not empty) unless
// --overwrite was given: Error "PATH: exists; give --overwrite to replace it".
// First removes the temporaries dead processes left there
// (remove_stale_temporaries_beside), so a folder holding only those is empty.
void refuse_existing_output(const GlobalFlags& g, const std::string& path);

// Warns when the cloud's CRS (`cloud_crs` overriding the file's) has no
// vertical part: the heights `what` names are then written without a named
// datum; `remedy` names the option that gives one (the CRS to give follows). Nothing when the cloud has no
// CRS at all (the command refuses it) or names its vertical CRS.
void warn_without_vertical_crs(const std::string& cloud, const std::string& cloud_crs, const std::string& what, const std::string& remedy);

// Removes the temporaries ("NAME.part-PID.EXT" files, "NAME.part-PID"
// folders) that processes of this machine which are no longer running (killed,
// crashed) left beside the output `path` (in its parent folder) and, when
// `path` is a folder, inside it; an info line says how many. Every writing
// command calls it (through refuse_existing_output or directly). Not for
// folders several hosts write to (run --tile, --mpi, merge-tiles).
void remove_stale_temporaries_beside(const std::string& path);

// "unknown subcommand 'segmnt'; did you mean 'segment'?" when the first word
// of `argv` that is not an option names no subcommand of `app` (at any
// level: `audit footprnts`); empty when all is well.
std::string unknown_subcommand_message(const CLI::App& app, int argc, char** argv);

// One leaf subcommand: its CLI11 parser and what runs when it was chosen.
// `run` calls one library function and returns the process exit status;
// library errors propagate as cityforge::Error and are caught once in main.
struct Command {
    CLI::App* app = nullptr;
    std::function<int()> run;
};

// Every subcommand file adds its leaf commands to this list.
using CommandList = std::vector<Command>;

// The progress sink the global flags ask for (none with --quiet).
Progress make_progress(const GlobalFlags& g);

// {"a", "b"} -> "a b".
std::string join_words(const std::vector<std::string>& words);

// "a,b,,c" -> {"a", "b", "c"}.
std::vector<std::string> split_list(const std::string& text);

// "0,1,2" -> {0, 1, 2}; other levels are refused (Error naming --lod).
std::vector<int> parse_lods(const std::string& text);

// Parses a JSON file or throws Error naming it.
nlohmann::json read_json_file(const std::string& path);

// The CRS a --vertical-crs option names; Error naming `option` when it has no
// vertical part (e.g. a projected CRS given by mistake).
CrsInfo vertical_crs_option(const std::string& text, const std::string& option = "--vertical-crs");

// Error naming `path` when it is not a raster GDAL reads (missing, a folder,
// empty, not georeferenced): options read late in a command (--texture-ortho)
// are checked before anything is written. Nothing for an empty path.
void require_readable_raster(const std::string& path);

}  // namespace cityforge::cli
