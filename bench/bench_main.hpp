#pragma once
// The benchmarks' common entry point: `--help` / `-h` prints the usage and
// exits 0; a cityforge::Error (bad argument, unreadable file) or any other
// exception is caught here, once, and printed as one line on stderr with a
// non-zero exit (1 for Error, 3 out of memory, 70 otherwise), as the CLI does.
// Numeric positional arguments are parsed strictly (no silent 0 from atof).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <new>
#include <string>

#include "core/resource_usage.hpp"
#include "core/error.hpp"

namespace cityforge::bench {

/// Wall-clock seconds (steady clock; differences only).
inline double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

/// CPU seconds of the whole process so far (all threads).
inline double cpu_now() { return cityforge::process_cpu_seconds(); }

/// `text` as a finite number, or Error naming `what` (e.g. "size_m").
inline double parse_number(const char* text, const char* what) {
    char* end = nullptr;
    const double v = std::strtod(text, &end);
    if (end == text || *end != '\0' || !(v == v) || v > 1e300 || v < -1e300)
        throw Error(what, std::string("not a number: \"") + text + "\"");
    return v;
}

/// Runs `body(argc, argv)` with the usage line `usage` (without the leading
/// "usage: ") and the program name `name` for messages.
template <class Body>
int run_main(int argc, char** argv, const char* name, const char* usage, Body&& body) {
    for (int i = 1; i < argc; ++i)
        if (!std::strcmp(argv[i], "--help") || !std::strcmp(argv[i], "-h")) {
            std::printf("usage: %s\n", usage);
            return 0;
        }
    try {
        return body(argc, argv);
    } catch (const Error& e) {
        std::fprintf(stderr, "%s: error: %s\n", name, e.what());
        return 1;
    } catch (const std::bad_alloc&) {
        std::fprintf(stderr, "%s: error: out of memory\n", name);
        return 3;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "%s: internal error: %s\n", name, e.what());
        return 70;
    }
}

}  // namespace cityforge::bench
