#pragma once
// Work that does not fit in memory: one Error subtype naming the file and the
// size, and what this process may allocate.
#include <string>

#include "core/error.hpp"

namespace cityforge {

/// An Error for work that does not fit in memory, naming the file and the size
/// asked for; the CLI exits 3 on it, as on a bare std::bad_alloc (which names
/// nothing). Thrown before a large allocation when it cannot fit, or in place
/// of a std::bad_alloc caught where the file is known.
class OutOfMemory : public Error {
public:
    OutOfMemory(const std::string& subject, const std::string& problem) : Error(subject, "out of memory: " + problem) {}
    /// `inner` re-thrown under the file it came from: "SUBJECT: <inner's message>"
    /// (e.g. "city.xyz: ground filter: out of memory: ...").
    OutOfMemory(const std::string& subject, const OutOfMemory& inner) : Error(subject, inner.what()) {}
};

/// Bytes this process may allocate at most: the smaller of the machine's
/// physical memory and the address-space limit (ulimit -v); 0 if unknown.
double usable_memory_bytes();

/// "12.7 GB", "850 MB": a byte count for messages.
std::string format_bytes(double bytes);

}  // namespace cityforge
