#include "core/atomic_file.hpp"

#include <fstream>
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

void commit_file(const fs::path& tmp, const fs::path& final_path) {
    std::error_code ec;
    fs::rename(tmp, final_path, ec);
    if (ec) {
        discard_file(tmp);
        throw Error(final_path.string(), "cannot move finished output into place: " + ec.message());
    }
}

void discard_file(const fs::path& tmp) noexcept {
    std::error_code ec;
    fs::remove(tmp, ec);
}

void write_text_file(const fs::path& path, const std::string& content) {
    const fs::path tmp = temporary_path_for(path);
    {
        std::ofstream out(tmp, std::ios::binary);
        if (!out) throw Error(path.string(), "cannot open for writing");
        out << content;
        out.flush();
        if (!out) {
            out.close();
            discard_file(tmp);
            throw Error(path.string(), "write failed (disk full?)");
        }
    }
    commit_file(tmp, path);
}

void ensure_directory(const fs::path& dir) {
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir)) throw Error(dir.string(), "cannot create output folder: " + ec.message());
}

}  // namespace cityforge
