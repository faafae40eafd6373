#include "audit/gates.hpp"

#include <algorithm>
#include <sstream>

#include "core/error.hpp"

namespace cityforge {

std::vector<AuditGate> parse_gates(const std::string& text, const std::string& option, bool minimum) {
    std::vector<AuditGate> gates;
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, ',')) {
        if (item.empty()) continue;
        const auto eq = item.find('=');
        if (eq == std::string::npos || eq == 0) throw Error(option, "expected NAME=VALUE, got '" + item + "'");
        std::size_t used = 0;
        double v = 0.0;
        try {
            v = std::stod(item.substr(eq + 1), &used);
        } catch (const std::exception&) {
            used = 0;
        }
        if (used == 0 || used != item.size() - eq - 1) throw Error(option, "bad number in '" + item + "'");
        gates.push_back({item.substr(0, eq), v, minimum});
    }
    return gates;
}

void check_gate_names(const std::vector<AuditGate>& gates, const std::vector<std::string>& known) {
    for (const AuditGate& g : gates)
        if (std::find(known.begin(), known.end(), g.measure) == known.end()) {
            std::string list;
            for (const std::string& k : known) list += (list.empty() ? "" : ", ") + k;
            throw Error(g.minimum ? "--fail-below" : "--fail-above", "unknown measure '" + g.measure + "' (known: " + list + ")");
        }
}

GateOutcome evaluate_gates(const std::vector<AuditGate>& gates, const std::map<std::string, double>& measures) {
    GateOutcome out;
    for (const AuditGate& g : gates) {
        std::ostringstream msg;
        const auto it = measures.find(g.measure);
        if (it == measures.end()) {
            msg << g.measure << " not measured";
        } else if (g.minimum ? it->second < g.limit : it->second > g.limit) {
            msg << g.measure << " " << it->second << (g.minimum ? " < " : " > ") << g.limit;
        } else {
            continue;
        }
        out.passed = false;
        out.failed.push_back(msg.str());
    }
    return out;
}

}  // namespace cityforge
