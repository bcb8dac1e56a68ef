// Whole-file reads and atomic writes.
#include <sys/stat.h>

#include <cerrno>
#include <cstdio>
#include <memory>
#include <string>

#include <sys/stat.h>

#include "absl/strings/str_cat.h"
#include "core/mesh/io.h"

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

bool IsStreamPath(const std::string& path) {
  struct stat st;
  return path == "-" || (::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode) && !S_ISDIR(st.st_mode));
}

namespace {

/// Writes `contents` to an open stream; the error names `path`.
absl::Status WriteAll(FILE* f, const std::string& path, std::string_view contents) {
  if (std::fwrite(contents.data(), 1, contents.size(), f) != contents.size() || std::fflush(f) != 0)
    return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
  return absl::OkStatus();
}

}  // namespace

absl::Status WriteFileAtomically(const std::string& path, std::string_view contents) {
  if (path == "-") return WriteAll(stdout, "standard output", contents);
  if (IsStreamPath(path)) {  // a device or pipe: no temporary file beside it
    std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "wb"), &std::fclose);
    if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
    return WriteAll(f.get(), path, contents);
  }
  const std::string tmp = path + ".tmp";
  FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
  bool ok =
      std::fwrite(contents.data(), 1, contents.size(), f) == contents.size() && std::fflush(f) == 0;
  int err = ok ? 0 : errno;
  if (std::fclose(f) != 0 && ok) {
    ok = false;
    err = errno;
  }
  if (!ok) {
    std::remove(tmp.c_str());
    return absl::ErrnoToStatus(err, absl::StrCat("cannot write '", path, "'"));
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    err = errno;
    std::remove(tmp.c_str());
    return absl::ErrnoToStatus(err, absl::StrCat("cannot rename '", tmp, "' to '", path, "'"));
  }
  return absl::OkStatus();
}

}  // namespace geomfit
