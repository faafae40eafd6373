#include "cli_support.hpp"

#include <fstream>
#include <sstream>

#include "core/error.hpp"

namespace cityforge::cli {

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
    std::ifstream in(path);
    if (!in) throw Error(path, "cannot open config file");
    try {
        return nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
        throw Error(path, std::string("invalid JSON: ") + e.what());
    }
}

}  // namespace cityforge::cli
