#include "audit/report_html.hpp"

#include "core/base64.hpp"
#include "core/xml_text.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <sstream>

namespace cityforge {

std::string format_number(double v, int digits) {
    if (std::isnan(v)) return "-";
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.*g", digits, v);
    return buf;
}

namespace {

constexpr int kWidth = 640, kHeight = 400, kLeft = 60, kRight = 20, kTop = 20, kBottom = 50;


// "Nice" tick step for a range (1, 2 or 5 times a power of ten).
double tick_step(double span, int target = 6) {
    if (!(span > 0)) return 1.0;
    const double raw = span / target, p = std::pow(10.0, std::floor(std::log10(raw)));
    for (double m : {1.0, 2.0, 5.0, 10.0})
        if (raw <= m * p) return m * p;
    return 10 * p;
}

// Axes with ticks for data range [x0, x1] x [y0, y1]; returns the opening SVG.
struct Axes {
    double x0, x1, y0, y1;
    double px(double x) const { return kLeft + (x - x0) / (x1 - x0) * (kWidth - kLeft - kRight); }
    double py(double y) const { return kHeight - kBottom - (y - y0) / (y1 - y0) * (kHeight - kTop - kBottom); }
    std::string open(const std::string& x_label, const std::string& y_label) const {
        std::ostringstream s;
        s << "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 " << kWidth << ' ' << kHeight << "\" width=\"" << kWidth
          << "\" height=\"" << kHeight << "\" font-family=\"sans-serif\" font-size=\"11\">\n"
          << "<rect x=\"0\" y=\"0\" width=\"" << kWidth << "\" height=\"" << kHeight << "\" fill=\"white\"/>\n";
        const double sx = tick_step(x1 - x0), sy = tick_step(y1 - y0);
        for (double t = std::ceil(x0 / sx) * sx; t <= x1 + 1e-9 * sx; t += sx)
            s << "<line x1=\"" << px(t) << "\" y1=\"" << kTop << "\" x2=\"" << px(t) << "\" y2=\"" << kHeight - kBottom
              << "\" stroke=\"#eee\"/><text x=\"" << px(t) << "\" y=\"" << kHeight - kBottom + 14 << "\" text-anchor=\"middle\">"
              << format_number(std::abs(t) < 1e-12 ? 0.0 : t) << "</text>\n";
        for (double t = std::ceil(y0 / sy) * sy; t <= y1 + 1e-9 * sy; t += sy)
            s << "<line x1=\"" << kLeft << "\" y1=\"" << py(t) << "\" x2=\"" << kWidth - kRight << "\" y2=\"" << py(t)
              << "\" stroke=\"#eee\"/><text x=\"" << kLeft - 4 << "\" y=\"" << py(t) + 4 << "\" text-anchor=\"end\">"
              << format_number(std::abs(t) < 1e-12 ? 0.0 : t) << "</text>\n";
        s << "<rect x=\"" << kLeft << "\" y=\"" << kTop << "\" width=\"" << kWidth - kLeft - kRight << "\" height=\""
          << kHeight - kTop - kBottom << "\" fill=\"none\" stroke=\"#333\"/>\n"
          << "<text x=\"" << (kLeft + kWidth - kRight) / 2 << "\" y=\"" << kHeight - 12 << "\" text-anchor=\"middle\">" << xml_escape(x_label)
          << "</text>\n<text transform=\"translate(14," << (kTop + kHeight - kBottom) / 2 << ") rotate(-90)\" text-anchor=\"middle\">"
          << xml_escape(y_label) << "</text>\n";
        return s.str();
    }
};

std::string empty_chart(const std::string& what) {
    std::ostringstream s;
    s << "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 " << kWidth << " 60\" width=\"" << kWidth
      << "\" height=\"60\" font-family=\"sans-serif\" font-size=\"12\"><text x=\"10\" y=\"30\">no data for " << xml_escape(what)
      << "</text></svg>\n";
    return s.str();
}

// Viridis, sampled at 5 stops and interpolated linearly.
std::string ramp_colour(double t) {
    static const std::array<std::array<double, 3>, 5> stops{{{68, 1, 84}, {59, 82, 139}, {33, 145, 140}, {94, 201, 98}, {253, 231, 37}}};
    t = std::clamp(std::isnan(t) ? 0.0 : t, 0.0, 1.0) * 4.0;
    const int i = std::min(3, static_cast<int>(t));
    const double f = t - i;
    char buf[16];
    std::snprintf(buf, sizeof buf, "#%02x%02x%02x", static_cast<int>(stops[i][0] + f * (stops[i + 1][0] - stops[i][0])),
                  static_cast<int>(stops[i][1] + f * (stops[i + 1][1] - stops[i][1])),
                  static_cast<int>(stops[i][2] + f * (stops[i + 1][2] - stops[i][2])));
    return buf;
}

}  // namespace

std::string svg_bar_chart(double lo, double hi, const std::vector<double>& count, const std::string& x_label, const std::string& y_label) {
    if (count.empty() || !(hi > lo)) return empty_chart(x_label);
    const int bins = static_cast<int>(count.size());
    const double top = std::max(1.0, *std::max_element(count.begin(), count.end()));
    const Axes ax{lo, hi, 0.0, top * 1.05};
    std::ostringstream s;
    s << ax.open(x_label, y_label);
    for (int b = 0; b < bins; ++b) {
        if (!(count[b] > 0)) continue;
        const double a = lo + (hi - lo) * b / bins, c = lo + (hi - lo) * (b + 1) / bins;
        s << "<rect x=\"" << ax.px(a) << "\" y=\"" << ax.py(count[b]) << "\" width=\"" << std::max(1.0, ax.px(c) - ax.px(a) - 1)
          << "\" height=\"" << ax.py(0) - ax.py(count[b]) << "\" fill=\"#3b528b\"><title>" << format_number(a) << " .. " << format_number(c)
          << ": " << format_number(count[b], 12) << "</title></rect>\n";
    }
    s << "</svg>\n";
    return s.str();
}

std::string svg_histogram(const std::vector<double>& values, const std::string& x_label, int bins) {
    std::vector<double> v;
    for (double x : values)
        if (std::isfinite(x)) v.push_back(x);
    if (v.empty()) return empty_chart(x_label);
    auto [lo_it, hi_it] = std::minmax_element(v.begin(), v.end());
    double lo = *lo_it, hi = *hi_it;
    if (hi - lo < 1e-12) lo -= 0.5, hi += 0.5;
    bins = std::max(1, bins);
    std::vector<double> count(bins, 0.0);
    for (double x : v) count[std::min(bins - 1, static_cast<int>((x - lo) / (hi - lo) * bins))] += 1.0;
    return svg_bar_chart(lo, hi, count, x_label);
}

std::string svg_scatter(const std::vector<double>& x, const std::vector<double>& y, const std::string& x_label, const std::string& y_label) {
    double lo = INFINITY, hi = -INFINITY;
    std::size_t n = 0;
    for (std::size_t i = 0; i < std::min(x.size(), y.size()); ++i)
        if (std::isfinite(x[i]) && std::isfinite(y[i])) lo = std::min({lo, x[i], y[i]}), hi = std::max({hi, x[i], y[i]}), ++n;
    if (!n) return empty_chart(y_label);
    const double pad = std::max(1e-9, (hi - lo) * 0.05);
    lo -= pad, hi += pad;
    const Axes ax{lo, hi, lo, hi};
    std::ostringstream s;
    s << ax.open(x_label, y_label);
    s << "<line x1=\"" << ax.px(lo) << "\" y1=\"" << ax.py(lo) << "\" x2=\"" << ax.px(hi) << "\" y2=\"" << ax.py(hi)
      << "\" stroke=\"#c00\" stroke-dasharray=\"4 3\"/>\n";
    for (std::size_t i = 0; i < std::min(x.size(), y.size()); ++i)
        if (std::isfinite(x[i]) && std::isfinite(y[i]))
            s << "<circle cx=\"" << ax.px(x[i]) << "\" cy=\"" << ax.py(y[i]) << "\" r=\"3\" fill=\"#21918c\" fill-opacity=\"0.7\"/>\n";
    s << "</svg>\n";
    return s.str();
}

std::string svg_footprint_map(const std::vector<std::vector<Polygon>>& shapes, const std::vector<double>& values, double low,
                              double high, const std::string& value_label, const std::vector<std::vector<Polygon>>& outlines,
                              const MapPicture* background) {
    Extent e = empty_extent();
    for (const auto* set : {&shapes, &outlines})
        for (const auto& parts : *set) include(e, parts_extent(parts));
    if (!(e.max_x > e.min_x && e.max_y > e.min_y)) return empty_chart(value_label);
    const double pad = 0.03 * std::max(e.width(), e.height());
    e.min_x -= pad, e.min_y -= pad, e.max_x += pad, e.max_y += pad;
    const double map_w = 800.0, scale = map_w / e.width(), map_h = e.height() * scale;
    const double legend_h = 50.0;
    auto X = [&](double x) { return (x - e.min_x) * scale; };
    auto Y = [&](double y) { return (e.max_y - y) * scale; };
    auto path = [&](const std::vector<Polygon>& parts) {
        std::ostringstream d;
        d.precision(7);
        auto ring = [&](const Ring& r) {
            for (std::size_t i = 0; i < r.size(); ++i) d << (i ? 'L' : 'M') << X(r[i].x) << ',' << Y(r[i].y);
            d << 'Z';
        };
        for (const Polygon& p : parts) {
            ring(p.outer);
            for (const Ring& h : p.holes) ring(h);
        }
        return d.str();
    };
    std::ostringstream s;
    s.precision(7);
    s << "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 " << map_w << ' ' << map_h + legend_h << "\" width=\"" << map_w
      << "\" height=\"" << map_h + legend_h << "\" font-family=\"sans-serif\" font-size=\"11\">\n<rect width=\"" << map_w << "\" height=\""
      << map_h << "\" fill=\"#f4f4f4\"/>\n";
    if (background && !background->png.empty())
        s << "<image x=\"" << X(background->extent.min_x) << "\" y=\"" << Y(background->extent.max_y) << "\" width=\""
          << background->extent.width() * scale << "\" height=\"" << background->extent.height() * scale
          << "\" preserveAspectRatio=\"none\" href=\"data:image/png;base64," << base64(background->png) << "\"/>\n";
    for (const auto& parts : outlines)
        s << "<path d=\"" << path(parts) << "\" fill=\"none\" stroke=\"#888\" stroke-width=\"1\" stroke-dasharray=\"3 2\" fill-rule=\"evenodd\"/>\n";
    const double span = high > low ? high - low : 1.0;
    for (std::size_t i = 0; i < shapes.size(); ++i) {
        const double v = i < values.size() ? values[i] : NAN;
        if (std::isnan(v))
            s << "<path d=\"" << path(shapes[i]) << "\" fill=\"none\" stroke=\"#d00\" stroke-width=\"1.5\" fill-rule=\"evenodd\"><title>"
              << xml_escape(value_label) << ": none</title></path>\n";
        else
            s << "<path d=\"" << path(shapes[i]) << "\" fill=\"" << ramp_colour((v - low) / span)
              << "\" fill-opacity=\"0.75\" stroke=\"#222\" stroke-width=\"0.5\" fill-rule=\"evenodd\"><title>" << xml_escape(value_label)
              << ": " << format_number(v) << "</title></path>\n";
    }
    // Legend: colour ramp, its ends, and the scale bar.
    const double ly = map_h + 12;
    for (int k = 0; k < 50; ++k)
        s << "<rect x=\"" << 10 + k * 4 << "\" y=\"" << ly << "\" width=\"4\" height=\"12\" fill=\"" << ramp_colour(k / 49.0) << "\"/>";
    s << "\n<text x=\"10\" y=\"" << ly + 26 << "\">" << format_number(low) << "</text><text x=\"210\" y=\"" << ly + 26
      << "\" text-anchor=\"end\">" << format_number(high) << "</text><text x=\"220\" y=\"" << ly + 10 << "\">" << xml_escape(value_label)
      << " (red outline: none; dashed grey: reference without match)</text>\n";
    const double bar = tick_step(e.width() / 4, 1);
    s << "<line x1=\"" << map_w - 20 - bar * scale << "\" y1=\"" << ly + 20 << "\" x2=\"" << map_w - 20 << "\" y2=\"" << ly + 20
      << "\" stroke=\"#000\" stroke-width=\"2\"/><text x=\"" << map_w - 20 << "\" y=\"" << ly + 34 << "\" text-anchor=\"end\">"
      << format_number(bar) << " map units</text>\n</svg>\n";
    return s.str();
}

HtmlReport::HtmlReport(std::string title) : title_(std::move(title)) {}

void HtmlReport::heading(const std::string& text) { body_ += "<h2>" + xml_escape(text) + "</h2>\n"; }
void HtmlReport::paragraph(const std::string& text) { body_ += "<p>" + xml_escape(text) + "</p>\n"; }

void HtmlReport::table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows, std::size_t max_rows) {
    std::string t = "<table>\n<tr>";
    for (const std::string& h : header) t += "<th>" + xml_escape(h) + "</th>";
    t += "</tr>\n";
    for (std::size_t i = 0; i < std::min(rows.size(), max_rows); ++i) {
        t += "<tr>";
        for (const std::string& c : rows[i]) t += "<td>" + xml_escape(c) + "</td>";
        t += "</tr>\n";
    }
    t += "</table>\n";
    if (rows.size() > max_rows) t += "<p>" + std::to_string(rows.size() - max_rows) + " more rows are in report.json.</p>\n";
    body_ += t;
}

void HtmlReport::figure(const std::string& svg, const std::string& caption) {
    body_ += "<figure>\n" + svg + "<figcaption>" + xml_escape(caption) + "</figcaption>\n</figure>\n";
}

std::string HtmlReport::render() const {
    return "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>" + xml_escape(title_) +
           "</title>\n<style>\nbody{font-family:sans-serif;margin:2em;max-width:1000px;color:#222}\n"
           "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}\n"
           "th{background:#f0f0f0}figure{margin:1em 0}figcaption{color:#555;font-size:90%}\n</style>\n</head>\n<body>\n<h1>" +
           xml_escape(title_) + "</h1>\n" + body_ + "</body>\n</html>\n";
}

}  // namespace cityforge
