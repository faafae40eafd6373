#include "core/atomic_file.hpp"

#include <fstream>
#include <vector>
#include <cerrno>
#include <csignal>
#include <regex>
#include <unistd.h>

#include "core/error.hpp"

namespace cityforge {
namespace fs = std::filesystem;

fs::path temporary_path_for(const fs::path& final_path) {
    fs::path tmp = final_path;
    tmp.replace_filename(final_path.stem().string() + ".part-" + std::to_string(::getpid()) +
                         final_path.extension().string());
    return tmp;
}

std::string user_named(std::string message, const fs::path& tmp, const fs::path& final_path) {
    for (const auto& [from, to] : {std::pair{tmp.string(), final_path.string()}, std::pair{tmp.filename().string(), final_path.filename().string()}}) {
        if (from.empty()) continue;
        for (std::size_t at = message.find(from); at != std::string::npos; at = message.find(from, at + to.size()))
            message.replace(at, from.size(), to);
    }
    return message;
}

namespace {
// Files a driver writes beside its main file (Shapefile's .shx, .dbf, ...):
// they belong to the temporary and move or go with it.
const char* const kSidecars[] = {".shx", ".dbf", ".prj", ".cpg", ".qpj", ".sbn", ".sbx", ".qix"};
fs::path sibling(const fs::path& p, const char* ext) {
    fs::path s = p;
    s.replace_filename(p.stem().string() + ext);
    return s;
}
}  // namespace

void commit_file(const fs::path& tmp, const fs::path& final_path) {
    std::error_code ec;
    for (const char* ext : kSidecars) {
        const fs::path from = sibling(tmp, ext);
        if (!fs::exists(from, ec)) continue;
        fs::rename(from, sibling(final_path, ext), ec);
        if (ec) {
            discard_file(tmp);
            throw Error(final_path.string(), "cannot move finished output into place: " + ec.message());
        }
    }
    fs::rename(tmp, final_path, ec);
    if (ec) {
        discard_file(tmp);
        throw Error(final_path.string(), "cannot move finished output into place: " + ec.message());
    }
}

void discard_file(const fs::path& tmp) noexcept {
    std::error_code ec;
    fs::remove(tmp, ec);
    for (const char* ext : kSidecars) fs::remove(sibling(tmp, ext), ec);
    for (const char* suffix : {"-journal", "-wal", "-shm"}) fs::remove(fs::path(tmp.string() + suffix), ec);
}

void write_text_file(const fs::path& path, const std::string& content) {
    AtomicTextFile file(path);
    file.stream() << content;
    file.commit();
}

AtomicTextFile::AtomicTextFile(fs::path final_path) : final_(std::move(final_path)), tmp_(temporary_path_for(final_)) {
    out_.open(tmp_, std::ios::binary);
    if (!out_) throw Error(final_.string(), "cannot open for writing");
}

AtomicTextFile::~AtomicTextFile() {
    if (!committed_) {
        out_.close();
        discard_file(tmp_);
    }
}

void AtomicTextFile::commit() {
    out_.flush();
    const bool ok = static_cast<bool>(out_);
    out_.close();
    if (!ok || out_.fail()) {
        discard_file(tmp_);
        committed_ = true;  // nothing left to clean up
        throw Error(final_.string(), "write failed (disk full?)");
    }
    committed_ = true;
    commit_file(tmp_, final_);
}

std::size_t remove_stale_temporaries(const fs::path& dir) {
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) return 0;
    static const std::regex part(R"(.*\.part-([0-9]{1,9})(\..*|-journal|-wal|-shm)?)");
    std::vector<fs::path> stale;
    for (const auto& e : fs::directory_iterator(dir, ec)) {
        std::smatch m;
        const std::string name = e.path().filename().string();
        if (!std::regex_match(name, m, part)) continue;
        const long pid = std::stol(m[1].str());
        if (pid <= 0 || pid == ::getpid()) continue;
        if (::kill(static_cast<pid_t>(pid), 0) == 0 || errno != ESRCH) continue;  // alive (or not ours to judge)
        stale.push_back(e.path());
    }
    std::size_t removed = 0;
    for (const fs::path& p : stale) removed += fs::remove(p, ec) ? 1 : 0;
    return removed;
}

void ensure_directory(const fs::path& dir) {
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir)) throw Error(dir.string(), "cannot create output folder: " + ec.message());
}

}  // namespace cityforge
