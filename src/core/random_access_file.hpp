#pragma once
// A file opened once for positional reads (pread): how the LAS/LAZ/COPC
// reader (LasReader, the LAZ chunk decoder, the COPC hierarchy) takes bytes
// at given offsets. Several threads may
// read from one object at once (pread has no shared file position). The
// file's size is taken from the open descriptor (fstat), so the size, the
// header and the records all come from the same file even if the path is
// renamed or replaced while it is read.
#include <cstddef>
#include <cstdint>
#include <string>

namespace cityforge {

class RandomAccessFile {
public:
    /// Opens `path` for reading. Throws Error naming the path: "file not
    /// found" (also a path through a file), "is a directory, not <what_kind>",
    /// "cannot open for reading: <system reason>" or "cannot read the file's
    /// size: <system reason>". `what_kind` names the expected content (e.g.
    /// "a point cloud file").
    RandomAccessFile(const std::string& path, const std::string& what_kind);
    ~RandomAccessFile();
    RandomAccessFile(const RandomAccessFile&) = delete;
    RandomAccessFile& operator=(const RandomAccessFile&) = delete;
    /// Takes over `other`'s open file (`other` is left closed: reads throw).
    RandomAccessFile(RandomAccessFile&& other);
    RandomAccessFile& operator=(RandomAccessFile&&) = delete;

    const std::string& path() const { return path_; }
    /// Size in bytes when the file was opened.
    uint64_t size() const { return size_; }

    /// Reads up to `bytes` at `offset` into `out`, again after a signal or a
    /// short read, until `bytes` are read or the file ends; returns how many
    /// were read (fewer only at the end of the file). An I/O error throws
    /// Error "<path>: read error at byte <offset>: <system reason>".
    std::size_t read_at(uint64_t offset, void* out, std::size_t bytes) const;
    /// read_at that must read all `bytes`: false when the file ends first.
    bool read_exact_at(uint64_t offset, void* out, std::size_t bytes) const { return read_at(offset, out, bytes) == bytes; }

    /// A hint to the kernel that the file is read front to back (a larger
    /// read-ahead window); never fails.
    void advise_sequential() const;

private:
    std::string path_;
    int fd_ = -1;
    uint64_t size_ = 0;
};

}  // namespace cityforge
