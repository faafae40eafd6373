#pragma once
// Minimal leveled logging to stderr. Results never go here, only diagnostics.
// The level is process-wide configuration set once by the CLI (like a logger
// sink), not error state: library code never reads it to decide behaviour.
#include <string_view>

namespace cityforge::log {

enum class Level { quiet = 0, warning = 1, info = 2, debug = 3 };

void set_level(Level level);
Level level();

void warning(std::string_view message);
void info(std::string_view message);
void debug(std::string_view message);

}  // namespace cityforge::log
