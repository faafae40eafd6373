// One registration function per subcommand file: each adds its subcommand(s)
// to `parent` and its leaf commands to `out`.
#pragma once

#include "cli_support.hpp"

namespace cityforge::cli {

void add_info_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);        // commands/info.cpp
void add_synth_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);       // commands/synth.cpp
void add_segment_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);     // commands/segment.cpp
void add_heights_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);     // commands/heights.cpp
void add_cloud_commands(CLI::App& parent, const GlobalFlags& g, CommandList& out);      // commands/cloud.cpp (cloud rasterize, ...)
void add_cloud_translate_command(CLI::App& cloud, const GlobalFlags& g, CommandList& out);  // commands/cloud_translate.cpp (under `cloud`)
void add_footprints_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);  // commands/footprints.cpp
void add_train_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);       // commands/train.cpp
void add_export_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);      // commands/export.cpp
void add_roofs_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);       // commands/roofs.cpp
void add_run_commands(CLI::App& parent, const GlobalFlags& g, CommandList& out);        // commands/run.cpp (run, plan, merge-tiles)
void add_view_command(CLI::App& parent, const GlobalFlags& g, CommandList& out);         // commands/view.cpp
void add_audit_commands(CLI::App& parent, const GlobalFlags& g, CommandList& out);      // commands/audit.cpp (audit footprints, ...)

}  // namespace cityforge::cli
