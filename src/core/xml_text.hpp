#pragma once
// Text for XML and HTML documents (CityGML, SVG, report pages).
#include <string>

namespace cityforge {

/// `text` with &, <, > and " escaped, and the control characters XML 1.0
/// forbids dropped (tab, newline and carriage return stay).
inline std::string xml_escape(const std::string& text) {
    std::string out;
    out.reserve(text.size());
    for (char c : text) {
        switch (c) {
            case '&': out += "&amp;"; break;
            case '<': out += "&lt;"; break;
            case '>': out += "&gt;"; break;
            case '"': out += "&quot;"; break;
            default:
                if (static_cast<unsigned char>(c) >= 0x20 || c == '\t' || c == '\n' || c == '\r') out += c;
        }
    }
    return out;
}

}  // namespace cityforge
