#pragma once
// Pass/fail gates of an audit, for CI: `--fail-below f1=0.8,iou=0.7` and
// `--fail-above mae=0.5`. Each audit publishes its measures by name; a gate
// names one of them and a limit. No GDAL.
#include <map>
#include <string>
#include <vector>

namespace cityforge {

struct AuditGate {
    std::string measure;   ///< a name from the audit's measure table, e.g. "f1", "mae", "f@0.5"
    double limit = 0.0;    ///< in the measure's unit (metres, %, or a ratio)
    bool minimum = true;   ///< true: fail when value < limit; false: fail when value > limit
};

/// Parses "NAME=VALUE[,NAME=VALUE...]". Throws Error naming `option` on
/// malformed text. `minimum` sets the direction of every gate parsed.
std::vector<AuditGate> parse_gates(const std::string& text, const std::string& option, bool minimum);

/// Throws Error naming the option when a gate names a measure not in `known`.
void check_gate_names(const std::vector<AuditGate>& gates, const std::vector<std::string>& known);

struct GateOutcome {
    bool passed = true;
    std::vector<std::string> failed;  ///< e.g. "f1 0.71 < 0.8"
};

/// Evaluates the gates against the measured values. A measure that is absent
/// (e.g. no matches, so no mean IoU) fails its gate, said as "not measured".
GateOutcome evaluate_gates(const std::vector<AuditGate>& gates, const std::map<std::string, double>& measures);

}  // namespace cityforge
