#pragma once
// Progress reporting in the spirit of GDALProgressFunc, without global state:
// long-running library functions take a `const Progress&` and call it.
#include <functional>
#include <string_view>

namespace cityforge {

/// Called with the fraction done (0..1) and a short stage message. Returning
/// false asks the callee to stop; it then throws Error("interrupted").
using ProgressFn = std::function<bool(double fraction, std::string_view message)>;

/// A possibly empty progress sink, with a sub-range helper so that a stage can
/// report 0..1 while the caller maps it into its own [start, end] window.
class Progress {
public:
    Progress() = default;
    explicit Progress(ProgressFn fn, double start = 0.0, double end = 1.0)
        : fn_(std::move(fn)), start_(start), end_(end) {}

    /// Reports `fraction` (0..1 of this range). Throws Error if the sink asks to stop.
    void operator()(double fraction, std::string_view message = {}) const;

    /// A progress over the sub-range [a, b] (fractions of this range).
    Progress sub(double a, double b) const {
        return Progress(fn_, start_ + (end_ - start_) * a, start_ + (end_ - start_) * b);
    }
    bool active() const { return static_cast<bool>(fn_); }

private:
    ProgressFn fn_;
    double start_ = 0.0;
    double end_ = 1.0;
};

/// A progress line on stderr: "cityforge: 45 % tile 4/9 (ok), ETA 12 s, 0:31
/// elapsed, 1.5 %/s, ETA 0:38" (percent, the stage's own count, elapsed
/// time, rate, ETA), rewritten in place on a terminal, else one line per
/// percent step at most once a second. Writes nothing when stderr is not a
/// terminal unless `force` is set (--progress).
ProgressFn make_terminal_progress(bool force = false);

}  // namespace cityforge
