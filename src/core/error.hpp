#pragma once
// The one error type of cityforge. Library code throws it; the CLI catches it
// once, prints its message on one line and exits non-zero.
#include <stdexcept>
#include <string>

namespace cityforge {

/// A failure the user can act on. `what()` is one line naming the file (when
/// there is one) and the problem, e.g. "in.tif: raster has no georeferencing".
class Error : public std::runtime_error {
public:
    explicit Error(const std::string& message) : std::runtime_error(message) {}
    /// Builds "SUBJECT: problem" — SUBJECT is usually a file path or option name.
    Error(const std::string& subject, const std::string& problem)
        : std::runtime_error(subject + ": " + problem) {}
};

}  // namespace cityforge
