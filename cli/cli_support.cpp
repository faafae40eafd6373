#include "cli_support.hpp"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "io/cloud_crs.hpp"
#include "raster/raster.hpp"

namespace cityforge::cli {

void remove_stale_temporaries_beside(const std::string& path) {
    namespace fs = std::filesystem;
    if (path.empty() || path.rfind("PG:", 0) == 0 || path.rfind("pg:", 0) == 0) return;
    const fs::path p(path);
    std::error_code ec;
    const fs::path parent = p.parent_path().empty() ? fs::path(".") : p.parent_path();
    std::size_t removed = remove_stale_temporaries(parent);
    if (fs::is_directory(p, ec)) removed += remove_stale_temporaries(p);
    if (removed)
        log::info("removed " + std::to_string(removed) + " temporar" + (removed == 1 ? "y" : "ies") + " of an interrupted process beside " + path);
}

void warn_without_vertical_crs(const std::string& cloud, const std::string& cloud_crs, const std::string& what, const std::string& remedy) {
    const CrsInfo c = resolve_cloud_crs(cloud, cloud_crs).crs;
    if (c.empty() || c.vertical_epsg || !c.vertical_name.empty()) return;
    log::warning(cloud + ": no vertical CRS (" + c.label() + "): " + what + " are written without a named height datum; " + remedy +
                 (c.horizontal_epsg ? " EPSG:" + std::to_string(*c.horizontal_epsg) + "+<vertical EPSG code>" : std::string(" a compound CRS")) +
                 " (e.g. 5703 NAVD88, 5709 NAP, 5720 NGF-IGN69 height)");
}

void refuse_existing_output(const GlobalFlags& g, const std::string& path) {
    namespace fs = std::filesystem;
    std::error_code ec;
    remove_stale_temporaries_beside(path);
    if (path.empty() || g.overwrite || !fs::exists(path, ec)) return;
    if (fs::is_directory(path, ec) && fs::is_empty(path, ec)) return;
    throw Error(path, std::string(fs::is_directory(path, ec) ? "output folder exists and is not empty" : "output exists") +
                          "; give --overwrite to replace it");
}

namespace {
std::size_t edit_distance(const std::string& a, const std::string& b) {
    std::vector<std::size_t> prev(b.size() + 1), cur(b.size() + 1);
    for (std::size_t j = 0; j <= b.size(); ++j) prev[j] = j;
    for (std::size_t i = 1; i <= a.size(); ++i) {
        cur[0] = i;
        for (std::size_t j = 1; j <= b.size(); ++j)
            cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
        std::swap(prev, cur);
    }
    return prev[b.size()];
}
}  // namespace

std::string unknown_subcommand_message(const CLI::App& app, int argc, char** argv) {
    const CLI::App* cur = &app;
    std::string path;
    for (int i = 1; i < argc; ++i) {
        const std::string word = argv[i];
        if (word.empty() || word[0] == '-') {
            if (word == "--help" || word == "-h" || word == "--version") return {};
            continue;
        }
        const auto subs = cur->get_subcommands([](const CLI::App*) { return true; });
        if (subs.empty()) return {};  // a value or positional of a leaf command
        const CLI::App* next = nullptr;
        std::string best;
        std::size_t best_d = std::string::npos;
        for (const CLI::App* s : subs) {
            if (s->get_name() == word) next = s;
            const std::size_t d = edit_distance(word, s->get_name());
            if (d < best_d) best_d = d, best = s->get_name();
        }
        if (!next) {
            std::string names;
            for (const CLI::App* s : subs) names += (names.empty() ? "" : ", ") + s->get_name();
            std::string m = "unknown subcommand '" + path + word + "'";
            if (best_d <= std::max<std::size_t>(2, word.size() / 3)) m += "; did you mean '" + path + best + "'?";
            else m += "; subcommands: " + names;
            return m;
        }
        path += word + " ";
        cur = next;
    }
    return {};
}

Progress make_progress(const GlobalFlags& g) {
    if (g.quiet) return {};
    return Progress(make_terminal_progress(g.progress));
}

std::string join_words(const std::vector<std::string>& words) {
    std::string out;
    for (const std::string& w : words) out += (out.empty() ? "" : " ") + w;
    return out;
}

std::vector<std::string> split_list(const std::string& text) {
    std::vector<std::string> out;
    std::string item;
    std::stringstream ss(text);
    while (std::getline(ss, item, ','))
        if (!item.empty()) out.push_back(item);
    return out;
}

std::vector<int> parse_lods(const std::string& text) {
    std::vector<int> lods;
    for (const std::string& l : split_list(text)) {
        if (l != "0" && l != "1" && l != "2") throw Error("--lod", "levels of detail are 0, 1 and 2, got '" + l + "'");
        lods.push_back(std::stoi(l));
    }
    return lods;
}

nlohmann::json read_json_file(const std::string& path) {
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) throw Error(path, "is a directory, not a JSON config file");
    std::ifstream in(path);
    if (!in) throw Error(path, "cannot open config file");
    try {
        return nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
        throw Error(path, std::string("invalid JSON: ") + e.what());
    } catch (const std::ios_base::failure& e) {
        throw Error(path, std::string("cannot read: ") + e.what());
    }
}

CrsInfo vertical_crs_option(const std::string& text, const std::string& option) {
    const CrsInfo v = crs_from_user_input(text, option);
    if (!v.vertical_epsg && v.vertical_name.empty())
        throw Error(option, v.label() + " is not a vertical CRS (e.g. EPSG:5703 NAVD88, 5709 NAP, 5720 NGF-IGN69 height)");
    return v;
}

void require_readable_raster(const std::string& path) {
    if (!path.empty()) read_raster_info(path);
}

}  // namespace cityforge::cli
