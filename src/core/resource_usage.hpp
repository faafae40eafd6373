#pragma once
// What this process has used: CPU time (seconds; only differences mean
// anything) and peak memory, for the figures stages and benchmarks report.
// POSIX; no dependencies.
#include <sys/resource.h>
#include <time.h>

namespace cityforge {

/// CPU seconds of the whole process so far (all threads, user + system).
inline double process_cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

/// CPU seconds of the calling thread so far.
inline double thread_cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

/// Peak resident memory of the process so far, MB (2^20 bytes).
inline double peak_memory_mb() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return static_cast<double>(u.ru_maxrss) / 1024.0;
}

}  // namespace cityforge
