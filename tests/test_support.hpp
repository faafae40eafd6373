#pragma once
// Shared helpers of the test suite: paths to real data and the built CLI,
// scratch folders and running the CLI as a user would.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>
#include <unistd.h>

namespace cityforge::test {

inline std::string shared_data(const std::string& rel) { return std::string(CITYFORGE_SHARED_DATA) + "/" + rel; }
inline std::string source_dir() { return CITYFORGE_SOURCE_DIR; }
inline std::string cli() { return CITYFORGE_CLI; }

/// A fresh, empty scratch folder removed at scope exit.
struct ScratchDir {
    std::filesystem::path path;
    explicit ScratchDir(const std::string& name) {
        path = std::filesystem::temp_directory_path() / ("cityforge_test_" + name + "_" + std::to_string(::getpid()));
        std::filesystem::remove_all(path);
        std::filesystem::create_directories(path);
    }
    ~ScratchDir() {
        std::error_code ec;
        std::filesystem::remove_all(path, ec);
    }
    std::string operator/(const std::string& name) const { return (path / name).string(); }
    std::size_t file_count() const {
        std::size_t n = 0;
        for ([[maybe_unused]] const auto& e : std::filesystem::recursive_directory_iterator(path)) ++n;
        return n;
    }
};

inline std::string slurp(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

struct CommandResult {
    int exit_code = -1;
    std::string out;
    std::string err;
};

/// Runs a shell command line, capturing its exit status, stdout and stderr.
inline CommandResult run_command(const std::string& command) {
    static int counter = 0;
    const auto base = std::filesystem::temp_directory_path() /
                      ("cityforge_cmd_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    const std::string out = base.string() + ".out", err = base.string() + ".err";
    const std::string cmd = command + " >" + out + " 2>" + err + " </dev/null";
    const int status = std::system(cmd.c_str());
    CommandResult r;
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = slurp(out);
    r.err = slurp(err);
    std::filesystem::remove(out);
    std::filesystem::remove(err);
    return r;
}

/// Runs the built `cityforge` with `args` (shell-quoted by the caller).
inline CommandResult run_cli(const std::string& args) { return run_command(cli() + " " + args); }

/// Validates a JSON (or JSON Lines) file against a JSON Schema with ajv
/// (tools/schema_check, installed by scripts/install_deps.sh). Exit 0 = valid;
/// `out` lists the errors otherwise.
inline CommandResult validate_json(const std::string& schema, const std::string& data, const std::vector<std::string>& extra_schemas = {}) {
    std::string cmd = "node " + source_dir() + "/tools/schema_check/validate.mjs " + schema + " " + data;
    for (const std::string& e : extra_schemas) cmd += " " + e;
    return run_command(cmd);
}

/// "ulimit -v KB; " for a shell command that must meet an address-space limit,
/// or "" in the sanitized build: AddressSanitizer reserves terabytes of virtual
/// address space for its shadow memory and cannot start under such a limit.
/// The tests using it still hold there: the memory checks refuse by the
/// machine's physical memory as well.
inline std::string address_space_limit(long kb) {
#ifdef CITYFORGE_SANITIZED
    (void)kb;
    return "";
#else
    return "ulimit -v " + std::to_string(kb) + "; ";
#endif
}

inline int count_lines(const std::string& s) {
    int n = 0;
    for (char c : s) n += c == '\n';
    return n;
}

}  // namespace cityforge::test
