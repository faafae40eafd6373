#include <algorithm>
#include <cstdio>
#include <string>
#include <sys/resource.h>
#include <unistd.h>

#include "core/memory.hpp"

namespace cityforge {

double usable_memory_bytes() {
    double limit = 0.0;
    const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
    if (pages > 0 && page > 0) limit = static_cast<double>(pages) * static_cast<double>(page);
    rlimit as{};
    if (::getrlimit(RLIMIT_AS, &as) == 0 && as.rlim_cur != RLIM_INFINITY) {
        const auto v = static_cast<double>(as.rlim_cur);
        limit = limit > 0.0 ? std::min(limit, v) : v;
    }
    return limit;
}

std::string format_bytes(double bytes) {
    char b[32];
    if (bytes >= 1e9) std::snprintf(b, sizeof b, "%.1f GB", bytes / 1e9);
    else std::snprintf(b, sizeof b, "%.0f MB", bytes / 1e6);
    return b;
}

}  // namespace cityforge
