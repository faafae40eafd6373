#include "core/atomic_file.hpp"

#include <fstream>
#include <vector>
#include <cerrno>
#include <csignal>
#include <mutex>
#include <regex>
#include <set>
#include <thread>
#include <unistd.h>

#include "core/error.hpp"

namespace cityforge {
namespace fs = std::filesystem;

namespace {
// The live temporaries of this process. Never destroyed: the signal thread may
// use them while the process exits.
std::mutex& registry_mutex() {
    static auto* m = new std::mutex;
    return *m;
}
std::set<std::string>& registry() {
    static auto* r = new std::set<std::string>;
    return *r;
}
}  // namespace

fs::path temporary_path_for(const fs::path& final_path) {
    fs::path tmp = final_path;
    tmp.replace_filename(final_path.stem().string() + ".part-" + std::to_string(::getpid()) +
                         final_path.extension().string());
    register_temporary(tmp);
    return tmp;
}

void register_temporary(const fs::path& path) {
    std::lock_guard<std::mutex> lock(registry_mutex());
    registry().insert(path.string());
}

void unregister_temporary(const fs::path& path) noexcept {
    try {
        std::lock_guard<std::mutex> lock(registry_mutex());
        registry().erase(path.string());
    } catch (...) {  // a list entry left over only costs a useless removal later
    }
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
    unregister_temporary(tmp);
}

namespace {
// Removes a temporary file with its sidecars and journals, or a temporary folder with its content.
void remove_temporary(const fs::path& tmp) noexcept {
    try {
        std::error_code ec;
        fs::remove_all(tmp, ec);
        for (const char* ext : kSidecars) fs::remove(sibling(tmp, ext), ec);
        for (const char* suffix : {"-journal", "-wal", "-shm"}) fs::remove(fs::path(tmp.string() + suffix), ec);
    } catch (...) {  // path building may allocate; on the error path nothing more can be done
    }
}

// Signal handling: the handler only writes the signal number to a pipe; a
// thread waiting on the pipe removes the temporaries and re-raises it.
int g_signal_pipe[2] = {-1, -1};
volatile std::sig_atomic_t g_signalled = 0;

extern "C" void on_termination_signal(int sig) {
    if (g_signalled) {  // a second signal: end at once
        std::signal(sig, SIG_DFL);
        std::raise(sig);
        return;
    }
    g_signalled = sig;
    const int saved = errno;
    const unsigned char b = static_cast<unsigned char>(sig);
    if (::write(g_signal_pipe[1], &b, 1) != 1) {  // no cleanup possible: end as the signal asks
        std::signal(sig, SIG_DFL);
        std::raise(sig);
    }
    errno = saved;
}

[[noreturn]] void clean_up_and_reraise() {
    unsigned char b = 0;
    while (::read(g_signal_pipe[0], &b, 1) != 1)
        if (errno != EINTR) ::pause();  // the pipe broke: leave it to the default actions
    const int sig = b;
    {
        // Held until the process ends: no new temporary is registered (and created) after this.
        registry_mutex().lock();
        for (const std::string& p : registry()) remove_temporary(p);
    }
    std::signal(sig, SIG_DFL);
    std::raise(sig);
    ::_exit(128 + sig);
}
}  // namespace

void discard_file(const fs::path& tmp) noexcept {
    remove_temporary(tmp);
    unregister_temporary(tmp);
}

std::size_t remove_registered_temporaries() noexcept {
    try {
        std::lock_guard<std::mutex> lock(registry_mutex());
        const std::size_t n = registry().size();
        for (const std::string& p : registry()) remove_temporary(p);
        registry().clear();
        return n;
    } catch (...) {
        return 0;
    }
}

void remove_temporaries_on_signals() {
    if (g_signal_pipe[0] >= 0) return;
    if (::pipe(g_signal_pipe) != 0) return;  // no handlers: a killed run's temporaries go on the next start
    std::thread(clean_up_and_reraise).detach();
    for (const int sig : {SIGINT, SIGTERM, SIGHUP}) {
        struct sigaction old {};
        if (::sigaction(sig, nullptr, &old) == 0 && old.sa_handler == SIG_IGN) continue;  // nohup, background jobs
        struct sigaction sa {};
        sa.sa_handler = on_termination_signal;
        sigemptyset(&sa.sa_mask);
        sa.sa_flags = SA_RESTART;
        ::sigaction(sig, &sa, nullptr);
    }
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
    for (const fs::path& p : stale) {
        // A folder (3dtiles.part-PID/content/...) goes with its content.
        const auto n = fs::is_directory(p, ec) ? fs::remove_all(p, ec) : static_cast<std::uintmax_t>(fs::remove(p, ec));
        removed += (!ec && n > 0) ? 1 : 0;
    }
    return removed;
}

void ensure_directory(const fs::path& dir) {
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir)) throw Error(dir.string(), "cannot create output folder: " + ec.message());
}

}  // namespace cityforge
