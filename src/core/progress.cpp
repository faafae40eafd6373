#include "core/progress.hpp"

#include <algorithm>
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
    if (!force && !isatty(fileno(stderr))) return {};
    // State shared by copies of the callback: the last tick printed (0..40, 2.5 % each).
    struct State {
        std::mutex mutex;  // parallel stages may report from several threads
        int last = -1;
    };
    auto state = std::make_shared<State>();
    return [state](double fraction, std::string_view) {
        std::lock_guard lock(state->mutex);
        int* last = &state->last;
        const int tick = static_cast<int>(std::clamp(fraction, 0.0, 1.0) * 40.0 + 1e-9);
        if (tick <= *last) return true;
        for (int t = *last + 1; t <= tick; ++t) {
            if (t % 4 == 0)
                std::fprintf(stderr, "%d", t * 10 / 4);
            else
                std::fputc('.', stderr);
        }
        if (tick == 40) std::fputs(" - done.\n", stderr);
        std::fflush(stderr);
        *last = tick;
        return true;
    };
}

}  // namespace cityforge
