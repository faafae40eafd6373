#pragma once
// A typed attribute value of a feature: null, integer, real or text. Shared
// by the vector I/O, the building model and its exporters.
#include <cstdint>
#include <string>
#include <variant>

namespace cityforge {

/// Attribute value of a feature (null = std::monostate).
using AttributeValue = std::variant<std::monostate, int64_t, double, std::string>;

/// Declared type of an attribute (a field): kept even when every value is null.
enum class FieldType { integer, real, string };

}  // namespace cityforge
