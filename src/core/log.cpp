#include "core/log.hpp"

#include <atomic>
#include <cstdio>
#include <mutex>

namespace cityforge::log {
namespace {
std::atomic<Level> g_level{Level::warning};
std::mutex g_mutex;
void emit(const char* tag, std::string_view message) {
    std::lock_guard lock(g_mutex);
    std::fprintf(stderr, "cityforge: %s%.*s\n", tag, static_cast<int>(message.size()), message.data());
}
}  // namespace

void set_level(Level l) { g_level = l; }
Level level() { return g_level; }
void warning(std::string_view m) { if (g_level >= Level::warning) emit("warning: ", m); }
void info(std::string_view m) { if (g_level >= Level::info) emit("", m); }
void debug(std::string_view m) { if (g_level >= Level::debug) emit("debug: ", m); }

}  // namespace cityforge::log
