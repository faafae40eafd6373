#include "core/progress.hpp"

#include <algorithm>
#include <chrono>
#include <string>
#include <cstdio>
#include <memory>
#include <mutex>
#include <unistd.h>

#include "core/error.hpp"

namespace cityforge {

void Progress::operator()(double fraction, std::string_view message) const {
    if (!fn_) return;
    const double f = start_ + (end_ - start_) * std::clamp(fraction, 0.0, 1.0);
    if (!fn_(f, message)) throw Error("interrupted by the user");
}

ProgressFn make_terminal_progress(bool force) {
    const bool tty = isatty(fileno(stderr));
    if (!force && !tty) return {};
    // One status line: percent, the stage's own count ("tile 3/9 ..."), elapsed
    // time, rate and ETA. Rewritten in place on a terminal, one line per
    // step (at most one a second) otherwise.
    struct State {
        std::mutex mutex;  // parallel stages may report from several threads
        std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now(), last_print{};
        int last_percent = -1;
        std::size_t last_width = 0;
        bool done = false;
    };
    auto state = std::make_shared<State>();
    return [state, tty](double fraction, std::string_view message) {
        std::lock_guard lock(state->mutex);
        if (state->done) return true;
        const double f = std::clamp(fraction, 0.0, 1.0);
        const int percent = static_cast<int>(f * 100.0 + 1e-9);
        const auto now = std::chrono::steady_clock::now();
        const double since_print = std::chrono::duration<double>(now - state->last_print).count();
        if (percent < 100 && (percent == state->last_percent || since_print < (tty ? 0.2 : 1.0))) return true;
        const double elapsed = std::chrono::duration<double>(now - state->start).count();
        auto clock = [](double seconds) {
            const long t = static_cast<long>(seconds + 0.5);
            char buf[32];
            if (t >= 3600) std::snprintf(buf, sizeof buf, "%ld:%02ld:%02ld", t / 3600, (t / 60) % 60, t % 60);
            else std::snprintf(buf, sizeof buf, "%ld:%02ld", t / 60, t % 60);
            return std::string(buf);
        };
        std::string line = "cityforge: " + std::to_string(percent) + " %";
        if (!message.empty()) line += " " + std::string(message);
        line += ", " + clock(elapsed) + " elapsed";
        if (f > 0.0 && f < 1.0 && elapsed > 1.0) {
            char rate[48];
            std::snprintf(rate, sizeof rate, ", %.1f %%/s", 100.0 * f / elapsed);
            line += rate + std::string(", ETA ") + clock(elapsed * (1.0 - f) / f);
        }
        if (tty) {
            const std::size_t width = line.size();
            if (width < state->last_width) line.append(state->last_width - width, ' ');
            state->last_width = width;
            std::fprintf(stderr, "\r%s", line.c_str());
            if (percent >= 100) std::fputc('\n', stderr);
        } else {
            std::fprintf(stderr, "%s\n", line.c_str());
        }
        std::fflush(stderr);
        state->last_percent = percent;
        state->last_print = now;
        state->done = percent >= 100;
        return true;
    };
}

}  // namespace cityforge
