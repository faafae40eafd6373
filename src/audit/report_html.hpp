#pragma once
// Self-contained HTML audit reports: tables and inline SVG charts (error
// histogram, predicted-vs-reference scatter, footprint map coloured by a
// measure, optionally over a PNG picture of the ortho embedded as a data URI).
// The page loads nothing from the network. No GDAL.
#include <string>
#include <vector>

#include "core/geometry.hpp"

namespace cityforge {

/// Histogram of `values` (NaNs skipped) with `bins` equal-width bins.
std::string svg_histogram(const std::vector<double>& values, const std::string& x_label, int bins = 20);

/// Bar chart of counts in equal bins over [low, high).
std::string svg_bar_chart(double low, double high, const std::vector<double>& counts, const std::string& x_label,
                          const std::string& y_label = "count");

/// Scatter of (x[i], y[i]) with the y = x line; NaN pairs skipped.
std::string svg_scatter(const std::vector<double>& x, const std::vector<double>& y, const std::string& x_label,
                        const std::string& y_label);

/// A background picture for a map: PNG bytes covering `extent` (map units).
struct MapPicture {
    std::string png;
    Extent extent;
};

/// Footprints in map coordinates filled by `values` on a colour ramp from
/// `low` to `high` (a NaN value draws the footprint hollow in red: e.g. a
/// false positive), plus grey `outlines` (e.g. unmatched references). North
/// up, equal scale on both axes.
std::string svg_footprint_map(const std::vector<std::vector<Polygon>>& shapes, const std::vector<double>& values, double low,
                              double high, const std::string& value_label, const std::vector<std::vector<Polygon>>& outlines = {},
                              const MapPicture* background = nullptr);

/// Builds one HTML page, section by section.
class HtmlReport {
public:
    explicit HtmlReport(std::string title);
    void heading(const std::string& text);
    void paragraph(const std::string& text);
    /// `rows` beyond `max_rows` are left out with a note (the JSON has them all).
    void table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows, std::size_t max_rows = 5000);
    void figure(const std::string& svg, const std::string& caption);
    std::string render() const;

private:
    std::string title_, body_;
};

/// Formats a number with `digits` significant digits ("-" for NaN).
std::string format_number(double v, int digits = 4);

}  // namespace cityforge
