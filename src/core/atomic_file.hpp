#pragma once
// Write-then-rename so that a failure never leaves a half-written output.
#include <filesystem>
#include <fstream>
#include <string>

namespace cityforge {

/// Temporary sibling path for `final_path` ("name.part-PID.ext", same folder so
/// the rename is atomic and keeps the extension so that drivers recognise it).
/// The path is registered (register_temporary) before the caller creates it,
/// so that an interrupted process removes it; commit_file and discard_file
/// take it off the list.
std::filesystem::path temporary_path_for(const std::filesystem::path& final_path);

/// Adds `path` (a file, with its sidecars, or a folder) to this process's list
/// of live temporaries: remove_registered_temporaries (run on SIGINT, SIGTERM
/// and SIGHUP once remove_temporaries_on_signals was called) removes it.
/// Register before creating the file or folder.
void register_temporary(const std::filesystem::path& path);

/// Takes `path` off the list of live temporaries (after it was renamed into
/// place or removed). Never throws.
void unregister_temporary(const std::filesystem::path& path) noexcept;

/// Removes every registered temporary (files with their sidecars and journals,
/// folders with their content) and empties the list. Returns how many were
/// listed. Never throws.
std::size_t remove_registered_temporaries() noexcept;

/// Installs handlers for SIGINT, SIGTERM and SIGHUP (those not ignored when
/// the process started): on the first signal the registered temporaries are
/// removed (by a helper thread, outside the signal handler; new temporaries
/// can no longer be registered) and the signal is raised again with its
/// default action, so that the process ends as killed by it. A second signal
/// ends the process at once. For the command-line program; call once.
void remove_temporaries_on_signals();

/// `message` (e.g. a GDAL error about the temporary file) with every mention
/// of `tmp` (full path or file name) replaced by `final_path`: errors name the
/// file the user gave, never "x.part-20659.gpkg".
std::string user_named(std::string message, const std::filesystem::path& tmp, const std::filesystem::path& final_path);

/// Renames `tmp` onto `final_path` (replacing it), with the sidecar files a
/// driver wrote beside it (.shx, .dbf, .prj, ... of a Shapefile). Throws
/// Error naming final_path.
void commit_file(const std::filesystem::path& tmp, const std::filesystem::path& final_path);

/// Removes `tmp` and its sidecars if present; never throws (used on the error path).
void discard_file(const std::filesystem::path& tmp) noexcept;

/// Writes `content` to `path` atomically. Throws Error naming the path.
void write_text_file(const std::filesystem::path& path, const std::string& content);

/// Removes the temporaries of dead processes of this machine in `dir` (not
/// recursive): files named like temporary_path_for's "NAME.part-PID.EXT" (and
/// their sidecars), and folders named "NAME.part-PID" (3D Tiles) with their
/// content, whose PID is not a running process. Returns how many went.
/// Only for folders no other machine writes to (a PID names a process of this
/// host only).
std::size_t remove_stale_temporaries(const std::filesystem::path& dir);

/// Creates `dir` (and parents) or throws Error naming it.
void ensure_directory(const std::filesystem::path& dir);

/// A text file written as a stream to a temporary sibling and renamed onto
/// its final path by commit(); destroyed without commit(), it leaves nothing.
class AtomicTextFile {
public:
    /// Opens the temporary file; throws Error naming `final_path` on failure.
    explicit AtomicTextFile(std::filesystem::path final_path);
    ~AtomicTextFile();
    AtomicTextFile(const AtomicTextFile&) = delete;
    AtomicTextFile& operator=(const AtomicTextFile&) = delete;
    std::ostream& stream() { return out_; }
    /// Flushes, checks for write errors and renames. Throws Error naming the path.
    void commit();

private:
    std::filesystem::path final_, tmp_;
    std::ofstream out_;
    bool committed_ = false;
};

}  // namespace cityforge
