// Whole-file reads and atomic writes.
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "core/mesh/io.h"
#include "core/util/status_macros.h"

namespace geomfit {

absl::StatusOr<std::string> ReadFileToString(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot open '", path, "'"));
  // One block: the whole file when its size is known (a regular file), read straight
  // into the string; pipes and growing files continue in doubling blocks.
  struct stat st;
  size_t block = 1 << 16;
  if (fstat(fileno(f.get()), &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0)
    block = static_cast<size_t>(st.st_size) + 1;  // + 1: EOF in the same read
  std::string out(block, '\0');
  size_t used = 0;
  for (;;) {
    used += std::fread(out.data() + used, 1, out.size() - used, f.get());
    if (used < out.size()) break;  // end of file or an error
    out.resize(2 * out.size());
  }
  out.resize(used);
  if (std::ferror(f.get()))
    return absl::ErrnoToStatus(errno, absl::StrCat("cannot read '", path, "'"));
  return out;
}

FileBytes& FileBytes::operator=(FileBytes&& o) noexcept {
  if (this != &o) {
    this->~FileBytes();
    map_ = std::exchange(o.map_, nullptr);
    size_ = std::exchange(o.size_, 0);
    text_ = std::move(o.text_);
  }
  return *this;
}

FileBytes::~FileBytes() {
  if (map_ != nullptr) munmap(map_, size_);
  map_ = nullptr;
}

absl::StatusOr<FileBytes> ReadFileBytes(const std::string& path) {
  FileBytes out;
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    struct stat st;
    if (fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) {
      // Every page mapped at once (MAP_POPULATE): no fault per page while parsing.
      void* p = mmap(nullptr, static_cast<size_t>(st.st_size), PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
      if (p != MAP_FAILED) {
        out.map_ = static_cast<char*>(p);
        out.size_ = static_cast<size_t>(st.st_size);
      }
    }
    ::close(fd);
    if (out.map_ != nullptr) return out;
  }
  // Not a regular file, or not mappable: read it (its errors name the path).
  GF_ASSIGN_OR_RETURN(out.text_, ReadFileToString(path));
  return out;
}

bool IsStreamPath(const std::string& path) {
  struct stat st;
  return path == "-" || (::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode) && !S_ISDIR(st.st_mode));
}

namespace {

/// Writes the pieces of `next` to an open stream; the error names `path`.
absl::Status WriteAll(FILE* f, const std::string& path, const std::function<std::string_view()>& next) {
  for (std::string_view piece = next(); !piece.empty(); piece = next())
    if (std::fwrite(piece.data(), 1, piece.size(), f) != piece.size())
      return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
  if (std::fflush(f) != 0) return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
  return absl::OkStatus();
}

}  // namespace

absl::Status WriteFileAtomically(const std::string& path, std::string_view contents) {
  bool done = false;
  return WriteFileAtomicallyInPieces(path, [&]() -> std::string_view {
    if (done) return {};
    done = true;
    return contents;
  });
}

absl::Status WriteFileAtomicallyInPieces(const std::string& path,
                                         const std::function<std::string_view()>& next) {
  if (path == "-") return WriteAll(stdout, "standard output", next);
  if (IsStreamPath(path)) {  // a device or pipe: no temporary file beside it
    std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "wb"), &std::fclose);
    if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
    return WriteAll(f.get(), path, next);
  }
  const std::string tmp = path + ".tmp";
  FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
  // Unbuffered: each piece goes to the kernel in one write(), with no copy through
  // stdio's buffer (pieces are large, or the whole contents).
  std::setvbuf(f, nullptr, _IONBF, 0);
  absl::Status written = WriteAll(f, path, next);
  if (std::fclose(f) != 0 && written.ok())
    written = absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
  if (!written.ok()) {
    std::remove(tmp.c_str());
    return written;
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::remove(tmp.c_str());
    return absl::ErrnoToStatus(err, absl::StrCat("cannot rename '", tmp, "' to '", path, "'"));
  }
  return absl::OkStatus();
}

}  // namespace geomfit
