// Whole-file reads and atomic writes.
#include <sys/stat.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <functional>
#include <memory>
#include <string>

#include <sys/stat.h>

#include "absl/strings/str_cat.h"
#include "core/mesh/io.h"

namespace geomfit {

absl::StatusOr<FileBytes> ReadFileBytes(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot open '", path, "'"));
  // One block: the whole file when its size is known (a regular file), read straight
  // into the buffer; pipes and growing files continue in doubling blocks.
  struct stat st;
  size_t capacity = 1 << 16;
  if (fstat(fileno(f.get()), &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0)
    capacity = static_cast<size_t>(st.st_size) + 1;  // + 1: EOF in the same read
  FileBytes out;
  out.data.reset(new char[capacity]);  // not zeroed
  for (;;) {
    out.size += std::fread(out.data.get() + out.size, 1, capacity - out.size, f.get());
    if (out.size < capacity) break;  // end of file or an error
    std::unique_ptr<char[]> grown(new char[2 * capacity]);
    std::memcpy(grown.get(), out.data.get(), out.size);
    out.data = std::move(grown);
    capacity *= 2;
  }
  if (std::ferror(f.get())) return absl::ErrnoToStatus(errno, absl::StrCat("cannot read '", path, "'"));
  return out;
}

absl::StatusOr<std::string> ReadFileToString(const std::string& path) {
  absl::StatusOr<FileBytes> bytes = ReadFileBytes(path);
  if (!bytes.ok()) return bytes.status();
  return std::string(bytes->view());
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
