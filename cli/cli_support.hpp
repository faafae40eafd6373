// Shared pieces of the `cityforge` command: global flags, the registry of
// subcommands and small parsers of option text. No algorithm lives here.
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/progress.hpp"

namespace cityforge::cli {

// Flags every subcommand accepts (before or after the subcommand's name).
struct GlobalFlags {
    bool quiet = false;     // nothing on stderr but errors
    bool verbose = false;   // debug messages
    bool progress = false;  // progress even when stderr is not a terminal
};

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

}  // namespace cityforge::cli
