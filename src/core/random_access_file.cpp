#include "core/random_access_file.hpp"

#include "core/error.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace cityforge {

RandomAccessFile::RandomAccessFile(const std::string& path, const std::string& what_kind) : path_(path) {
    fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) {
        const int e = errno;
        if (e == ENOENT || e == ENOTDIR) throw Error(path, "file not found");
        throw Error(path, std::string("cannot open for reading: ") + std::strerror(e));
    }
    struct stat st {};
    if (::fstat(fd_, &st) != 0) {
        const int e = errno;
        ::close(fd_);
        throw Error(path, std::string("cannot read the file's size: ") + std::strerror(e));
    }
    if (S_ISDIR(st.st_mode)) {
        ::close(fd_);
        throw Error(path, "is a directory, not " + what_kind);
    }
    size_ = static_cast<uint64_t>(st.st_size);
}

RandomAccessFile::RandomAccessFile(RandomAccessFile&& other)
    : path_(other.path_), fd_(other.fd_), size_(other.size_) {  // the path stays: a read of `other` names the file
    other.fd_ = -1, other.size_ = 0;
}

RandomAccessFile::~RandomAccessFile() {
    if (fd_ >= 0) ::close(fd_);
}

std::size_t RandomAccessFile::read_at(uint64_t offset, void* out, std::size_t bytes) const {
    char* p = static_cast<char*>(out);
    std::size_t done = 0;
    while (done < bytes) {
        const ssize_t got = ::pread(fd_, p + done, std::min<std::size_t>(bytes - done, std::size_t(1) << 30), static_cast<off_t>(offset + done));
        if (got < 0) {
            const int e = errno;
            if (e == EINTR) continue;
            throw Error(path_, "read error at byte " + std::to_string(offset + done) + ": " + std::strerror(e));
        }
        if (got == 0) break;
        done += static_cast<std::size_t>(got);
    }
    return done;
}

void RandomAccessFile::advise_sequential() const { ::posix_fadvise(fd_, 0, 0, POSIX_FADV_SEQUENTIAL); }

}  // namespace cityforge
